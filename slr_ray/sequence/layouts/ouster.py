"""An Ouster recording as a directory: range-image frames ``*.npz`` (one a frame, in natural order
of their names), the sensor's metadata ``*.json`` (its beam angles: the sensor card) and a
trajectory ``*poses*.txt`` in KITTI form (12 numbers a line, one a frame: the sensor's pose in the
world). Each frame is read by :func:`slr_ray.io.read_cloud` (the ``.npz`` reader gives the ring and
column of each pixel with a return).

An Ouster's points are in its *sensor* frame, whose origin lies below the *lidar* origin the beams
start from (the metadata's ``lidar_to_sensor_transform``: 36.18 mm up on an OS1): seen from the
sensor origin a beam's points are not at its elevation (0.4 deg off at 5 m, more than the 0.35 deg
between an OS1-128's beams). The layout moves each frame to the lidar origin (the translation of
that transform; the axes kept) and each pose with it, so the points are unchanged in the world and
every pulse starts where the beams do. The beam-origin offset (``lidar_origin_to_beam_origin_mm``,
15.8 mm out from the axis) is kept as the card's per-beam height, not moved.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ...errors import InputValueError
from ..poses import read_trajectory
from .base import FrameSource, Sequence, SequenceInputs, files_in

__all__ = ["OusterDirectory", "LAYOUT", "read_ouster_directory", "lidar_origin"]


def lidar_origin(metadata) -> np.ndarray:
    """Where the lidar origin lies in the sensor frame (m): the translation of the metadata's
    ``lidar_to_sensor_transform`` (16 numbers row-major, mm); zero where the file has none."""
    if metadata is None:
        return np.zeros(3)
    try:
        d = json.loads(Path(metadata).read_text())
    except (OSError, ValueError) as e:
        raise InputValueError(f"{metadata}: not readable as Ouster metadata JSON ({e})") from None
    t = d.get("lidar_to_sensor_transform") or (d.get("lidar_intrinsics") or {}).get("lidar_to_sensor_transform")
    if t is None:
        return np.zeros(3)
    m = np.asarray(t, np.float64).ravel()
    if m.shape != (16,) or not np.all(np.isfinite(m)):
        raise InputValueError(f"{metadata}: lidar_to_sensor_transform must be 16 finite numbers, got {m.shape}")
    return m.reshape(4, 4)[:3, 3] / 1000.0


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
        self.origin = lidar_origin(metadata)  # the lidar origin in the sensor frame (m)

    def frame(self, seq, i):
        """Frame ``i`` moved to the lidar origin (module docstring)."""
        pts, attrs = super().frame(seq, i)
        return pts - self.origin, attrs

    def trajectory(self, seq, path):
        """A trajectory of the sensor's poses, moved to the lidar origin as the frames are."""
        poses, how = super().trajectory(seq, path)
        return self.to_lidar(poses), how

    def to_lidar(self, poses):
        """Sensor poses as lidar poses: ``pose @ [I | origin]`` (the world points unchanged)."""
        shift = np.eye(4)
        shift[:3, 3] = self.origin
        return np.asarray(poses, np.float64) @ shift

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
        return {"metadata": None if self.metadata is None else str(self.metadata),
                "lidar_origin_m": [float(x) for x in self.origin]}


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
    if isinstance(trajectory, (list, tuple)):
        if len(trajectory) != 1:
            raise InputValueError(f"{root}: an Ouster directory takes one trajectory file, got {len(trajectory)}")
        trajectory = trajectory[0]
    if trajectory == "origins":
        raise InputValueError(f"{root}: its frames are each in their sensor's frame: poses 'origins' is for files "
                              "in one world frame")
    layout = OusterDirectory(metadata[0] if metadata else None)
    names = [f.stem for f in frames]
    source = trajectory if trajectory is not None else (poses[0] if poses else None)
    if source is None:
        return Sequence(frames, None, names, "none", root, input_format, layout, metadata)
    return Sequence(frames, layout.to_lidar(read_trajectory(source, len(frames))), names,
                    "trajectory" if trajectory is not None else Path(source).name, root, input_format, layout,
                    [source, *metadata])


LAYOUT = OusterDirectory
