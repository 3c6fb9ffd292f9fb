"""An E57 file of several scans: each scan a frame, its pose (rotation quaternion and translation)
the frame's: a frame's points are in its scanner's own axes at its origin, as the scanner recorded
them; the file read once a process. A scan without a pose (of two or more: a file of one scan is that
scan at the file's origin, as E57 reads an absent pose), or whose quaternion is not of norm 1, is
refused.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from ...errors import InputValueError
from ...io import read_e57_scans
from ..poses import check_pose, quaternion_rotation
from .base import FrameSource, Sequence, SequenceInputs

__all__ = ["E57Scans", "LAYOUT", "read_e57_sequence"]


@lru_cache(maxsize=1)
def _e57_scans(path: str, mtime: float) -> list:
    """Every scan of an E57 file, read once a process (a window reads its scans again and again)."""
    return read_e57_scans(path)


class E57Scans(FrameSource):
    """The scans of one E57 file (module docstring)."""

    name = "e57"
    what = "an E57 file of several scans, each with its pose"

    @classmethod
    def detect(cls, path) -> float:
        return 1.0 if Path(path).is_file() and Path(path).suffix.lower() == ".e57" else 0.0

    @classmethod
    def open(cls, path, inputs: SequenceInputs) -> Sequence:
        if (inputs.input_format or ".e57").lstrip(".").lower() != "e57":
            raise InputValueError(f"{path}: an E57 file read as {inputs.input_format}")
        inputs.refuse(path, "E57", "trajectory", "origins", "scan_field", why="its scans carry their poses")
        return read_e57_sequence(path)

    def fields(self, seq, i):
        return frozenset(_e57_scans(str(seq.paths[i]), os.path.getmtime(seq.paths[i]))[i].attributes)  # read once

    def frame(self, seq, i):
        c = _e57_scans(str(seq.paths[i]), os.path.getmtime(seq.paths[i]))[i]
        T = seq.poses[i]  # into the scan's own axes at its origin: R^T (p - t)
        return (c.points - T[:3, 3]) @ T[:3, :3], dict(c.attributes)


def read_e57_sequence(path) -> Sequence:
    """The scans of one E57 file as a sequence (module docstring)."""
    p = Path(path)
    scans = _e57_scans(str(p), os.path.getmtime(p))
    poses = np.repeat(np.eye(4)[None], len(scans), 0)
    for i, c in enumerate(scans):
        if c.origin is None and len(scans) == 1:  # one scan: at the file's origin (E57 reads no pose so)
            continue
        if c.origin is None:
            raise InputValueError(f"{p}: scan {i} has no pose (no scanner origin): a sequence needs each scan's")
        poses[i, :3, 3] = c.origin
        q = c.meta.get("e57_quaternion")
        if q is not None:  # (w, x, y, z) as the file holds it: pye57's matrix normalises it first
            quaternion_rotation(q[1], q[2], q[3], q[0], f"{p}, scan {i}'s pose")
        if "e57_rotation" in c.meta:
            rot = np.column_stack([c.meta["e57_rotation"], np.zeros(3)])
            poses[i, :3, :3] = check_pose(rot, f"{p}, scan {i}'s pose")[:3, :3]
    return Sequence([p] * len(scans), poses, [f"{i:06d}" for i in range(len(scans))], "e57 scan poses", None,
                    None, E57Scans())


LAYOUT = E57Scans
