"""One file holding several scans in one world frame (a campaign's LAS/LAZ): each value of a
per-point field (LAS ``point_source_id``, or any attribute the reader gives) a frame, in ascending
order of the value; each scan's scanner origin a line of a text file, in that order. A frame's
points are moved to its origin when read (its axes the world's); the file read once a process.
Chosen by the scan field (``--scan-field``), never detected.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from ...errors import InputValueError
from ...io import read_cloud
from ..poses import read_origins
from .base import FrameSource, Sequence, SequenceInputs

__all__ = ["SplitScans", "LAYOUT", "read_split_scans"]


@lru_cache(maxsize=1)
def _whole_cloud(path: str, mtime: float, input_format):
    """A file of several scans, read once a process (each frame is a part of it)."""
    return read_cloud(path, input_format, allow_empty=False)


class SplitScans(FrameSource):
    """One file split into scans by the per-point ``field``; ``scan_ids`` its values, a frame each."""

    name = "scan-field"
    what = "one file of several scans in one world frame, split by --scan-field with --origins"

    def __init__(self, field: str, scan_ids):
        self.field = field
        self.scan_ids = list(scan_ids)

    @classmethod
    def open(cls, path, inputs: SequenceInputs) -> Sequence:
        paths = [path] if isinstance(path, (str, Path)) else list(path)
        if len(paths) != 1 or inputs.origins is None or inputs.trajectory is not None:
            raise InputValueError("a scan field splits one file of several scans: give one file and --origins "
                                  "(each scan's scanner origin), no --poses")
        return read_split_scans(paths[0], inputs.scan_field, inputs.origins, inputs.input_format)

    def frame(self, seq, i):
        whole = _whole_cloud(str(seq.paths[i]), os.path.getmtime(seq.paths[i]), seq.input_format)
        mine = np.asarray(whole.attributes[self.field]) == self.scan_ids[i]
        return whole.points[mine] - seq.poses[i][:3, 3], {k: np.asarray(v)[mine] for k, v in whole.attributes.items()}

    def to_dict(self) -> dict:
        return {"split": self.field, "scan_ids": self.scan_ids}


def read_split_scans(path, field: str, origins, input_format: str | None = None) -> Sequence:
    """One file of several scans as a sequence (module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise InputValueError(f"{p}: no such file")
    c = _whole_cloud(str(p), os.path.getmtime(p), input_format)
    if field not in c.attributes or np.ndim(c.attributes[field]) != 1:
        have = sorted(k for k, v in c.attributes.items() if np.ndim(v) == 1)
        raise InputValueError(f"{p}: no per-point field {field!r} to split its scans by (it has: "
                              f"{', '.join(have) or 'none'})")
    ids = np.unique(np.asarray(c.attributes[field]))
    poses = np.repeat(np.eye(4)[None], len(ids), 0)
    try:
        poses[:, :3, 3] = read_origins(origins, len(ids))
    except InputValueError as exc:
        raise InputValueError(f"{exc} ({p} holds {len(ids)} scans by its field {field!r})") from None
    return Sequence([p] * len(ids), poses, [f"{i:06d}" for i in range(len(ids))], "origins file", None, input_format,
                    SplitScans(field, ids.tolist()), [origins])


LAYOUT = SplitScans
