"""The binning backend: keep the closest point in every pulse bin (exact).

This is the reference implementation of the nearest-in-pulse rule of DESIGN §2.
Per occupied pulse bin ``(v, h)`` the point with the smallest range wins; ties
go to the lowest input index.

How it runs
-----------
The paper sorts all points by ``(h, v, R)``: O(N log N). Here a per-bin
minimum needs no sort:

1. a compiled loop (numba) computes, per point, the pulse key ``v * n_h + h``
   and the range, in float64 after subtracting the origin (non-finite rows
   are counted first and refused);
2. in the same loop the point goes into an open-addressing hash table of
   ``(key, range, index)`` that keeps the smallest ``(range, index)`` per key.
   Each thread reduces its own slice of the points into its own table; the
   tables are merged (O(occupied bins)) when the result is asked for.

Memory therefore grows with the number of *occupied* bins (24 bytes per bin,
at most twice that while a table grows), never with the number of points or
with the number of possible bins (0.001 deg would be 6.5e10 bins). Patterns with few
pulses (0.144 deg: 3.1e6) use plain per-pulse arrays instead, which is faster
when the cloud is dense. The tables outlive a call, which is what :class:`slr_ray.ScanAccumulator` uses to reduce
a cloud chunk by chunk to exactly the one-shot answer.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit


__all__ = ["BinTables", "default_threads", "pulse_keys"]

_EMPTY = np.int64(-1)
_HASH = np.uint64(0x9E3779B97F4A7C15)
_INITIAL_BITS = 12


def default_threads() -> int:
    """Threads used when none is given: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@njit(cache=True, inline="always")
def _slot(key, shift):
    return np.int64((np.uint64(key) * _HASH) >> np.uint64(shift))


@njit(cache=True, inline="always")
def _pulse_key(x, y, z, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax):
    """(key, range) of one point; key -1 when unseen, -2 when not finite."""
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return np.int64(-2), math.inf
    dx = x - ox
    dy = y - oy
    dz = z - oz
    r = math.sqrt(dx * dx + dy * dy + dz * dz)
    if r == 0.0 or r < rmin or r > rmax:
        return np.int64(-1), r
    theta = math.atan2(math.hypot(dx, dy), dz)
    if theta < th0 or theta > th1:
        return np.int64(-1), r
    v = np.int64(math.floor((theta - th0) / d_theta))
    if v >= nv:
        v = nv - 1
    phi = math.atan2(dy, dx)
    if phi < 0.0:
        phi += 2.0 * math.pi
    h = np.int64(math.floor(phi / d_phi))
    if h >= nh:
        h = nh - 1
    return v * nh + h, r


@njit(cache=True, nogil=True)
def _keys_array(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax, keys, ranges):
    for i in range(points.shape[0]):
        keys[i], ranges[i] = _pulse_key(
            np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2]),
            ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax)


def pulse_keys(points, origin, pattern):
    """Flat pulse key ``v * n_azimuth + h`` and range of every point.

    The same compiled arithmetic as the reduction, so a point on a bin edge
    falls on the same side here as in a scan. Key -1: not seen; -2: not finite.
    """
    keys = np.empty(len(points), dtype=np.int64)
    ranges = np.empty(len(points), dtype=np.float64)
    if len(points):
        _keys_array(points, *_kernel_params(origin, pattern), keys, ranges)
    return keys, ranges


def _kernel_params(origin, pattern):
    d_theta, d_phi, th0, th1 = pattern.radians
    rmin, rmax = pattern.range_limits
    nv, nh = pattern.shape
    return (float(origin[0]), float(origin[1]), float(origin[2]),
            d_theta, d_phi, th0, th1, np.int64(nv), np.int64(nh), rmin, rmax)


@njit(cache=True, nogil=True)
def _count_nonfinite(points, start, stop):
    bad = 0
    for i in range(start, stop):
        if not (math.isfinite(points[i, 0]) and math.isfinite(points[i, 1])
                and math.isfinite(points[i, 2])):
            bad += 1
    return bad


@njit(cache=True, nogil=True)
def _put(tkeys, tranges, tidx, shift, key, r, idx):
    """Insert or improve one bin; returns (slot, 1 if the bin is new)."""
    mask = tkeys.shape[0] - 1
    s = _slot(key, shift)
    while True:
        k = tkeys[s]
        if k == key:
            if r < tranges[s] or (r == tranges[s] and idx < tidx[s]):
                tranges[s] = r
                tidx[s] = idx
            return s, 0
        if k == -1:
            tkeys[s] = key
            tranges[s] = r
            tidx[s] = idx
            return s, 1
        s = (s + 1) & mask


