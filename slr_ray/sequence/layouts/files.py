"""A list of frame files, in the order given: any format :func:`slr_ray.io.read_cloud` reads.

Each frame in its own sensor's frame, with a trajectory file in KITTI form (12 numbers a line) or
TUM form (``time x y z qx qy qz qw``), one pose a frame (a TUM file of more or fewer poses than
frames named by their times, ``1630577758.569490.pcd``: each frame the pose of its time, within
1 ms), or one pose file a frame
(:func:`~slr_ray.sequence.poses.read_pose_files`); or no poses at all, to be found by registration.

Or the files in one world frame (:class:`WorldFiles`), each frame moved to its scanner's origin
when read (its axes the world's): the origins a text file gives (``x y z`` a line), or
``poses="origins"``, those the files record (``.npz`` origin, ``.pcd`` VIEWPOINT, ``.e57`` pose; an
E57 pose's rotation gives the frame its scanner's axes, as an E57 of several scans does).
A file that records none, or files that all record 0, 0, 0 (the readers' default), are refused.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import InputValueError
from ...io import read_cloud
from ..poses import check_pose, frame_stamps, read_origins, read_pose_files, read_trajectory
from .base import FrameSource, Sequence, SequenceInputs

__all__ = ["FileList", "WorldFiles", "LAYOUT", "read_file_list", "frame_files"]


def frame_files(paths) -> list:
    """``paths`` as Paths, each an existing file named once."""
    files = [Path(p) for p in paths]
    if not files:
        raise InputValueError("no frames given")
    seen = {}
    for p in files:
        if not p.exists():
            raise InputValueError(f"{p}: no such file or directory")
        if p.is_dir():
            raise InputValueError(f"{p} is a directory: give one sequence directory, or frame files")
        r = p.resolve()
        if r in seen:
            raise InputValueError(f"{p}: named twice in the sequence (as {seen[r]})")
        seen[r] = p
    return files


class FileList(FrameSource):
    """Frame files each in its sensor's frame (module docstring)."""

    name = "files"
    what = "frame files in order, each in its sensor's frame, with --poses (or --register)"

    @classmethod
    def detect(cls, path) -> float:
        return 0.1 if Path(path).is_file() else 0.0  # one file: a sequence of one frame, unless a layout claims it

    @classmethod
    def open(cls, path, inputs: SequenceInputs) -> Sequence:
        inputs.refuse(path, "file list", "scan_field", why="a scan field splits one file of several scans")
        paths = [path] if isinstance(path, (str, Path)) else path
        return read_file_list(paths, inputs.trajectory, inputs.input_format, inputs.origins)


class WorldFiles(FrameSource):
    """Frame files in one world frame, each moved to its scanner's origin (its pose's translation)."""

    name = "world-files"
    what = "frame files in one world frame, with --origins FILE or --poses origins"

    def frame(self, seq, i):
        c = read_cloud(seq.paths[i], seq.input_format, allow_empty=False)
        T = seq.poses[i]  # its axes the world's, or an E57 pose's rotation's (poses 'origins'): R^T (p - t)
        own = c.points - T[:3, 3]
        return (own if np.array_equal(T[:3, :3], np.eye(3)) else own @ T[:3, :3]), dict(c.attributes)

    def trajectory(self, seq, path):
        raise InputValueError(f"{path}: frames in one world frame are placed by their origins, not a trajectory")


def _recorded_origins(files, input_format, rotations=None) -> np.ndarray:
    """The scanner origin each file records; one that records none refused, as are two or more at
    exactly 0, 0, 0 (the readers' default where a file holds no origin: a .bin, a PCD's VIEWPOINT).
    ``rotations`` (an ``(n, 3, 3)`` array): each file's recorded axes set there (an E57 pose's rotation,
    as the E57 layout takes a scan's; it was dropped: the scan taken in the world's axes)."""
    out = np.zeros((len(files), 3))
    for i, p in enumerate(files):
        c = read_cloud(p, input_format, allow_empty=False)
        if c.origin is None:
            raise InputValueError(f"{p}: records no scanner origin (poses 'origins' needs one in every file: "
                                  ".npz origin, .pcd VIEWPOINT, .e57 pose)")
        out[i] = np.asarray(c.origin, np.float64)
        if rotations is not None and c.meta.get("e57_rotation") is not None:
            rot = np.column_stack([c.meta["e57_rotation"], np.zeros(3)])
            rotations[i] = check_pose(rot, f"{p}'s E57 pose")[:3, :3]
    at_zero = np.flatnonzero(~out.any(axis=1))
    if len(at_zero) > 1 or len(at_zero) == len(files):
        raise InputValueError(f"{files[at_zero[0]]}: records no scanner origin (0, 0, 0, as {len(at_zero)} of the "
                              f"{len(files)} files: the readers' default where a file holds none): poses 'origins' "
                              "needs each scanner's position (.npz origin, .pcd VIEWPOINT, .e57 pose); give "
                              "--origins FILE or a trajectory")
    return out


def read_file_list(paths, trajectory=None, input_format: str | None = None, origins=None) -> Sequence:
    """Frames from a list of files, in the order given, with an optional trajectory file, or a
    list of pose files (one a frame); or ``trajectory="origins"`` or an ``origins`` file: the
    files hold one world frame (module docstring)."""
    files = frame_files(paths)
    names = [f"{i:06d}" for i in range(len(files))]
    if isinstance(trajectory, (list, tuple)) and len(trajectory) == 1:
        trajectory = trajectory[0]
    if origins is not None or trajectory == "origins":  # files in one world frame
        if origins is not None and trajectory is not None:
            raise InputValueError("give the frames' poses or their origins, not both")
        poses = np.repeat(np.eye(4)[None], len(files), 0)
        if origins is not None:
            poses[:, :3, 3] = read_origins(origins, len(files))
            return Sequence(files, poses, names, "origins file", None, input_format, WorldFiles(), [origins])
        rotations = poses[:, :3, :3].copy()
        poses[:, :3, 3] = _recorded_origins(files, input_format, rotations)
        poses[:, :3, :3] = rotations
        return Sequence(files, poses, names, "origins", None, input_format, WorldFiles())
    if isinstance(trajectory, (list, tuple)):  # one pose file a frame
        if len(trajectory) != len(files):
            raise InputValueError(f"{len(trajectory)} pose files for {len(files)} frames (one a frame, in order)")
        return Sequence(files, read_pose_files(trajectory), names, "pose files", None, input_format, FileList(),
                        trajectory)
    if trajectory is not None:
        return Sequence(files, read_trajectory(trajectory, len(files), frame_stamps(files)), names, "trajectory", None, input_format,
                        FileList(), [trajectory])
    return Sequence(files, None, names, "none", None, input_format, FileList())


LAYOUT = FileList
