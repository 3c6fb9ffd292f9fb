"""Pulse keys of a beam table (a spinning multi-beam sensor): the compiled kernels.

The definition is :mod:`slr_ray.sensors`' (its module docstring): a point's
row is the beam whose elevation band holds it, tested on ``-z / r`` against
the bands' negated edge cosines (ascending; no arctangent); its column is
``floor(((azimuth - offset) mod 2 pi) / (2 pi / columns))`` with that row's
azimuth offset. Key ``row * columns + column``; -1 not seen.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["beam_keys", "beam_keys_given", "beam_reduce"]


@njit(cache=True, inline="always", error_model="numpy")
def _beam_key(dx, dy, dz, neg_cos_edges, offsets, columns, rmin, rmax):
    r = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not (r > 0.0) or r < rmin or r > rmax:
        return -1, r
    # zenith in [e_i, e_{i+1})  <=>  -cos(e_i) <= -z/r < -cos(e_{i+1}): ascending, no arctangent
    q = -dz / r
    nrow = len(neg_cos_edges) - 1
    if q < neg_cos_edges[0] or q >= neg_cos_edges[nrow]:
        return -1, r
    row = np.searchsorted(neg_cos_edges, q, side="right") - 1
    return row * columns + _column(dx, dy, offsets[row], columns), r


@njit(cache=True, inline="always", error_model="numpy")
def _column(dx, dy, offset, columns):
    """The column of azimuth ``atan2(dy, dx)`` for a beam firing ``offset`` radians off it."""
    two_pi = 2.0 * math.pi
    a = math.atan2(dy, dx) - offset
    a = a - two_pi * math.floor(a / two_pi)
    col = int(math.floor(a / (two_pi / columns)))
    if col >= columns:  # a = 2 pi - tiny rounds to the last column's end
        col = columns - 1
    return col


@njit(cache=True, parallel=True, error_model="numpy")
def beam_keys_given(pts, ox, oy, oz, edges, offsets, columns, rmin, rmax, rows, keys, ranges):
    """As :func:`beam_keys`, a point with ``rows[i] >= 0`` in that row."""
    for i in prange(len(pts)):
        dx, dy, dz = pts[i, 0] - ox, pts[i, 1] - oy, pts[i, 2] - oz
        if rows[i] < 0:
            keys[i], ranges[i] = _beam_key(dx, dy, dz, edges, offsets, columns, rmin, rmax)
            continue
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        ranges[i] = r
        if not (r > 0.0) or r < rmin or r > rmax:
            keys[i] = -1
            continue
        keys[i] = rows[i] * columns + _column(dx, dy, offsets[rows[i]], columns)


@njit(cache=True, parallel=True, error_model="numpy")
def beam_keys(pts, ox, oy, oz, edges, offsets, columns, rmin, rmax, keys, ranges):
    for i in prange(len(pts)):
        keys[i], ranges[i] = _beam_key(pts[i, 0] - ox, pts[i, 1] - oy, pts[i, 2] - oz, edges, offsets, columns,
                                       rmin, rmax)


@njit(cache=True, parallel=True, error_model="numpy")
def beam_reduce(pts, ox, oy, oz, edges, offsets, columns, rmin, rmax, best_r, best_i):
    t_count = best_r.shape[0]
    n = len(pts)
    for t in prange(t_count):
        lo = n * t // t_count
        hi = n * (t + 1) // t_count
        for i in range(lo, hi):
            k, r = _beam_key(pts[i, 0] - ox, pts[i, 1] - oy, pts[i, 2] - oz, edges, offsets, columns, rmin, rmax)
            if k >= 0 and r < best_r[t, k]:  # ascending i within a thread: a tie keeps the lower index
                best_r[t, k] = r
                best_i[t, k] = i
