"""Pulse keys of a beam table (a spinning multi-beam sensor): the compiled kernels.

The definition is :mod:`slr_ray.sensors`' (its module docstring): a point's
row is the beam whose elevation band holds it, tested on ``-z / r`` against
the bands' negated edge cosines (ascending; no arctangent); its column is
``floor(((azimuth - offset) mod 2 pi) / (2 pi / columns))`` with that row's
azimuth offset. Key ``row * columns + column``; -1 not seen.

How the reduction runs (:func:`beam_reduce`): threads take contiguous shares
of the points, each with its own per-pulse tables. Per block of
:data:`~slr_ray.core.grid.BLOCK` points, two vectorised passes compute every
azimuth with the polynomial ``atan2`` of :mod:`slr_ray.core.grid`
(:func:`~slr_ray.core.grid.atan2_fast`, error ~1e-11 rad), and the range,
``-z / r`` and a cell of a lookup table over ``-z / r`` (:func:`row_table`);
a third pass, over the points seen only, takes the row the cell starts in and
corrects it by exact comparisons with the band edges (the table is only a
hint: the row is always the definition's, with no binary search), takes the
column from the fast azimuth where it is more than
:data:`~slr_ray.core.grid.FAST_TOL` from a column edge (and the wraps, which
lie on column edges), elsewhere (a few points in 10^5) from libm's ``atan2``
(:func:`_column`, the definition), and keeps the nearest point per pulse.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .grid import APPROX_MATH, BLOCK, FAST_TOL, atan2_fast

#: nearer the axis than this (metres, |x| and |y| both), the fast azimuth is not
#: trusted: its branch test multiplies by tan(pi/8), which rounds among
#: subnormals (at |x|, |y| ~ 1e-323 it picked the wrong branch, 3e-8 rad off)
AXIS = 1e-300

__all__ = ["beam_keys", "beam_keys_given", "beam_reduce", "beam_reduce_serial", "beam_reduce_posed", "row_table", "ROW_CELLS"]

#: cells of the row lookup table over the bands' span of ``-z / r`` (4096: a
#: cell is far narrower than any shipped table's narrowest band, so at most one
#: edge lies in a cell and the correction takes at most one step)
ROW_CELLS = 4096


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


@njit(cache=True, inline="always", error_model="numpy")
def _cell(q, e0, scale, last):
    """Cell of the row table holding ``q >= e0``: monotone in ``q`` (each step rounds monotonically)."""
    c = np.int64((q - e0) * scale)
    return c if c < last else last


@njit(cache=True, error_model="numpy")
def row_table(edges, cells):
    """``(lut, scale)``: ``lut[c]`` is the highest row ``j`` whose lower edge
    ``edges[j]`` falls in a cell before ``c`` (0 if none), a lower bound of the
    row of every ``q`` in cell ``c`` because :func:`_cell` is monotone; the
    reduction corrects it by exact comparisons with the edges either side."""
    nrow = len(edges) - 1
    scale = cells / (edges[nrow] - edges[0])
    lut = np.zeros(cells, np.int32)
    for j in range(1, nrow):
        c = _cell(edges[j], edges[0], scale, cells - 1)
        for k in range(c + 1, cells):
            lut[k] = j
    return lut, scale


@njit(cache=True, nogil=True, fastmath=APPROX_MATH, error_model="numpy")
def _approx_azimuths(x, y, phi, n):
    """Fast azimuths; NaN (the exact path's sign) nearer the axis than ``AXIS``."""
    for i in range(n):
        p = atan2_fast(y[i], x[i])
        phi[i] = p if max(abs(x[i]), abs(y[i])) >= AXIS else math.nan


@njit(cache=True, nogil=True, error_model="numpy")
def _ranges_cells(x, y, z, n, e0, en, scale, last, rmin, rmax, ranges, qs, cells):
    """Range, ``-z / r`` and row-table cell of each point; cell -1 where the point
    is not seen (range 0, outside the limits or not finite, or ``-z / r``
    outside the bands). Branch-free, so the compiler vectorises it; ``r`` and
    ``-z / r`` are computed without contraction, bit for bit as in
    :func:`_beam_key`."""
    for i in range(n):
        dx = x[i]
        dy = y[i]
        dz = z[i]
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        ranges[i] = r
        q = -dz / r
        qs[i] = q
        seen = (r > 0.0) & (r >= rmin) & (r <= rmax) & (r < math.inf) & (q >= e0) & (q < en)
        c = (q - e0) * scale
        c = c if c < last else last
        cells[i] = np.int32(c) if seen else np.int32(-1)


@njit(cache=True, nogil=True, error_model="numpy")
def _reduce_block(pts, s, e, ox, oy, oz, edges, lut, scale, offsets, columns, rmin, rmax, x, y, z, phi,
                  ranges, qs, cells, best_r, best_i, base):
    """Reduce pts[s:e] (at most BLOCK) into one thread's per-pulse minimum
    (point ``s + i`` recorded as ``base + s + i``).

    Two vectorised passes (fast azimuths; ranges, ``-z / r`` and table cells),
    then one over the points seen: the row from the table's hint corrected by
    exact comparisons with the band edges, the column from the fast azimuth
    where it is certain (libm's ``atan2`` is within ``FAST_TOL`` of it, every
    later step rounds monotonically and no wrap is near), else from libm, and
    the per-pulse minimum.
    """
    n = e - s
    for i in range(n):
        x[i] = np.float64(pts[s + i, 0]) - ox
        y[i] = np.float64(pts[s + i, 1]) - oy
        z[i] = np.float64(pts[s + i, 2]) - oz
    _approx_azimuths(x, y, phi, n)
    nrow = len(edges) - 1
    _ranges_cells(x, y, z, n, edges[0], edges[nrow], scale, np.float64(len(lut) - 1), rmin, rmax, ranges, qs,
                  cells)
    two_pi = 2.0 * math.pi
    inv_2pi = 1.0 / two_pi
    inv_w = columns / two_pi
    tol_h = FAST_TOL * inv_w
    for i in range(n):
        c = cells[i]
        if c < 0:
            continue
        q = qs[i]
        row = np.int64(lut[c])
        while q >= edges[row + 1]:
            row += 1
        while q < edges[row]:
            row -= 1
        p = phi[i]
        a = p - offsets[row]
        a = a - two_pi * math.floor(a * inv_2pi)
        qh = a * inv_w
        fh = math.floor(qh)
        eh = qh - fh
        mh = tol_h + 1e-12 * qh
        if (abs(p) <= math.pi - FAST_TOL and a >= FAST_TOL and a <= two_pi - FAST_TOL
                and eh >= mh and eh <= 1.0 - mh):
            col = np.int64(fh)
        else:  # near a column edge or a wrap, or at the axis (phi NaN): the definition
            col = _column(x[i], y[i], offsets[row], columns)
        k = row * columns + col
        r = ranges[i]
        if r < best_r[k]:  # ascending index within a thread: a tie keeps the lower index
            best_r[k] = r
            best_i[k] = base + s + i


@njit(cache=True)
def _block_buffers():
    """The scratch arrays :func:`_reduce_block` fills for one block of points: x, y, z,
    azimuth, range, -z / r (the elevation's table coordinate) and the row-table cell (int32)."""
    return (np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK),
            np.empty(BLOCK), np.empty(BLOCK, np.int32))


