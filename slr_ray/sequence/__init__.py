"""Sequences in, datasets out: frames of a drive or a campaign, their poses, their union.

``frames``
    reading a sequence (:func:`read_sequence`: the layout a path is in) and
    registering its frames; bad input refused naming the file and line.
``layouts``
    the layouts sequences come in, one module a layout (KITTI / SemanticKITTI,
    file lists, E57 scans, a LAS split by a scan field, PCD and Ouster
    directories), each a ``FrameSource`` with its ``detect``; the ``Sequence``.
``poses``
    trajectory and pose files: KITTI, TUM, pose files, ``calib.txt``'s ``Tr``,
    origins, CSV blocks.
``union``
    the accumulated primary: a window of frames in the world frame, each point
    with its source frame and origin, moving classes left out.
``estimators``
    one return per pulse from a union: nearest (SLR's rule), first-peak
    average, embree discs.
``rays``
    the ``rays`` estimator: the sensor's own rays (each laser's height and elevation, the sweep's
    motion) fitted from frames' points, each beam cast along its ray onto the union's planes.
``methods``
    the registry of sequence methods (one module a method: its options, its capabilities), which
    ``holdout`` and ``convert`` loop over.
``holdout``
    leave-one-out evaluation: each held-out frame re-simulated from the others.
``sources``
    each source frame's own sensor: see-through removal of moving objects
    without labels, embree discs from each frame's own pulse grid.
``convert``
    a sequence re-simulated as another sensor, written in the SemanticKITTI layout.
"""

from .convert import CONVERT_ESTIMATORS, convert_sequence, target_poses
from .estimators import ESTIMATORS, FPA_GAP, PulseReturns, estimate
from .frames import (Frame, Sequence, kitti_velodyne_poses, read_calib_tr, read_file_list,
                     read_kitti_layout, read_sequence, read_trajectory, register_chain, write_kitti_poses)
from .holdout import METHODS, evaluate_holdout, evaluate_sequence, mean_rows
from .sources import REMOVE_MOVING, SeeThrough
from .union import (MOVING_CLASSES, FrameCache, Keep, Union, accumulate, discs_of_frames, nearest_of_frames,
                    to_frame, window)

__all__ = ["CONVERT_ESTIMATORS", "REMOVE_MOVING", "SeeThrough", "discs_of_frames", "convert_sequence", "target_poses",
           "ESTIMATORS", "FPA_GAP", "PulseReturns", "estimate", "Frame",
           "Sequence", "kitti_velodyne_poses", "read_calib_tr", "read_file_list",
           "read_kitti_layout", "read_sequence", "read_trajectory", "register_chain", "write_kitti_poses",
           "METHODS", "evaluate_holdout", "evaluate_sequence", "mean_rows", "MOVING_CLASSES", "FrameCache",
           "Keep", "Union", "accumulate", "nearest_of_frames", "to_frame", "window"]
