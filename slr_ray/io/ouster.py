"""Ouster range-image frames in ``.npz``: ``xyz`` ``(rows, columns, 3)`` (the sensor's frame, m),
``range_mm`` ``(rows, columns)``, and optionally ``reflectivity`` and other ``(rows, columns)`` images,
per-column ``col_timestamp_ns``, ``beam_altitude_deg`` / ``beam_azimuth_deg`` (as ouster-sdk's
``LidarScan`` fields). :mod:`~slr_ray.io.npy` reads an ``.npz`` with these arrays and no ``points`` here.

Each pixel with a return is a point with its ``ring`` (the row: 0 the top beam, as Ouster numbers
them), ``column`` and every image's value; pixels of range 0 (no return) are not points, and how many
there were is said (a warning, and ``meta["no_return_pixels"]``). The beam angles go to ``meta``.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import FormatError, SlrNote
from .cloud import PointCloud

__all__ = ["is_ouster_npz", "read_ouster_npz"]


def is_ouster_npz(files) -> bool:
    """Whether the arrays named ``files`` are an Ouster range image's (``xyz`` and ``range_mm``, no ``points``)."""
    return "points" not in files and {"xyz", "range_mm"} <= set(files)


def read_ouster_npz(path, z) -> PointCloud:
    """The cloud of the open archive ``z`` (``np.load`` of ``path``; module docstring)."""
    xyz, rng = z["xyz"], z["range_mm"]
    if xyz.ndim != 3 or xyz.shape[2] != 3 or rng.shape != xyz.shape[:2]:
        raise FormatError(f"{path}: an Ouster range image needs xyz (rows, columns, 3) and range_mm (rows, "
                          f"columns), got {xyz.shape} and {rng.shape}")
    rows, cols = rng.shape
    hit = rng > 0
    lost = int(hit.size - hit.sum())
    if lost:
        warnings.warn(f"{path}: {lost:,} of {hit.size:,} pixels have no return (range_mm 0): not read as points",
                      SlrNote, stacklevel=4)
    r, c = np.nonzero(hit)
    attrs = {"ring": r.astype(np.int32), "column": c.astype(np.int32)}
    meta = {"layout": f"Ouster range image {rows} x {cols}", "no_return_pixels": lost}
    for k in z.files:
        if k in ("xyz",):
            continue
        v = z[k]
        if v.shape == (rows, cols):
            attrs[k] = v[hit]
        elif k == "col_timestamp_ns" and v.shape == (cols,):
            attrs["timestamp_ns"] = v[c]
        elif k in ("beam_altitude_deg", "beam_azimuth_deg") and v.shape == (rows,):
            meta[k] = v.astype(np.float64).tolist()
        else:
            meta[k] = v.tolist() if v.size <= 16 else f"array {v.shape} {v.dtype} (not per pixel: not read)"
    return PointCloud(xyz[hit].astype(np.float64), attrs, np.zeros(3), meta)
