"""A sequence of LiDAR frames and their poses, read from the layouts real data comes in.

:func:`read_sequence` is the entry: it opens a path in the layout :func:`.layouts.detect`
finds (or the one named), a list of files as a file list, one file with a scan field as its
scans. The layouts are :mod:`slr_ray.sequence.layouts`' modules (KITTI / SemanticKITTI
directories, file lists with a trajectory or origins, E57 files of several scans, LAS/LAZ
split by a scan field, PCD and Ouster directories); the poses and trajectory files
:mod:`slr_ray.sequence.poses`' readers. The old names of both are importable from here.

Every pose is a sensor-to-world rigid transform, float64. Bad input is refused
before anything is read beyond the headers, each error one line naming the
file (and the line): a poses file with fewer or more lines than frames, or lines of
both forms, a non-rigid or NaN pose, a calib without Tr (or with two), gaps in frame
numbers, a labels file of another length than its frame, a path that does not exist,
a directory of two layouts (name one).

Poses by registration: :func:`register_chain`.
"""

from __future__ import annotations

import os

import numpy as np
from tqdm import tqdm

from ..errors import InputTypeError, InputValueError
from ..registration import check_registration, register
from .layouts import SequenceInputs, detect
from .layouts.base import Frame, FrameSource, Sequence, layout_class
from .layouts.e57 import read_e57_sequence
from .layouts.files import read_file_list
from .layouts.kitti import read_kitti_layout
from .layouts.scans import read_split_scans
from .poses import (POSE_TOLERANCE, check_pose, kitti_velodyne_poses, read_calib_tr, read_origins,
                    read_pose_files, read_trajectory, write_kitti_poses)

__all__ = ["Sequence", "Frame", "FrameSource", "read_sequence", "read_kitti_layout", "read_file_list",
           "read_trajectory", "read_calib_tr", "read_pose_files", "read_e57_sequence", "read_origins",
           "read_split_scans", "kitti_velodyne_poses", "write_kitti_poses", "register_chain", "POSE_TOLERANCE"]


def read_sequence(source, trajectory=None, input_format: str | None = None, origins=None,
                  scan_field: str | None = None, layout: str | None = None) -> Sequence:
    """A sequence: one path in the layout it is in (:func:`.layouts.detect`; or ``layout``, a
    registered layout's name), or a list of frame files (with a trajectory, pose files, or
    ``origins``: a text file of each frame's scanner origin for files in one world frame); or one
    file of several scans in one world frame, split by the per-point ``scan_field`` with
    ``origins`` (:func:`read_split_scans`). ``trajectory`` replaces a layout's own poses (a
    KITTI directory's in KITTI form taken as its ``poses.txt`` is: the camera's, moved by
    ``calib.txt``'s ``Tr``), as does an ``(n, 4, 4)`` array of the frames' sensor poses (one a frame,
    rigid: :func:`pose_array`); any other kind of ``trajectory`` is refused (TypeError)."""
    if isinstance(trajectory, np.ndarray):
        if origins is not None:
            raise InputValueError("give the frames' poses or their origins, not both")
        return read_sequence(source, None, input_format, origins, scan_field, layout).with_poses(
            pose_array(trajectory), "poses array")
    if not (trajectory is None or isinstance(trajectory, (str, os.PathLike))
            or isinstance(trajectory, (list, tuple)) and all(isinstance(t, (str, os.PathLike)) for t in trajectory)):
        raise InputTypeError(f"trajectory must be a file, a list of pose files, 'origins' or an (n, 4, 4) array "
                             f"of poses, got {type(trajectory).__name__}")
    src = [source] if isinstance(source, (str, os.PathLike)) else list(source)
    inputs = SequenceInputs(trajectory, input_format, origins, scan_field)
    if layout is None:
        if scan_field is not None:
            layout = "scan-field"
        elif len(src) != 1:
            layout = "files"
        else:
            layout = detect(src[0])
    cls = layout_class(layout)
    return cls.open(src[0] if len(src) == 1 else src, inputs)


def pose_array(poses) -> np.ndarray:
    """``poses`` (an ``(n, 4, 4)`` array of sensor poses, :func:`read_sequence`'s ``trajectory``) as
    float64, each a rigid pose (:func:`~slr_ray.sequence.poses.check_pose`: real, finite, a rotation)."""
    P = np.asarray(poses)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or not len(P):
        raise InputValueError(f"trajectory: an array of poses must be (n, 4, 4), one a frame, got shape {P.shape}")
    return np.stack([check_pose(T, f"trajectory: pose {i} of the array") for i, T in enumerate(P)])


def register_chain(seq: Sequence, min_fitness: float | None = None, progress: bool = False,
                   accept_registration: bool = False) -> tuple[Sequence, list]:
    """Poses by registering each frame to the one before (:func:`slr_ray.registration.register`),
    chained from frame 0 at the identity. Returns the sequence with those poses and each
    pair's registration (dicts).

    Each registration passes the gate (:func:`slr_ray.registration.check_registration`: fitness,
    reverse fitness, inlier RMSE, tilt; ``min_fitness`` replaces the fitness bound) or is refused
    (InputValueError naming the frames, the failed check, its figure and bound), unless
    ``accept_registration``: a pose chained from a failed registration moves every frame after it.
    """
    if len(seq) < 2:
        raise InputValueError("registration needs two frames or more")
    if not isinstance(accept_registration, (bool, np.bool_)):
        raise InputValueError(f"accept_registration must be True or False, got {accept_registration!r}")
    if min_fitness is not None and not (isinstance(min_fitness, (int, float)) and 0 <= min_fitness <= 1):
        raise InputValueError(f"min_fitness must be a number in [0, 1] (a share of a frame's points), got "
                              f"{min_fitness!r}")
    bounds = {} if min_fitness is None else {"min_fitness": min_fitness}
    poses = [np.eye(4)]
    regs = []
    prev = seq.with_poses(np.repeat(np.eye(4)[None], len(seq), 0), "identity")
    last = prev.read(0).points
    for i in tqdm(range(1, len(seq)), desc="registering", disable=not progress):
        cur = prev.read(i).points
        reg = register(cur, last)
        if not accept_registration:
            check_registration(reg, bounds, what=f"frame {i} ({seq.paths[i]}) registered to frame {i - 1} "
                                                 f"({seq.paths[i - 1]})",
                               remedy="give the poses (--poses FILE), or chain this pose anyway "
                                      "(accept_registration=True, --accept-registration)")
        poses.append(poses[-1] @ reg.transform)
        regs.append(reg.to_dict() | {"frame": i, "to": i - 1})
        last = cur
    return seq.with_poses(np.stack(poses), "register"), regs
