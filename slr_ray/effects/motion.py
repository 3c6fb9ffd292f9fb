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

Where the sweep starts and which way it turns are options: Velodyne units
turn clockwise seen from above (azimuth ``atan2(y, x)`` falling), and a
KITTI frame starts and ends at the rear (``start_deg=180, clockwise=True``:
the timing KISS-ICP gives KITTI's raw frames, ``t = (1 - atan2(y, x) / pi) /
2``). With a start inside the column range, the sectors are also split at
it, so no sector straddles the sweep's first and last columns.

The result is written in the sensor frame at the end of the sweep, as a
motion-compensating driver writes a frame: ``p_end = R_end^T (p_world -
t_end)``; or, as a raw frame is written (KITTI raw; a driver that does not
compensate), each return in the sensor frame of the pose its column fired
from (:func:`to_firing_frames`). :func:`deskew` undoes the latter: a raw
frame's points into the poses' (world) frame.
"""

from __future__ import annotations

import numpy as np

from .. import lazy
from ..errors import InputValueError

#: scipy.spatial.transform, loaded on first use (slr_ray.lazy)
spatial_transform = lazy.module("scipy.spatial.transform")

__all__ = ["pose", "as_poses", "interpolate_poses", "column_sectors", "column_times", "azimuth_times", "to_frame", "rotate",
           "to_firing_frames", "deskew"]


def pose(translation=(0.0, 0.0, 0.0), yaw_deg: float = 0.0, pitch_deg: float = 0.0,
         roll_deg: float = 0.0) -> np.ndarray:
    """``(4, 4)`` sensor-to-world transform: rotation yaw (about z), then pitch
    (y), then roll (x), intrinsic, and the sensor origin ``translation``."""
    out = np.eye(4)
    out[:3, :3] = spatial_transform.Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix()
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
    rot = spatial_transform.Slerp(knots, spatial_transform.Rotation.from_matrix(p[:, :3, :3]))(t).as_matrix()
    origin = np.column_stack([np.interp(t, knots, p[:, i, 3]) for i in range(3)])
    return rot.reshape(-1, 3, 3), origin


def azimuth_times(azimuth_deg, start_deg: float = 0.0, clockwise: bool = False) -> np.ndarray:
    """Firing time, as a fraction of the sweep in [0, 1), of a return at ``azimuth_deg``
    (``atan2(y, x)``, degrees) of a sweep that starts at ``start_deg`` and turns
    counter-clockwise (azimuth rising) or ``clockwise``."""
    az = np.asarray(azimuth_deg, np.float64)
    d = (start_deg - az) if clockwise else (az - start_deg)
    return np.mod(d, 360.0) / 360.0


def column_times(n_columns: int, start_deg: float = 0.0, clockwise: bool = False) -> np.ndarray:
    """``(n_columns,)`` firing time of each column (its centre azimuth ``(h + 1/2) 360 / n``),
    fractions of the sweep; ``(h + 1/2) / n`` with the defaults."""
    n = int(n_columns)
    return azimuth_times((np.arange(n) + 0.5) * 360.0 / n, start_deg, clockwise)


def column_sectors(n_columns: int, sectors: int, start_deg: float = 0.0, clockwise: bool = False):
    """``(starts, stops, times)`` of ``sectors`` groups of consecutive columns,
    each with the mean firing time of its columns (fractions of the sweep).
    A sweep that starts inside the column range is split there too (one
    sector more), so no sector holds both the first and the last firings."""
    n = int(n_columns)
    sectors = max(1, min(int(sectors), n))
    tc = column_times(n, start_deg, clockwise)
    seam = np.flatnonzero(np.abs(np.diff(tc)) > 0.5) + 1  # where the time wraps from the end to the start
    edges = np.unique(np.r_[np.linspace(0, n, sectors + 1).round().astype(np.int64), seam])
    starts, stops = edges[:-1], edges[1:]
    times = np.add.reduceat(tc, starts) / (stops - starts)
    return starts, stops, times


def to_firing_frames(points, columns, n_columns: int, poses, sectors: int | None = None, start_deg: float = 0.0,
                     clockwise: bool = False) -> np.ndarray:
    """``(m, 3)`` world points, each in the sensor frame of the pose its column fired from
    (:func:`column_sectors` with the same arguments as the scan): a raw frame.

    Parameters
    ----------
    points : (m, 3) float
        In the poses' (world) frame.
    columns : (m,) int
        Each point's column.
    n_columns : int
    poses : (k, 4, 4) float
    sectors : int, optional
        Default: every column its own pose.
    """
    p = np.asarray(points, np.float64)
    h = np.asarray(columns, np.int64)
    starts, _, times = column_sectors(n_columns, sectors or n_columns, start_deg, clockwise)
    rot, org = interpolate_poses(poses, times)
    sec = np.searchsorted(starts, h, side="right") - 1
    return np.einsum("mji,mj->mi", rot[sec], p - org[sec])


def deskew(points, poses, start_deg: float = 0.0, clockwise: bool = False) -> np.ndarray:
    """A raw frame (each point in the sensor frame of its firing pose) into the poses'
    (world) frame: ``R(t) p + o(t)``, ``t`` from each point's azimuth (:func:`azimuth_times`).

    To compensate a frame for a constant motion ``delta`` (the sensor's pose at the
    sweep's end in the frame of its start), pass ``poses=[identity, delta]`` and
    :func:`to_frame` the result into the pose of your reference time.
    """
    p = np.asarray(points, np.float64)
    t = azimuth_times(np.degrees(np.arctan2(p[:, 1], p[:, 0])), start_deg, clockwise)
    rot, org = interpolate_poses(poses, t)
    return np.einsum("mij,mj->mi", rot, p) + org


def to_frame(points, pose_matrix) -> np.ndarray:
    """``(m, 3)`` world points in the frame of the sensor at ``pose_matrix`` (float64:
    ``R^T (p - t)``, by :func:`rotate`). The one such function: the sequence's unions
    (``slr_ray.sequence.union.to_frame`` is this one) and the beam tables' posed reduction
    (``BeamPattern.reduce_posed``, which moves each point with the same arithmetic) agree
    with it to the bit."""
    T = np.asarray(pose_matrix, np.float64)
    return rotate(np.asarray(points, np.float64) - T[:3, 3], T[:3, :3].T)


def rotate(points, R) -> np.ndarray:
    """``points @ R.T`` (each row rotated by ``R``) by three multiply-adds a column, not a BLAS
    matrix product: a (n, 3) x (3, 3) product went through BLAS's threads, 100 times slower on a
    loaded machine (0.33 s for 124,000 points) than this."""
    p = np.asarray(points, np.float64)
    out = np.empty_like(p)
    for j in range(3):
        out[:, j] = p[:, 0] * R[j, 0] + p[:, 1] * R[j, 1] + p[:, 2] * R[j, 2]
    return out
