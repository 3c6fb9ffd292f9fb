"""Spherical coordinates and pulse bins of points seen from a scanner (numpy).

These are the readable definitions of the ideal scanner (docs/backends.md,
"What a scan returns (the ideal scanner)"); the pulse keys of :mod:`slr_ray.core`
compute the same quantities fused in a compiled loop. Everything is done in float64
after subtracting the scanner origin, so a cloud in UTM coordinates (10^6 m)
bins exactly like the same cloud near 0.
"""

from __future__ import annotations

import numpy as np

from .arrays import as_origin, as_points
from .core import Pattern
from .pattern import pulse_directions

__all__ = ["spherical_coordinates", "pulse_bins", "pulse_directions"]


def spherical_coordinates(points, origin):
    """Range, zenith and azimuth of points seen from ``origin``.

    Parameters
    ----------
    points : (n, 3) float
    origin : (3,) float

    Returns
    -------
    ranges : (n,) float64
        ``|p - origin|``.
    zenith : (n,) float64
        ``atan2(hypot(dx, dy), dz)`` in [0, pi]; 0 is straight up. Stable at
        the poles, unlike ``arccos(dz / R)``.
    azimuth : (n,) float64
        ``atan2(dy, dx)`` moved into [0, 2 pi), counter-clockwise from +x.
    """
    pts = as_points(points)
    o = as_origin(origin)
    d = pts.astype(np.float64) - o
    dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
    ranges = np.sqrt(dx * dx + dy * dy + dz * dz)
    zenith = np.arctan2(np.hypot(dx, dy), dz)
    azimuth = np.arctan2(dy, dx)
    azimuth = np.where(azimuth < 0, azimuth + 2 * np.pi, azimuth)
    return ranges, zenith, azimuth


def pulse_bins(points, origin, pattern: Pattern):
    """Pulse bin of every point, and whether the scanner can see it at all.

    Returns
    -------
    v : (n,) int64
        Zenith bin, in ``[0, pattern.n_zenith)`` where ``visible``.
    h : (n,) int64
        Azimuth bin, in ``[0, pattern.n_azimuth)`` where ``visible``.
    ranges : (n,) float64
    visible : (n,) bool
        False for points at range 0, outside the zenith field of view or
        outside the range limits (their ``v`` and ``h`` are -1).

    Notes
    -----
    ``v = min(floor((zenith - theta_min) / d_theta), n_zenith - 1)`` and
    ``h = min(floor(azimuth / d_phi), n_azimuth - 1)`` with the angles of
    :func:`spherical_coordinates`. This uses the same compiled arithmetic as
    the binning backend, so a point lying on a bin edge is put on the same
    side of it here as in a scan (numpy's own ``arctan2`` may differ from the
    C library's in the last bit).
    """
    keys, ranges = pattern.pulse_ids(as_points(points), as_origin(origin))
    visible = keys >= 0
    nh = pattern.n_azimuth
    return np.where(visible, keys // nh, -1), np.where(visible, keys % nh, -1), ranges, visible
