"""Source frames recorded from (almost) the target's pose vote on its pulses (``embree-rays``' rule, #46).

A unit that stands still fires its next scan's pulses along its last scan's: whether a pulse returns
at all is then known from the source frames fired from the same place, pulse by pulse, where a
surface built from them (a ring mesh, its skirts) only says where a ray would meet it. A return in a
pulse none of those frames returned in is left out (on a standing Pandar64 the mesh's returns in such
pulses, 1 % of them, were far: 0.011 m² of the Chamfer distance's 0.03). Frames farther than
:data:`SAME_POSE_M` from the target (a moving vehicle: KITTI's 0.7 m a frame, the Ouster's 0.25 m)
do not vote: their pulses are other directions.
"""

from __future__ import annotations

import numpy as np

from .estimators import PulseReturns

__all__ = ["SAME_POSE_M", "keep_voted", "pulses_voted", "same_pose_frames"]

#: a source frame whose origin lies within this (m) of the target's was recorded from its pose: its pulses
#: are the target's (a standing Pandar64's frames lie 0.5 mm apart; KITTI's 0.7 m, the OS1-128's 0.25 m)
SAME_POSE_M = 0.02


def same_pose_frames(origins, origin, reach: float = SAME_POSE_M) -> np.ndarray:
    """The positions (in ``origins``, the source frames' scanner origins, world) of the frames recorded
    within ``reach`` of ``origin`` (the target's)."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    return np.flatnonzero(np.linalg.norm(o - np.asarray(origin, np.float64)[None, :3], axis=1) <= reach)


def pulses_voted(points, source, frames, pattern) -> np.ndarray:
    """The pulses of ``pattern`` (sorted flat ids) that a point of ``points`` (the target's frame) from one
    of ``frames`` (positions in ``source``, each point's frame) falls in."""
    pick = np.isin(np.asarray(source), np.asarray(frames))
    keys, _ = pattern.pulse_ids(np.asarray(points, np.float64)[pick], np.zeros(3))
    return np.unique(keys[keys >= 0])


def keep_voted(ret: PulseReturns, points, source, origins, origin, pattern, reach: float | None = None) -> PulseReturns:
    """``ret`` without the returns in pulses that no source frame recorded within ``reach`` of ``origin``
    returned in (module docstring; ``points`` the union in the target's frame, ``source`` each point's
    frame, a position in ``origins``; ``reach`` default :data:`SAME_POSE_M`); ``ret`` itself where no frame was."""
    same = same_pose_frames(origins, origin, SAME_POSE_M if reach is None else reach)
    if not len(same) or not len(ret):
        return ret
    voted = pulses_voted(points, source, same, pattern)
    keep = np.isin(ret.keys, voted)
    if keep.all():
        return ret
    return PulseReturns(ret.keys[keep], ret.ranges[keep], ret.points[keep], ret.index[keep])
