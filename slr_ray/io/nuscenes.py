"""nuScenes lidar frames (``.pcd.bin``): float32 x, y, z, intensity, ring (5 a point), the sensor at the
origin of each frame. Chosen by the name (``.pcd.bin``) or ``format='.pcd.bin'`` (``--input-format
pcd.bin``), never by the byte count: a plain ``.bin`` is KITTI's 4 floats (:mod:`~slr_ray.io.kitti`
refuses one that reads as this layout)."""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import FormatError
from .cloud import PointCloud
from .format import Format
from .records import float_records

__all__ = ["FORMATS", "EXTENSION", "looks_like_rings"]

EXTENSION = ".pcd.bin"


def looks_like_rings(column) -> bool:
    """Whether a float column holds ring numbers: integers in [0, 1024), more than one of them."""
    c = np.asarray(column)
    return bool(len(c) and np.all(np.isfinite(c)) and np.all(c == np.round(c)) and c.min() >= 0
                and c.max() < 1024 and len(np.unique(c)) > 1)


def _read(path):
    a = float_records(path, ("x", "y", "z", "intensity", "ring"), "a nuScenes .pcd.bin",
                      (4, " (a multiple of 16: KITTI's layout? name it .bin, or --input-format bin)"))
    ring = a[:, 4]
    if len(a) and not (np.all(ring == np.round(ring)) and ring.min() >= 0):
        raise FormatError(f"{path}: the fifth float of a point is not a ring number (not integers >= 0: "
                          f"{ring[:3].tolist()}...): not a nuScenes .pcd.bin")
    return PointCloud(a[:, :3], {"intensity": a[:, 3].copy(), "ring": ring.astype(np.int32)},
                      np.zeros(3), {"layout": "nuScenes .pcd.bin: float32 x, y, z, intensity, ring"})


def _write(path, cloud, binary):
    dropped = sorted(k for k in cloud.attributes if k not in ("intensity", "ring"))
    if dropped:
        warnings.warn(f"{path}: a nuScenes .pcd.bin holds x, y, z, intensity and ring only; not written: {dropped}",
                      stacklevel=3)
    a = np.empty((len(cloud), 5), np.float32)
    a[:, :3] = cloud.points
    a[:, 3] = cloud.attributes.get("intensity", 0.0)
    a[:, 4] = cloud.attributes.get("ring", 0)
    a.astype("<f4").tofile(path)


FORMATS = (Format(EXTENSION, _read, _write),)
