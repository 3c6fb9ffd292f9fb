"""KITTI odometry / SemanticKITTI: a directory holding ``velodyne/NNNNNN.bin`` (numbered from
000000 without gaps), optional ``labels/NNNNNN.label`` (one uint32 a point), ``poses.txt`` (one line
a frame, 12 numbers: the first three rows of the 4 x 4 pose of the *left camera* in the world) and
``calib.txt`` whose ``Tr`` line is the velodyne-to-camera transform. The velodyne pose of frame
``i`` is ``Tr^-1 P_i Tr``. Without ``calib.txt`` ``Tr`` is the identity (the poses are the
velodyne's own); a ``calib.txt`` with no ``Tr`` line, or two, is refused.

A trajectory given for the directory (``--poses``, ``--target-poses``) in KITTI form is taken as
``poses.txt`` is, the left camera's, moved to the velodyne by the same ``Tr``; in TUM form, as the
velodyne's own. Which one is said (a note).
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np

from ...errors import FormatError, InputValueError, SlrNote
from ..poses import kitti_velodyne_poses, read_calib_tr, read_trajectory, trajectory_form
from .base import FrameSource, Sequence, SequenceInputs, one_trajectory

__all__ = ["KittiDirectory", "LAYOUT", "read_kitti_layout"]

_NUMBERED = re.compile(r"^(\d+)\.bin$")


def _check_sizes(bins) -> None:
    for b in bins:
        if os.path.getsize(b) % 16:
            raise FormatError(f"{b}: {os.path.getsize(b)} bytes, not whole points (16 bytes a point: float32 x, y, z, "
                              "intensity): truncated, or not a KITTI .bin")


def _check_labels(bins, labels_dir: Path) -> None:
    for b in bins:
        lab = labels_dir / (b.stem + ".label")
        if lab.is_file() and os.path.getsize(lab) * 4 != os.path.getsize(b):
            raise FormatError(f"{lab}: {os.path.getsize(lab) // 4} labels for the {os.path.getsize(b) // 16} "
                              f"points of {b}")


class KittiDirectory(FrameSource):
    """A KITTI / SemanticKITTI sequence directory (module docstring); ``tr`` its ``calib.txt``'s ``Tr``
    (None: no ``calib.txt``)."""

    name = "kitti"
    what = "a KITTI / SemanticKITTI directory (velodyne/NNNNNN.bin, labels/, poses.txt, calib.txt)"

    def __init__(self, tr=None, calib=None):
        self.tr = None if tr is None else np.asarray(tr, np.float64)
        self.calib = calib

    @classmethod
    def detect(cls, path) -> float:
        vel = Path(path) / "velodyne"
        return 1.0 if vel.is_dir() and any(_NUMBERED.match(p.name) for p in vel.iterdir()) else 0.0

    @classmethod
    def open(cls, path, inputs: SequenceInputs) -> Sequence:
        fmt = inputs.input_format
        if fmt is not None and str(fmt).lower().lstrip(".") != "bin":  # never ignored unsaid
            raise InputValueError(f"{path}: a KITTI directory's frames are velodyne/NNNNNN.bin, read as such: "
                                  f"--input-format {fmt!r} does not apply (drop it)")
        inputs.refuse(path, "KITTI", "origins", "scan_field", why="its frames are .bin files, each in its sensor's frame")
        seq = read_kitti_layout(path)
        traj = one_trajectory(path, inputs.trajectory, "a KITTI sequence")
        if traj is not None:
            poses, source = seq.layout.trajectory(seq, traj)
            seq = seq.with_poses(poses, source, [traj])
        return seq

    def trajectory(self, seq, path) -> tuple[np.ndarray, str]:
        poses = read_trajectory(path, len(seq))
        if self.tr is not None and trajectory_form(path) == "kitti":
            warnings.warn(f"{path}: KITTI-form poses taken as the left camera's, as {seq.root}/poses.txt is, and "
                          f"moved to the velodyne by {self.calib}'s Tr", SlrNote, stacklevel=3)
            return kitti_velodyne_poses(poses, self.tr), "trajectory + calib.txt Tr"
        why = "TUM form" if self.tr is not None else f"no calib.txt in {seq.root}"
        warnings.warn(f"{path}: poses taken as the velodyne's own ({why})", SlrNote, stacklevel=3)
        return poses, "trajectory"

    def to_dict(self) -> dict:
        return {"calib": None if self.calib is None else str(self.calib)}


def read_kitti_layout(root) -> Sequence:
    """A KITTI odometry / SemanticKITTI sequence directory with its own poses (module docstring)."""
    root = Path(root)
    vel = root / "velodyne"
    if not vel.is_dir():
        raise InputValueError(f"{root}: no velodyne/ directory (not a KITTI sequence)")
    found = []
    for p in vel.iterdir():
        m = _NUMBERED.match(p.name)
        if m:
            found.append((int(m.group(1)), p))
    if not found:
        raise InputValueError(f"{vel}: no NNNNNN.bin frames")
    found.sort()
    for k, (num, p) in enumerate(found):
        if num != k:
            raise InputValueError(f"{p}: frame number {num} where {k} was expected (frames must be numbered "
                                  f"from 0 without gaps)")
    bins = [p for _, p in found]
    _check_sizes(bins)
    if (root / "labels").is_dir():
        _check_labels(bins, root / "labels")
    calib = root / "calib.txt"
    layout = KittiDirectory(read_calib_tr(calib), calib) if calib.is_file() else KittiDirectory()
    poses, source, files = None, "none", []
    if (root / "poses.txt").is_file():
        cam = read_trajectory(root / "poses.txt", len(bins))
        poses = kitti_velodyne_poses(cam, np.eye(4) if layout.tr is None else layout.tr)
        source = "poses.txt" + (" + calib.txt Tr" if calib.is_file() else "")
        files = [root / n for n in ("poses.txt", "calib.txt") if (root / n).is_file()]
    return Sequence(bins, poses, [p.stem for p in bins], source, root, None, layout, files)


LAYOUT = KittiDirectory
