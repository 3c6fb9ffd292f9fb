"""NumPy files: ``.npy`` (an ``(n, 3)`` or wider array, or a structured one with
``x, y, z`` fields) and ``.npz`` (``points``, an optional ``origin``, and every
other length-``n`` array as an attribute; an Ouster range image's ``xyz`` and
``range_mm``: :mod:`~slr_ray.io.ouster`)."""

from __future__ import annotations

import warnings
import zipfile

import numpy as np

from ..errors import FormatError
from .cloud import PointCloud
from .format import Format
from .ouster import is_ouster_npz, read_ouster_npz

__all__ = ["FORMATS"]


def _read_npy(path):
    with open(path, "rb") as f:
        if f.read(6) != b"\x93NUMPY":
            raise FormatError(f"{path}: not a .npy file (no NumPy header)")
    a = np.load(path, allow_pickle=False)
    if a.dtype.names:
        if not {"x", "y", "z"} <= set(a.dtype.names):
            raise FormatError(f"{path}: structured array without x, y, z fields")
        pts = np.column_stack([a["x"], a["y"], a["z"]])
        return PointCloud(pts, {n: a[n] for n in a.dtype.names if n not in ("x", "y", "z")})
    if a.ndim != 2 or a.shape[1] < 3:
        raise FormatError(f"{path}: expected an (n, 3) or wider array, got shape {a.shape}")
    return PointCloud(a[:, :3], {f"column_{j}": a[:, j] for j in range(3, a.shape[1])})


def _read_npz(path):
    with open(path, "rb") as f:
        if f.read(2) != b"PK":
            raise FormatError(f"{path}: not a .npz file (not a zip archive)")
    with np.load(path, allow_pickle=False) as z:
        if is_ouster_npz(z.files):  # an Ouster range image (xyz, range_mm): its pixels with a return
            return read_ouster_npz(path, z)
        if "points" not in z.files:
            raise FormatError(f"{path}: no 'points' array (has {z.files})")
        pts = z["points"]
        origin = z["origin"].astype(np.float64) if "origin" in z.files else None
        attrs = {k: z[k] for k in z.files if k not in ("points", "origin")}
    return PointCloud(pts, attrs, origin)


def _columns(cloud):
    """Coordinates and every attribute as float64 columns ``(n, 3 + k)`` (empty clouds too)."""
    n = len(cloud)
    cols = [np.asarray(cloud.points, np.float64)]
    for v in cloud.attributes.values():
        v = np.asarray(v, np.float64)
        cols.append(v.reshape(n, int(np.prod(v.shape[1:], dtype=np.int64))))
    return cols


def _exact_in_float64(v) -> bool:
    """Whether every value of dtype ``v.dtype`` is a float64 (so a plain column keeps it)."""
    return v.dtype.kind == "b" or (v.dtype.kind == "f" and v.dtype.itemsize <= 8) or \
        (v.dtype.kind in "iu" and v.dtype.itemsize <= 4)


def _write_npy(path, cloud, binary):
    """Plain float64 columns (x, y, z, then each attribute) when float64 holds every
    attribute exactly; otherwise (int64, uint64 attributes) a structured array with
    fields ``x, y, z`` and each attribute in its own dtype, so no digit is lost."""
    attrs = {k: np.asarray(v) for k, v in cloud.attributes.items()}
    if all(_exact_in_float64(v) for v in attrs.values()):
        cols = _columns(cloud)
        data = np.hstack(cols) if len(cols) > 1 else cloud.points
        lost = [k for j, (k, v) in enumerate(attrs.items()) if k != f"column_{3 + j}" or v.ndim > 1]
        if lost:  # plain columns keep every value, not the names
            warnings.warn(f"{path}: .npy columns keep values, not names: {lost} read back as column_3... "
                          "(write .npz to keep the names)", stacklevel=3)
    else:
        bad = [k for k, v in attrs.items() if v.dtype.kind not in "biuf" or k in ("x", "y", "z")]
        if bad:
            raise FormatError(f".npy cannot store attribute(s) {bad} beside x, y, z")
        data = np.empty(len(cloud), [("x", "f8"), ("y", "f8"), ("z", "f8")]
                        + [(k, v.dtype, v.shape[1:]) for k, v in attrs.items()])
        data["x"], data["y"], data["z"] = np.asarray(cloud.points, np.float64).T
        for k, v in attrs.items():
            data[k] = v
    with open(path, "wb") as f:
        np.save(f, data)


def _write_npz(path, cloud, binary):
    """``np.savez_compressed``'s layout, each array written by name: an attribute
    called ``file`` or ``allow_pickle`` is an array like any other, not a keyword."""
    arrays = {"points": cloud.points, **cloud.attributes}
    if cloud.origin is not None:
        arrays["origin"] = cloud.origin
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as z:
        for name, a in arrays.items():
            with z.open(name + ".npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(a), allow_pickle=False)


FORMATS = (Format(".npy", _read_npy, _write_npy, reserved=frozenset({"x", "y", "z"})),
           Format(".npz", _read_npz, _write_npz, reserved=frozenset({"points", "origin"})))
