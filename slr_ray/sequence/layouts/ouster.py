"""An Ouster recording as a directory: range-image frames ``*.npz`` (one a frame, in natural order
of their names), the sensor's metadata ``*.json`` (its beam angles: the sensor card) and a
trajectory ``*poses*.txt`` in KITTI form (12 numbers a line, one a frame: the sensor's pose in the
world). Each frame is read by :func:`slr_ray.io.read_cloud` (the ``.npz`` reader gives the ring and
column of each pixel with a return).
"""

from __future__ import annotations

from pathlib import Path

from ...errors import InputValueError
from ..poses import read_trajectory
from .base import FrameSource, Sequence, SequenceInputs, files_in, one_trajectory

__all__ = ["OusterDirectory", "LAYOUT", "read_ouster_directory"]


def _parts(root: Path):
    frames = files_in(root, ".npz")
    metadata = files_in(root, ".json")
    poses = [p for p in files_in(root, ".txt") if "poses" in p.name.lower()]
    return frames, metadata, poses


class OusterDirectory(FrameSource):
    """An Ouster directory (module docstring); ``metadata`` its sensor metadata JSON."""

    name = "ouster-directory"
    what = "a directory of Ouster .npz frames, the sensor's metadata .json and a *poses*.txt trajectory"

    def __init__(self, metadata=None):
        self.metadata = metadata

    @classmethod
    def detect(cls, path) -> float:
        frames, metadata, poses = _parts(Path(path))
        return 1.0 if frames and metadata and poses else 0.0

    @classmethod
    def open(cls, path, inputs: SequenceInputs) -> Sequence:
        inputs.refuse(path, "Ouster directory", "origins", "scan_field", why="its frames are each in their "
                                                                             "sensor's frame")
        return read_ouster_directory(path, inputs.trajectory, inputs.input_format)

    def to_dict(self) -> dict:
        return {"metadata": None if self.metadata is None else str(self.metadata)}


def read_ouster_directory(root, trajectory=None, input_format=None) -> Sequence:
    """An Ouster directory as a sequence (module docstring); ``trajectory`` instead of its own."""
    root = Path(root)
    frames, metadata, poses = _parts(root)
    for what, found in (("a *poses*.txt trajectory", poses), ("a metadata .json", metadata)):
        if len(found) > 1:
            raise InputValueError(f"{root}: {len(found)} files could be {what} "
                                  f"({', '.join(p.name for p in found)}): keep one")
    if not frames:
        raise InputValueError(f"{root}: no .npz frames")
    trajectory = one_trajectory(root, trajectory, "an Ouster directory")
    layout = OusterDirectory(metadata[0] if metadata else None)
    names = [f.stem for f in frames]
    source = trajectory if trajectory is not None else (poses[0] if poses else None)
    if source is None:
        return Sequence(frames, None, names, "none", root, input_format, layout, metadata)
    return Sequence(frames, read_trajectory(source, len(frames)), names,
                    "trajectory" if trajectory is not None else Path(source).name, root, input_format, layout,
                    [source, *metadata])


LAYOUT = OusterDirectory