@njit(cache=True, error_model="numpy")
def beam_reduce_serial(pts, ox, oy, oz, edges, offsets, columns, rmin, rmax, best_r, best_i):
    """:func:`beam_reduce` for one thread (``best_r``, ``best_i`` of one row), outside a parallel
    region: entering one costs milliseconds of waking and joining the pool whatever the work
    (12 ms against 0.7 ms for a 130,000-point frame on a loaded 2-core machine), and a caller that
    reduces one frame at a time (a sequence's window: 61 frames a target) pays it every call."""
    n = len(pts)
    lut, scale = row_table(edges, np.int64(ROW_CELLS))  # int64, as from Python: one compile, not two
    x, y, z, phi, ranges, qs, cells = _block_buffers()
    for s in range(0, n, BLOCK):
        _reduce_block(pts, s, min(n, s + BLOCK), ox, oy, oz, edges, lut, scale, offsets, columns, rmin, rmax,
                      x, y, z, phi, ranges, qs, cells, best_r, best_i, np.int64(0))


@njit(cache=True, error_model="numpy")
def beam_reduce_posed(pts, rot, tx, ty, tz, edges, offsets, columns, rmin, rmax, best_r, best_i):
    """:func:`beam_reduce_serial` of ``pts`` ((n, 3) float64, world) seen from a sensor at
    translation ``t`` with rotation ``rot`` (the sensor's axes: ``rot = R.T`` of its pose), each
    point moved as ``slr_ray.effects.motion.to_frame`` moves it (``p - t``, then row ``j``:
    ``d0 rot[j, 0] + d1 rot[j, 1] + d2 rot[j, 2]``, the same roundings) a block at a time into a
    buffer: no moved copy of the cloud."""
    n = len(pts)
    lut, scale = row_table(edges, np.int64(ROW_CELLS))  # int64, as from Python: one compile, not two
    buf = np.empty((BLOCK, 3))
    x, y, z, phi, ranges, qs, cells = _block_buffers()
    for s in range(0, n, BLOCK):
        m = min(n, s + BLOCK) - s
        for i in range(m):
            d0 = pts[s + i, 0] - tx
            d1 = pts[s + i, 1] - ty
            d2 = pts[s + i, 2] - tz
            for j in range(3):
                buf[i, j] = d0 * rot[j, 0] + d1 * rot[j, 1] + d2 * rot[j, 2]
        _reduce_block(buf, np.int64(0), m, 0.0, 0.0, 0.0, edges, lut, scale, offsets, columns, rmin, rmax,
                      x, y, z, phi, ranges, qs, cells, best_r, best_i, s)


@njit(cache=True, parallel=True, error_model="numpy")
def beam_reduce(pts, ox, oy, oz, edges, offsets, columns, rmin, rmax, best_r, best_i):
    """Nearest point per pulse of ``pts`` ((n, 3) float32/64) into ``best_r[t]``,
    ``best_i[t]``, one row of tables per thread ``t`` (each takes a contiguous
    share of the points; the caller merges them)."""
    t_count = best_r.shape[0]
    n = len(pts)
    lut, scale = row_table(edges, np.int64(ROW_CELLS))  # int64, as from Python: one compile, not two
    for t in prange(t_count):
        lo = n * t // t_count
        hi = n * (t + 1) // t_count
        x, y, z, phi, ranges, qs, cells = _block_buffers()  # each thread its own
        for s in range(lo, hi, BLOCK):
            _reduce_block(pts, s, min(hi, s + BLOCK), ox, oy, oz, edges, lut, scale, offsets, columns, rmin,
                          rmax, x, y, z, phi, ranges, qs, cells, best_r[t], best_i[t], np.int64(0))
