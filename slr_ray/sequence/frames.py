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

from ..errors import InputValueError
from ..evaluate import register
from .layouts import SequenceInputs, detect
from .layouts.base import Frame, FrameSource, Sequence, layout_class
from .layouts.e57 import read_e57_sequence
from .layouts.files import read_file_list
from .layouts.kitti import read_kitti_layout
from .layouts.scans import read_split_scans
from .poses import (POSE_TOLERANCE, kitti_velodyne_poses, read_calib_tr, read_origins, read_pose_files,
                    read_trajectory, write_kitti_poses)

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
    ``calib.txt``'s ``Tr``)."""
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


def register_chain(seq: Sequence, min_fitness: float = 0.3, progress: bool = False) -> tuple[Sequence, list]:
    """Poses by registering each frame to the one before (:func:`slr_ray.evaluate.register`),
    chained from frame 0 at the identity. Returns the sequence with those poses and each
    pair's registration (dicts)."""
    if len(seq) < 2:
        raise InputValueError("registration needs two frames or more")
    poses = [np.eye(4)]
    regs = []
    prev = seq.with_poses(np.repeat(np.eye(4)[None], len(seq), 0), "identity")
    last = prev.read(0).points
    for i in tqdm(range(1, len(seq)), desc="registering", disable=not progress):
        cur = prev.read(i).points
        reg = register(cur, last)
        if not reg.fitness >= min_fitness:
            raise InputValueError(f"{seq.paths[i]}: registered to {seq.paths[i - 1]} with fitness {reg.fitness:.3f} "
                                  f"< {min_fitness:g}: do the frames overlap? Give the poses instead")
        poses.append(poses[-1] @ reg.transform)
        regs.append(reg.to_dict() | {"frame": i, "to": i - 1})
        last = cur
    return seq.with_poses(np.stack(poses), "register"), regs