@njit(cache=True, nogil=True, fastmath=False)
def _reduce_slice(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                  tkeys, tranges, tidx, count, offset, start, stop):
    """Bin points[start:stop] into one table, fused (trigonometry + insert).

    Stops early when the table is half full; returns (count, next position).
    """
    cap = tkeys.shape[0]
    limit = cap // 2
    shift = 64 - int(math.log2(cap) + 0.5)
    last_key = np.int64(-1)
    last_slot = np.int64(0)
    for i in range(start, stop):
        key, r = _pulse_key(np.float64(points[i, 0]), np.float64(points[i, 1]),
                            np.float64(points[i, 2]), ox, oy, oz, d_theta, d_phi,
                            th0, th1, nv, nh, rmin, rmax)
        if key < 0:
            continue
        idx = offset + i
        if key == last_key:  # scans are ordered: neighbours often share a pulse
            if r < tranges[last_slot]:
                tranges[last_slot] = r
                tidx[last_slot] = idx
            continue
        if count >= limit:
            return count, i
        last_slot, new = _put(tkeys, tranges, tidx, shift, key, r, idx)
        last_key = key
        count += new
    return count, stop


@njit(cache=True, nogil=True)
def _merge(tkeys, tranges, tidx, nkeys, nranges, nidx):
    """Insert every bin of one table into another (which must be large enough)."""
    cap = nkeys.shape[0]
    shift = 64 - int(math.log2(cap) + 0.5)
    new = 0
    for j in range(tkeys.shape[0]):
        key = tkeys[j]
        if key != -1:
            new += _put(nkeys, nranges, nidx, shift, key, tranges[j], tidx[j])[1]
    return new


@njit(cache=True, nogil=True)
def _extract(tkeys, tranges, tidx, out_keys, out_ranges, out_idx):
    j = 0
    for s in range(tkeys.shape[0]):
        if tkeys[s] != -1:
            out_keys[j] = tkeys[s]
            out_ranges[j] = tranges[s]
            out_idx[j] = tidx[s]
            j += 1
    return j


@njit(cache=True, nogil=True, fastmath=False)
def _reduce_dense(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                  branges, bidx, offset, start, stop):
    """Bin points[start:stop] into dense per-pulse arrays; returns new bins."""
    new = 0
    for i in range(start, stop):
        key, r = _pulse_key(np.float64(points[i, 0]), np.float64(points[i, 1]),
                            np.float64(points[i, 2]), ox, oy, oz, d_theta, d_phi,
                            th0, th1, nv, nh, rmin, rmax)
        if key < 0:
            continue
        # indices only grow within a table, so a strict < keeps ties on the lowest
        if r < branges[key]:
            if bidx[key] < 0:
                new += 1
            branges[key] = r
            bidx[key] = offset + i
    return new


@njit(cache=True, nogil=True)
def _merge_dense(branges, bidx, oranges, oidx):
    new = 0
    for k in range(bidx.shape[0]):
        j = oidx[k]
        if j < 0:
            continue
        i = bidx[k]
        if i < 0:
            new += 1
        if i < 0 or oranges[k] < branges[k] or (oranges[k] == branges[k] and j < i):
            branges[k] = oranges[k]
            bidx[k] = j
    return new


class _DenseTable:
    """Per-pulse arrays (range, index): used when the pattern has few pulses."""

    __slots__ = ("ranges", "idx", "count")

    def __init__(self, n_pulses: int):
        self.ranges = np.full(n_pulses, np.inf)
        self.idx = np.full(n_pulses, -1, dtype=np.int64)
        self.count = 0

    def reduce(self, points, params, offset, start, stop) -> None:
        self.count += _reduce_dense(points, *params, self.ranges, self.idx, offset, start, stop)

    def absorb(self, other: "_DenseTable") -> None:
        if other.count:
            self.count += _merge_dense(self.ranges, self.idx, other.ranges, other.idx)

    def extract(self):
        """Occupied bins ``(keys, ranges, indices)`` sorted by index."""
        keys = np.flatnonzero(self.idx >= 0).astype(np.int64)
        idx = self.idx[keys]
        bits = max(1, int(len(self.idx) - 1).bit_length())
        if len(keys) and int(idx.max()) < 1 << (63 - bits):
            # one sort of (index, key) packed in an int64: faster than an argsort
            packed = np.sort((idx << bits) | keys)
            keys = packed & ((1 << bits) - 1)
            idx = packed >> bits
        else:  # pragma: no cover - more than 2**39 points
            order = np.argsort(idx)
            keys, idx = keys[order], idx[order]
        return keys, self.ranges[keys], idx

    @property
    def nbytes(self) -> int:
        return self.ranges.nbytes + self.idx.nbytes


