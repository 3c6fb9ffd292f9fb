"""KITTI Velodyne frames (``.bin``): float32 x, y, z, intensity; the sensor at the
origin of each frame; SemanticKITTI labels beside it (``.label``) read and written."""

from __future__ import annotations

import os
import warnings

import numpy as np

from ..errors import FormatError
from .atomic import atomic_path
from .cloud import PointCloud
from .format import Format
from .nuscenes import looks_like_rings
from .outputs import label_destinations, label_path, label_targets
from .records import float_records

__all__ = ["FORMATS", "KITTI_TOLERANCE"]


def _read_kitti(path):
    a = float_records(path, ("x", "y", "z", "intensity"), "a KITTI .bin",
                      (5, " (a multiple of 20: a nuScenes frame? name it .pcd.bin, or --input-format pcd.bin)"))
    size = a.nbytes
    five = a.reshape(-1, 5) if size % 20 == 0 else None
    if five is not None and looks_like_rings(five[:, 4]) and not np.all(five[:, :3] == np.round(five[:, :3])):
        # the count fits both, and the fifth floats are rings among measured coordinates: never guessed
        raise FormatError(f"{path}: {size} bytes divide into KITTI's 4 floats a point and nuScenes' 5, and every "
                          "fifth float is a ring number: a nuScenes frame? name it .pcd.bin, or read it with "
                          "--input-format pcd.bin (format='.pcd.bin')")
    attrs = {"intensity": a[:, 3].copy()}
    lab = label_path(path)
    if lab is not None:  # SemanticKITTI: uint32, semantic class in the low 16 bits, instance in the high 16
        if os.path.getsize(lab) != 4 * len(a):
            raise FormatError(f"{lab}: {os.path.getsize(lab)} bytes, not 4 a point: not the labels for the "
                              f"{len(a)} points of {path}")
        words = np.fromfile(lab, dtype="<u4")
        if len(words) != len(a):
            raise FormatError(f"{lab}: {len(words)} labels for {len(a)} points of {path}")
        attrs["semantic"] = (words & 0xFFFF).astype(np.uint16)
        attrs["instance"] = (words >> 16).astype(np.uint16)
    return PointCloud(a[:, :3], attrs, np.zeros(3), {"labels": str(lab) if lab else None})


def _label_words(path, cloud) -> np.ndarray:
    """SemanticKITTI labels of a KITTI ``.bin``: little-endian uint32, semantic | instance << 16."""
    sem = np.asarray(cloud.attributes["semantic"])
    inst = np.asarray(cloud.attributes.get("instance", np.zeros(len(sem), np.uint32)))
    for name, v in (("semantic", sem), ("instance", inst)):
        if v.dtype.kind not in "iu" or (len(v) and (v.min() < 0 or v.max() > 0xFFFF)):
            raise FormatError(f"{path}: SemanticKITTI {name} labels must be integers in [0, 65535]")
    return ((sem.astype(np.uint32) & 0xFFFF) | (inst.astype(np.uint32) << 16)).astype("<u4")


#: Largest coordinate error (m) a KITTI ``.bin`` (float32) may add before :func:`write_cloud` warns.
KITTI_TOLERANCE = 1e-3


def _warn_kitti_precision(path, cloud, stacklevel: int = 3) -> None:
    """Warn when float32 storage moves a coordinate by more than :data:`KITTI_TOLERANCE`."""
    pts = np.asarray(cloud.points, np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return
    err = float(np.abs(pts.astype(np.float32).astype(np.float64) - pts).max())
    if err > KITTI_TOLERANCE:
        warnings.warn(f"{path}: KITTI .bin stores float32 coordinates: these (up to "
                      f"{np.abs(pts).max():.4g} m from 0) move by up to {err:.3g} m; write .las/.ply/.npz "
                      "to keep them, or subtract an offset first", stacklevel=stacklevel)


def _write_kitti(path, cloud, binary):
    dropped = sorted(k for k in cloud.attributes if k not in ("intensity", "semantic", "instance"))
    if dropped:
        warnings.warn(f"{path}: KITTI .bin holds x, y, z and intensity only; not written: {dropped}",
                      stacklevel=3)
    a = np.empty((len(cloud), 4), np.float32)
    a[:, :3] = cloud.points
    a[:, 3] = cloud.attributes.get("intensity", 0.0)
    a.tofile(path)


def _before(path, cloud):
    """The precision warning, and the labels' words checked before anything is written."""
    _warn_kitti_precision(path, cloud, stacklevel=4)
    if "semantic" in cloud.attributes:
        return _label_words(label_targets(path)[0], cloud)
    return None


def _after(path, words) -> None:
    written = label_destinations(path) if words is not None else []  # a link's: beside it and its file
    for dest in written:
        with atomic_path(dest) as tmp:
            words.tofile(tmp)
    for stale in label_targets(path)[len(written):]:  # an older file's labels: a reader would pair them
        if stale.is_file():                            # with this .bin
            stale.unlink()


FORMATS = (Format(".bin", _read_kitti, _write_kitti, before=_before, after=_after),)
