"""A directory of PCD frames, each in its sensor's frame (a Hesai or Ouster unit's recording as
PCL writes it), in natural order of their names (``full9`` before ``full10``; timestamps in time
order), with the poses of a CSV of 4 x 4 world-from-lidar blocks if the directory holds one (BALM's
``alidarPose.csv``: a matrix row a line, the fourth row's last number a timestamp): one block a frame
in order where there are as many; else frame ``fullN.pcd`` takes block N. Without a CSV, give
``--poses`` or ``--register``. Each frame is read by :func:`slr_ray.io.read_cloud` (ring and
timestamp fields as the PCD reader gives them).
"""

from __future__ import annotations

from pathlib import Path

from ...errors import InputValueError
from ..poses import frame_stamps, read_pose_blocks, read_trajectory
from .base import FrameSource, Sequence, SequenceInputs, files_in, one_trajectory, trailing_number

__all__ = ["PcdDirectory", "LAYOUT", "read_pcd_directory"]


class PcdDirectory(FrameSource):
    """A directory of ``.pcd`` frames and an optional pose CSV (module docstring)."""

    name = "pcd-directory"
    what = "a directory of .pcd frames (and a CSV of 4 x 4 poses, or --poses, or --register)"

    @classmethod
    def detect(cls, path) -> float:
        return 1.0 if files_in(path, ".pcd") else 0.0

    @classmethod
    def open(cls, path, inputs: SequenceInputs) -> Sequence:
        inputs.refuse(path, "PCD directory", "origins", "scan_field", why="its frames are each in their sensor's "
                                                                          "frame")
        return read_pcd_directory(path, inputs.trajectory, inputs.input_format)


def _csv_poses(csv: Path, frames: list):
    blocks = read_pose_blocks(csv)
    if len(blocks) == len(frames):
        return blocks, f"{csv.name} (one pose a frame, in order)"
    numbers = [trailing_number(f) for f in frames]
    for f, n in zip(frames, numbers):
        if n is None or n >= len(blocks):
            raise InputValueError(f"{csv}: {len(blocks)} poses for {len(frames)} frames, and {f.name} names no pose "
                                  f"of them by its number (frame N takes pose N, from 0)")
    return blocks[numbers], f"{csv.name} (pose N for frame ...N.pcd)"


def read_pcd_directory(root, trajectory=None, input_format=None) -> Sequence:
    """A directory of PCD frames as a sequence (module docstring)."""
    root = Path(root)
    frames = files_in(root, ".pcd")
    if not frames:
        raise InputValueError(f"{root}: no .pcd frames")
    csvs = files_in(root, ".csv")
    if len(csvs) > 1:
        raise InputValueError(f"{root}: {len(csvs)} CSV files ({', '.join(c.name for c in csvs)}): which holds the "
                              "poses? Give --poses")
    names = [f.stem for f in frames]
    trajectory = one_trajectory(root, trajectory, "a PCD directory")
    if trajectory is not None:
        return Sequence(frames, read_trajectory(trajectory, len(frames), frame_stamps(frames)), names, "trajectory", root, input_format,
                        PcdDirectory(), [trajectory])
    if csvs:
        poses, source = _csv_poses(csvs[0], frames)
        return Sequence(frames, poses, names, source, root, input_format, PcdDirectory(), csvs)
    return Sequence(frames, None, names, "none", root, input_format, PcdDirectory())


LAYOUT = PcdDirectory