class _Table:
    """One thread's open-addressing hash table: bin key -> (range, index)."""

    __slots__ = ("keys", "ranges", "idx", "count")

    def __init__(self, bits: int = _INITIAL_BITS):
        cap = 1 << bits
        self.keys = np.full(cap, _EMPTY, dtype=np.int64)
        self.ranges = np.empty(cap, dtype=np.float64)
        self.idx = np.empty(cap, dtype=np.int64)
        self.count = 0

    def grow(self, at_least: int = 0) -> None:
        """Double the capacity (or more, to hold ``at_least`` bins half full)."""
        cap = len(self.keys) * 2
        while cap // 2 < at_least:
            cap *= 2
        keys = np.full(cap, _EMPTY, dtype=np.int64)
        ranges = np.empty(cap, dtype=np.float64)
        idx = np.empty(cap, dtype=np.int64)
        _merge(self.keys, self.ranges, self.idx, keys, ranges, idx)
        self.keys, self.ranges, self.idx = keys, ranges, idx

    def reduce(self, points, params, offset, start, stop) -> None:
        while True:
            self.count, start = _reduce_slice(
                points, *params, self.keys, self.ranges, self.idx, self.count,
                offset, start, stop,
            )
            if start >= stop:
                return
            self.grow()

    def absorb(self, other: "_Table") -> None:
        """Merge another table's bins into this one (lower (range, index) wins)."""
        if other.count == 0:
            return
        if self.count + other.count > len(self.keys) // 2:
            self.grow(self.count + other.count)
        self.count += _merge(other.keys, other.ranges, other.idx,
                             self.keys, self.ranges, self.idx)

    def extract(self):
        """Occupied bins ``(keys, ranges, indices)`` sorted by index."""
        m = self.count
        keys = np.empty(m, dtype=np.int64)
        ranges = np.empty(m, dtype=np.float64)
        idx = np.empty(m, dtype=np.int64)
        _extract(self.keys, self.ranges, self.idx, keys, ranges, idx)
        order = np.argsort(idx)  # indices are unique: no stability needed
        return keys[order], ranges[order], idx[order]

    @property
    def nbytes(self) -> int:
        return self.keys.nbytes + self.ranges.nbytes + self.idx.nbytes


class BinTables:
    """Per-bin minimum of (range, index) for one scanner position and pattern.

    The state of a streamed binning reduction. :meth:`add` reduces a chunk of
    points (indices continue across chunks); :meth:`winners` returns the
    occupied bins. Used by :func:`slr_ray.simulate_scan` and
    :class:`slr_ray.ScanAccumulator`; most users want those instead.

    Patterns with few pulses (``16 * n_pulses * n_threads <= dense_bytes``,
    e.g. 0.144 deg) use dense per-pulse arrays, which are faster for dense
    clouds; finer patterns use hash tables that grow with occupied bins.
    """

    #: memory allowed for dense per-pulse arrays, all threads together
    dense_bytes = 256 * 2**20

    def __init__(self, origin, pattern, n_threads: int | None = None):
        self.origin = origin
        self.pattern = pattern
        self.n_threads = int(n_threads or default_threads())
        if self.n_threads < 1:
            raise ValueError(f"n_threads must be >= 1, got {n_threads}")
        self.dense = pattern.n_pulses * 16 * self.n_threads <= self.dense_bytes
        self.tables = [self._new_table() for _ in range(self.n_threads)]
        self.n_points = 0
        self._params = _kernel_params(origin, pattern)

    def _new_table(self):
        return _DenseTable(self.pattern.n_pulses) if self.dense else _Table()

    def _slices(self, n):
        step = -(-n // self.n_threads)
        return [(s, min(s + step, n)) for s in range(0, n, step)]

    def add(self, points: np.ndarray) -> int:
        """Reduce ``points`` ((n, 3) float32/64, C-contiguous) into the tables.

        Returns the number of non-finite rows; when it is not 0 nothing was
        added (the caller raises).
        """
        n = len(points)
        if n == 0:
            return 0
        slices = self._slices(n)
        if len(slices) == 1:
            bad = _count_nonfinite(points, 0, n)
            if bad:
                return bad
            self.tables[0].reduce(points, self._params, self.n_points, 0, n)
        else:
            with ThreadPoolExecutor(len(slices)) as pool:
                bad = sum(pool.map(lambda se: _count_nonfinite(points, *se), slices))
                if bad:
                    return bad
                futs = [
                    pool.submit(t.reduce, points, self._params, self.n_points, s, e)
                    for t, (s, e) in zip(self.tables, slices)
                ]
                for f in futs:
                    f.result()
        self.n_points += n
        return 0

    def _merged(self) -> _Table:
        first, *rest = self.tables
        for t in rest:
            first.absorb(t)
        self.tables = [first] + [self._new_table() for _ in rest]
        return first

    @property
    def n_bins(self) -> int:
        """Number of occupied pulse bins so far."""
        return self._merged().count if len(self.tables) > 1 else self.tables[0].count

    @property
    def nbytes(self) -> int:
        """Bytes held by the tables."""
        return sum(t.nbytes for t in self.tables)

    def winners(self):
        """Occupied bins as ``(keys, ranges, indices)``, sorted by index."""
        return self._merged().extract()
