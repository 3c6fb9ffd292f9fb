"""Motion during a sweep: each column of a spinning sensor fires from its own pose.

A sweep takes time (100 ms at 10 Hz); a sensor on a moving vehicle fires
its first column from one pose and its last from another. Poses are
sensor-to-world rigid transforms, ``(4, 4)``: the sensor's axes (the
pattern's directions) and its origin in the cloud's coordinates. Given the
poses at the start and the end of the sweep, or a trajectory (``k >= 2``
poses evenly spaced in time over the sweep), column ``h`` of ``n`` fires at
time ``(h + 1/2) / n`` of the sweep (columns in azimuth order, from the
pattern's azimuth 0, counter-clockwise) from the pose interpolated there:
translation linearly, rotation by spherical linear interpolation (slerp).
``sectors`` groups columns that share one pose (the mean time of their
columns): every column its own with the embree backend, a few with
binning, which scans the whole cloud once per sector.

The result is written in the sensor frame at the end of the sweep, as
drivers write a frame: ``p_end = R_end^T (p_world - t_end)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..errors import InputValueError

__all__ = ["pose", "as_poses", "interpolate_poses", "column_sectors", "to_frame"]


def pose(translation=(0.0, 0.0, 0.0), yaw_deg: float = 0.0, pitch_deg: float = 0.0,
         roll_deg: float = 0.0) -> np.ndarray:
    """``(4, 4)`` sensor-to-world transform: rotation yaw (about z), then pitch
    (y), then roll (x), intrinsic, and the sensor origin ``translation``."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix()
    out[:3, 3] = np.asarray(translation, np.float64)
    return out


def as_poses(poses) -> np.ndarray:
    """``(k, 4, 4)`` float64 poses, checked: ``k >= 2``, finite, rigid.

    Raises
    ------
    InputValueError
        naming what is wrong.
    """
    p = np.asarray(poses, np.float64)
    if p.ndim != 3 or p.shape[1:] != (4, 4) or len(p) < 2:
        raise InputValueError(f"poses must be two or more (4, 4) transforms (start ... end of the sweep), "
                              f"got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InputValueError("poses must be finite")
    r = p[:, :3, :3]
    err = np.abs(np.einsum("kij,kil->kjl", r, r) - np.eye(3)).max()
    if err > 1e-6 or np.any(np.linalg.det(r) < 0) or np.abs(p[:, 3] - [0, 0, 0, 1]).max() > 1e-12:
        raise InputValueError("poses must be rigid transforms: a rotation (orthonormal, det +1) and a "
                              "translation, last row [0, 0, 0, 1]")
    return p


def interpolate_poses(poses, times):
    """Rotations ``(m, 3, 3)`` and origins ``(m, 3)`` at ``times`` in [0, 1] of the
    sweep, the poses evenly spaced over it (linear translation, slerp rotation)."""
    p = as_poses(poses)
    t = np.clip(np.asarray(times, np.float64), 0.0, 1.0)
    knots = np.linspace(0.0, 1.0, len(p))
    rot = Slerp(knots, Rotation.from_matrix(p[:, :3, :3]))(t).as_matrix()
    origin = np.column_stack([np.interp(t, knots, p[:, i, 3]) for i in range(3)])
    return rot.reshape(-1, 3, 3), origin


def column_sectors(n_columns: int, sectors: int):
    """``(starts, stops, times)`` of ``sectors`` groups of consecutive columns,
    each with the mean firing time of its columns (fractions of the sweep)."""
    sectors = max(1, min(int(sectors), int(n_columns)))
    edges = np.linspace(0, n_columns, sectors + 1).round().astype(np.int64)
    starts, stops = edges[:-1], edges[1:]
    times = 0.5 * (starts + stops) / n_columns  # mean of (h + 1/2) / n over the sector
    return starts, stops, times


def to_frame(points, pose_matrix) -> np.ndarray:
    """``(m, 3)`` world points in the frame of the sensor at ``pose_matrix``."""
    p = np.asarray(pose_matrix, np.float64)
    return (np.asarray(points, np.float64) - p[:3, 3]) @ p[:3, :3]
