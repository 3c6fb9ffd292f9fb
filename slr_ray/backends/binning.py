"""The binning backend: keep the closest point in every pulse bin (exact).

This is the reference implementation of the paper's nearest-in-pulse rule (README, "The ideal scanner").
Per occupied pulse bin ``(v, h)`` the point with the smallest range wins; ties
go to the lowest input index.

How it runs
-----------
The paper sorts all points by ``(h, v, R)``: O(N log N). Here a per-bin
minimum needs no sort:

1. a compiled loop (numba) takes the points in blocks of 512, subtracts the
   origin in float64 and computes both angles with a branch-free polynomial
   ``atan2`` that the compiler vectorises (one division per angle, a 7-term
   Chebyshev polynomial; error below 1e-11 rad);
2. a second vectorised pass (selects, no branches) turns them into pulse
   keys wherever they decide the bin for certain; a point within 1e-8 rad of
   a bin edge, a field-of-view limit or the azimuth wrap (a few in 10^5) is
   left to a third pass that takes its bin from the C library's ``atan2``, so
   every bin is exactly the definition's
   (``floor((atan2(hypot(dx, dy), dz) - theta_min) / d_theta)``...) *for the
   float64 offsets* ``dx = x - ox``... as computed. Those offsets are the exact
   differences of the stored coordinates when point and origin lie within a
   factor of two of each other on an axis (Sterbenz's lemma: a UTM cloud with
   its scanner inside it), or when both are multiples of one power of two
   ``2**-k`` below ``2**(53 - k)`` (1/1024 m up to 8.8e12 m); then moving
   cloud and origin by such an offset changes no bin (tested:
   ``test_scans_do_not_depend_on_where_the_cloud_lies``). Adding an offset to
   arbitrary float64 coordinates rounds them (by up to 4.7e-10 m at 4e6 m):
   that is another cloud, and a point so close to a bin edge may change bin;
3. each point then goes into a table that keeps, per pulse key
   ``v * n_azimuth + h``, the smallest ``(range, index)``. Non-finite rows are
   counted first and refused, so a bad chunk leaves the state untouched (a
   prepared scanner checks its cloud once, not per scan).

Tables are of three kinds, by the pattern's size:

- **dense** (``16 * n_pulses * n_threads`` bytes within
  :attr:`BinTables.dense_bytes`, 256 MiB; 0.144 deg has 3.1e6 pulses): plain
  per-pulse arrays, one per thread; threads split the points and the tables
  merge, in parallel, in O(pulses) when the result is asked for;
- **slots** (``4 * n_pulses`` within :attr:`BinTables.slot_bytes`, 512 MiB;
  SYNS's 0.036 deg has 3.75e7 pulses): one shared int32 slot per pulse
  pointing into compact per-thread records ``(key, range, index)``; threads
  own whole 64-byte lines of slots, so nothing is merged or hashed;
- **hash** (finer patterns: 0.001 deg would be 6.5e10 pulses): an
  open-addressing hash table of 24-byte records per thread that grows with
  the number of *occupied* bins (at most twice that while growing), never
  with the number of points or of possible pulses. Neighbouring pulses hash
  to neighbouring slots in groups of 16, so scan-ordered clouds touch memory
  in order.

With slot and hash tables the threads split the *keys*: keys are computed
for a superblock of points in parallel, then each thread inserts the keys it
owns. Dense and slot tables are cleared in O(occupied bins) and reused from
one scan to the next by a prepared :class:`BinningScanner`. The tables
outlive a call, which is what :class:`slr_ray.ScanAccumulator` uses to reduce
a cloud chunk by chunk to exactly the one-shot answer.
"""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..arrays import as_origin
from ..errors import InputValueError
from ..pattern import ScanPattern, as_pattern
from ..scan import Scan
from ..threads import default_threads
from .base import BackendOptions, Scanner


__all__ = ["BinningOptions", "BinningScanner", "BinTables", "default_threads", "pulse_keys", "ranges_of"]

#: points per block: the scratch arrays (5 x 4 KiB) stay in the L1 cache
_BLOCK = 512
_HASH = np.uint64(0x9E3779B97F4A7C15)
#: neighbouring keys share a group of 2**_GROUP consecutive slots
_GROUP = 4
_INITIAL_BITS = 12
_RECORD = np.dtype([("key", np.int64), ("r", np.float64), ("idx", np.int64)])
#: the hash tables' compact record (16 bytes instead of 24): for patterns of fewer
#: than 2**31 pulses while point indices stay below 2**32 (a 0.00576 deg pattern
#: has 1.95e9 pulses; its dense primary's 2e8 bins take 8 GiB of tables, not 12)
_COMPACT_RECORD = np.dtype([("key", np.int32), ("idx", np.uint32), ("r", np.float64)])
_COMPACT_MAX_PULSES = 2**31 - 1
_COMPACT_MAX_POINTS = 2**32 - 1
#: one hash table grows at a time: two threads doubling theirs at once held
#: old and new tables of both (18.4 GiB for that primary instead of 12)
_GROW_LOCK = threading.Lock()

# atan(t) / t as a polynomial in t^2 for |t| <= tan(pi/8): the degree-6
# Chebyshev interpolant at the first-kind nodes (its error, measured against
# mpmath, is 8e-12 rad; tests/test_binning.py checks 1e-10 against libm). Seven
# terms instead of the thirteen of the Taylor series the first version used.
_ATAN_C = (0.9999999999783985, -0.333333320976113, 0.19999883856645354, -0.14281588774020137,
           0.1104048923222256, -0.08456192859922249, 0.04707347983517718)
_TAN_PI_8 = 0.41421356237309503
#: bound used on |fast angle - libm angle| (radians), far above the true ~1e-11
_FAST_TOL = 1e-8
#: the polynomial may be contracted into FMAs and divide by reciprocals: it is
#: only used where its error bound decides the bin for certain
_APPROX_MATH = {"contract", "arcp"}


@njit(cache=True, inline="always", fastmath=_APPROX_MATH, error_model="numpy")
def _atan2_fast(y, x):
    """atan2(y, x) to ~1e-11 rad, branch-free so that loops vectorise.

    NaN when x = y = 0; callers check such points with the exact path.
    """
    ax = abs(x)
    ay = abs(y)
    mn = min(ax, ay)
    mx = max(ax, ay)
    # one division: t = a or (a - 1) / (a + 1) for a = mn / mx, without forming a
    # (divisions, not the polynomial, are what this costs)
    big = mn > _TAN_PI_8 * mx
    num = mn - mx if big else mn
    den = mn + mx if big else mx
    t = num / den
    base = math.pi / 4 if big else 0.0
    t2 = t * t
    p = _ATAN_C[6]
    p = p * t2 + _ATAN_C[5]
    p = p * t2 + _ATAN_C[4]
    p = p * t2 + _ATAN_C[3]
    p = p * t2 + _ATAN_C[2]
    p = p * t2 + _ATAN_C[1]
    p = p * t2 + _ATAN_C[0]
    r = base + t * p
    r = (math.pi / 2 - r) if ay > ax else r
    r = (math.pi - r) if x < 0.0 else r
    return -r if y < 0.0 else r


@njit(cache=True, nogil=True, fastmath=_APPROX_MATH, error_model="numpy")
def _approx_angles(x, y, z, theta, phi, n):
    for i in range(n):
        theta[i] = _atan2_fast(math.sqrt(x[i] * x[i] + y[i] * y[i]), z[i])
        phi[i] = _atan2_fast(y[i], x[i])


@njit(cache=True, inline="always", error_model="numpy")
def _bins_exact(dx, dy, dz, d_theta, d_phi, th0, th1, nv, nh):
    """(v, h) with libm's atan2 and hypot: the definition. v = -1 outside the view."""
    theta = math.atan2(math.hypot(dx, dy), dz)
    if theta < th0 or theta > th1:
        return np.int64(-1), np.int64(-1)
    v = np.int64(math.floor((theta - th0) / d_theta))
    if v >= nv:
        v = nv - 1
    phi = math.atan2(dy, dx)
    if phi < 0.0:
        phi += 2.0 * math.pi
    h = np.int64(math.floor(phi / d_phi))
    if h >= nh:
        h = nh - 1
    return v, h


@njit(cache=True, nogil=True, error_model="numpy")
def _sure_keys(x, y, z, theta, phi, n, inv_dt, inv_dp, th0, th1, nh, rmin, rmax, tol_v, tol_h,
               keys, ranges):
    """Keys the approximate angles decide for certain; -3 where they do not.

    Branch-free (selects only), so the compiler vectorises it. Key -1: surely
    not seen (a finite range outside the limits, or an angle more than
    ``_FAST_TOL`` outside the field of view). Key -3: near a bin edge, the
    view's edge or the azimuth wrap, at the origin, or not finite: decided by
    :func:`_fix_keys` with libm. ``r`` is computed without contraction, so it
    is bit for bit the range every other path computes. Multiplying by the
    inverse bin width instead of dividing moves ``q`` by a few ulp, far inside
    the ``1e-12 * q`` margin.
    """
    two_pi = 2.0 * math.pi
    for i in range(n):
        dx = x[i]
        dy = y[i]
        dz = z[i]
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        ranges[i] = r
        t = theta[i]
        p = phi[i]
        p = p + two_pi if p < 0.0 else p
        qv = (t - th0) * inv_dt
        qh = p * inv_dp
        fv = math.floor(qv)
        fh = math.floor(qh)
        ev = qv - fv
        eh = qh - fh
        mv = tol_v + 1e-12 * qv
        mh = tol_h + 1e-12 * qh
        inside = ((r > 0.0) & (r >= rmin) & (r <= rmax) & (r < math.inf)
                  & (t >= th0 + _FAST_TOL) & (t <= th1 - _FAST_TOL)
                  & (p >= _FAST_TOL) & (p <= two_pi - _FAST_TOL)
                  & (ev >= mv) & (ev <= 1.0 - mv) & (eh >= mh) & (eh <= 1.0 - mh))
        outside = (r < math.inf) & ((r < rmin) | (r > rmax)
                                    | (t < th0 - _FAST_TOL) | (t > th1 + _FAST_TOL))
        # int64 arithmetic: keys reach 2**62, beyond a double's exact integers
        k = np.int64(fv) * nh + np.int64(fh)
        keys[i] = k if inside else (np.int64(-1) if outside else np.int64(-3))


@njit(cache=True, nogil=True, error_model="numpy")
def _fix_keys(x, y, z, n, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax, keys, ranges):
    """Decide the keys left at -3 by :func:`_sure_keys` with libm: the definition.

    Key -1: not seen (range 0, outside the view or the range limits);
    -2: not finite. Returns the number of non-finite rows.
    """
    bad = 0
    for i in range(n):
        if keys[i] != -3:
            continue
        dx = x[i]
        dy = y[i]
        dz = z[i]
        if not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)):
            keys[i] = -2
            ranges[i] = math.inf
            bad += 1
            continue
        r = ranges[i]
        if r == 0.0 or r < rmin or r > rmax:
            keys[i] = -1
            continue
        v, h = _bins_exact(dx, dy, dz, d_theta, d_phi, th0, th1, nv, nh)
        keys[i] = -1 if v < 0 else v * nh + h
    return bad


@njit(cache=True, nogil=True, error_model="numpy")
def _block_keys(points, s, e, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                x, y, z, theta, phi, keys, ranges):
    """Keys and ranges of points[s:e] (at most _BLOCK) into keys[:e-s], ranges[:e-s].

    Key -1: not seen (range 0, outside the view or the range limits);
    -2: not finite. Returns the number of non-finite rows.

    Three passes over the block, the first two vectorised: approximate angles,
    the keys they decide for certain, and libm for the few they do not (a few
    points in 10^5 at 0.144 deg).
    """
    n = e - s
    for i in range(n):
        x[i] = np.float64(points[s + i, 0]) - ox
        y[i] = np.float64(points[s + i, 1]) - oy
        z[i] = np.float64(points[s + i, 2]) - oz
    _approx_angles(x, y, z, theta, phi, n)
    _sure_keys(x, y, z, theta, phi, n, 1.0 / d_theta, 1.0 / d_phi, th0, th1, nh, rmin, rmax,
               _FAST_TOL / d_theta, _FAST_TOL / d_phi, keys, ranges)
    return _fix_keys(x, y, z, n, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax, keys, ranges)


@njit(cache=True)
def _scratch():
    return (np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK),
            np.empty(_BLOCK), np.empty(_BLOCK, np.int64), np.empty(_BLOCK))


def pulse_keys(points, origin, pattern):
    """Flat pulse key ``v * n_azimuth + h`` and range of every point.

    The same compiled arithmetic as the reduction, so a point on a bin edge
    falls on the same side here as in a scan. Key -1: not seen; -2: not finite.
    """
    if not isinstance(pattern, ScanPattern):  # a beam table (slr_ray.sensors)
        return pattern.keys(points, origin)
    keys = np.empty(len(points), dtype=np.int64)
    ranges = np.empty(len(points), dtype=np.float64)
    n = len(points)
    params = _kernel_params(origin, pattern)
    # the kernel releases the GIL: large inputs are split over the cores (2.7 s -> 1.4 s on 58 M points)
    parts = max(1, min(default_threads(), n // (1 << 20)))
    if parts == 1:
        if n:
            _block_keys_range(points, *params, keys, ranges, 0, n)
    else:
        cuts = [n * i // parts for i in range(parts + 1)]
        with ThreadPoolExecutor(parts) as pool:
            list(pool.map(lambda i: _block_keys_range(points, *params, keys, ranges, cuts[i], cuts[i + 1]),
                          range(parts)))
    return keys, ranges


@njit(cache=True, nogil=True, error_model="numpy")
def _keys_exact(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, keys):
    """Keys with libm only (no fast path): for tests of the fast path."""
    for i in range(points.shape[0]):
        dx = np.float64(points[i, 0]) - ox
        dy = np.float64(points[i, 1]) - oy
        dz = np.float64(points[i, 2]) - oz
        v, h = _bins_exact(dx, dy, dz, d_theta, d_phi, th0, th1, nv, nh)
        keys[i] = -1 if v < 0 else v * nh + h


def _kernel_params(origin, pattern):
    d_theta, d_phi, th0, th1 = pattern.radians
    rmin, rmax = pattern.range_limits
    nv, nh = pattern.shape
    return (float(origin[0]), float(origin[1]), float(origin[2]),
            d_theta, d_phi, th0, th1, np.int64(nv), np.int64(nh), rmin, rmax)


@njit(cache=True, nogil=True, error_model="numpy")
def _count_nonfinite(points, start, stop):
    bad = 0
    for i in range(start, stop):
        if not (math.isfinite(points[i, 0]) and math.isfinite(points[i, 1])
                and math.isfinite(points[i, 2])):
            bad += 1
    return bad


# --- dense per-pulse arrays ----------------------------------------------------

@njit(cache=True, nogil=True, error_model="numpy")
def _reduce_dense(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                  branges, bidx, offset, start, stop):
    """Bin points[start:stop] into dense per-pulse arrays; returns new bins."""
    x, y, z, th, ph, keys, ranges = _scratch()
    new = 0
    for s in range(start, stop, _BLOCK):
        e = min(stop, s + _BLOCK)
        _block_keys(points, s, e, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                    x, y, z, th, ph, keys, ranges)
        for i in range(e - s):
            key = keys[i]
            if key < 0:
                continue
            r = ranges[i]
            # indices only grow within a table: a strict < keeps ties on the lowest
            if r < branges[key]:
                if bidx[key] < 0:
                    new += 1
                branges[key] = r
                bidx[key] = offset + s + i
    return new


@njit(cache=True, nogil=True, error_model="numpy")
def _merge_dense(branges, bidx, oranges, oidx, start, stop):
    """Fold keys [start, stop) of another table into this one; returns new bins."""
    new = 0
    for k in range(start, stop):
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


# --- hash tables of records (key, r, idx) ---------------------------------------

@njit(cache=True, inline="always", error_model="numpy")
def _slot(key, bits):
    """Slot of a key: groups of 2**_GROUP neighbouring keys share a hashed run."""
    g = np.int64((np.uint64(key >> _GROUP) * _HASH) >> np.uint64(64 - bits + _GROUP))
    return (g << _GROUP) | (key & ((1 << _GROUP) - 1))


@njit(cache=True, inline="always", error_model="numpy")
def _put(tab, bits, key, r, idx):
    """Insert or improve one bin; returns (slot, 1 if the bin is new)."""
    mask = tab.shape[0] - 1
    s = _slot(key, bits)
    while True:
        e = tab[s]
        k = e.key
        if k == key:
            if r < e.r or (r == e.r and idx < e.idx):
                e.r = r
                e.idx = idx
            return s, 0
        if k == -1:
            e.key = key
            e.r = r
            e.idx = idx
            return s, 1
        s = (s + 1) & mask


@njit(cache=True, inline="always", error_model="numpy")
def _owner(key, n_parts):
    """The thread (of ``n_parts``, at most 256) that owns a key's bin: groups of
    16 neighbouring keys, dealt out in runs of 256 groups. A multiply and a shift:
    an integer ``%`` here cost as much as the whole insertion."""
    return (((key >> _GROUP) & 255) * n_parts) >> 8


@njit(cache=True, nogil=True, error_model="numpy")
def _block_keys_range(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                      keys, ranges, start, stop):
    """Keys and ranges of points[start:stop] into keys[start:stop], ranges[start:stop]."""
    x, y, z, th, ph, kb, rb = _scratch()
    for s in range(start, stop, _BLOCK):
        e = min(stop, s + _BLOCK)
        _block_keys(points, s, e, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                    x, y, z, th, ph, kb, rb)
        keys[s:e] = kb[: e - s]
        ranges[s:e] = rb[: e - s]


@njit(cache=True, nogil=True, error_model="numpy")
def _insert_part(tab, count, keys, ranges, offset, part, n_parts, start):
    """Insert the keys of one share (``_owner(key, n_parts) == part``).

    Stops when the table reaches its load limit; returns (count, next position)
    so that the caller grows it and goes on.
    """
    bits = int(math.log2(tab.shape[0]) + 0.5)
    limit = (tab.shape[0] * 7) // 10
    last_key = np.int64(-1)
    last = np.int64(0)
    n = keys.shape[0]
    for i in range(start, n):
        key = keys[i]
        if key < 0 or _owner(key, n_parts) != part:
            continue
        r = ranges[i]
        if key == last_key:  # scans are ordered: neighbours often share a pulse
            if r < tab[last].r:
                tab[last].r = r
                tab[last].idx = offset + i
            continue
        if count >= limit:
            return count, i
        last, new = _put(tab, bits, key, r, offset + i)
        last_key = key
        count += new
    return count, n


@njit(cache=True, nogil=True, error_model="numpy")
def _extract_hash(tab, keys, ranges, idx, at):
    j = at
    for s in range(tab.shape[0]):
        if tab[s].key != -1:
            keys[j] = tab[s].key
            ranges[j] = tab[s].r
            idx[j] = tab[s].idx
            j += 1
    return j


@njit(cache=True, nogil=True, error_model="numpy")
def _pack_hash(tab, packed, bits, at):
    """``(index << bits) | key`` of every occupied record into packed[at:]."""
    j = at
    for s in range(tab.shape[0]):
        if tab[s].key != -1:
            packed[j] = (np.int64(tab[s].idx) << bits) | np.int64(tab[s].key)
            j += 1
    return j


@njit(cache=True, nogil=True, error_model="numpy")
def _unpack(packed, bits, keys, idx):
    mask = (np.int64(1) << bits) - 1
    for j in range(packed.shape[0]):
        keys[j] = packed[j] & mask
        idx[j] = packed[j] >> bits


@njit(cache=True, nogil=True, error_model="numpy")
def _ranges_of(points, idx, ox, oy, oz, out):
    """Ranges of points[idx], by the same arithmetic as the reduction."""
    for j in range(idx.shape[0]):
        i = idx[j]
        dx = np.float64(points[i, 0]) - ox
        dy = np.float64(points[i, 1]) - oy
        dz = np.float64(points[i, 2]) - oz
        out[j] = math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, nogil=True, error_model="numpy")
def _merge_hash(src, dst):
    """Insert every bin of ``src`` into ``dst`` (large enough); returns new bins."""
    bits = int(math.log2(dst.shape[0]) + 0.5)
    new = 0
    for j in range(src.shape[0]):
        e = src[j]
        if e.key != -1:
            new += _put(dst, bits, np.int64(e.key), e.r, np.int64(e.idx))[1]
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

    def absorb(self, other: "_DenseTable", pool=None, n_parts: int = 1) -> None:
        """Fold ``other`` in (its entries stay: they are dominated now, so a
        later absorb of the same table changes nothing)."""
        if not other.count:
            return
        n = len(self.idx)
        step = -(-n // n_parts)
        parts = [(a, min(a + step, n)) for a in range(0, n, step)]
        args = (self.ranges, self.idx, other.ranges, other.idx)
        if pool is None or len(parts) == 1:
            self.count += sum(_merge_dense(*args, a, b) for a, b in parts)
        else:
            self.count += sum(pool.map(lambda ab: _merge_dense(*args, *ab), parts))

    def clear(self, keys=None) -> None:
        """Empty the table: only at ``keys`` when every occupied bin is among them."""
        if keys is None:
            self.ranges.fill(np.inf)
            self.idx.fill(-1)
        else:
            self.ranges[keys] = np.inf
            self.idx[keys] = -1
        self.count = 0

    def extract(self):
        """Occupied bins ``(keys, ranges, indices)`` sorted by index."""
        keys = np.flatnonzero(self.idx >= 0).astype(np.int64)
        idx = self.idx[keys]
        bits = max(1, int(len(self.idx) - 1).bit_length())
        if len(keys) and int(idx.max()) < 1 << (63 - bits):
            # one sort of (index, key) packed in an int64 is faster than an argsort
            packed = np.sort((idx << bits) | keys)
            keys = packed & ((1 << bits) - 1)
            idx = packed >> bits
        else:  # pragma: no cover - more than 2**40 points
            order = np.argsort(idx)
            keys, idx = keys[order], idx[order]
        return keys, self.ranges[keys], idx

    @property
    def nbytes(self) -> int:
        return self.ranges.nbytes + self.idx.nbytes


class _HashTable:
    """One thread's open-addressing hash table of (key, range, index) records.

    Load factor at most 0.7 (linear probing, keys hashed in groups of 16).
    ``compact``: 16-byte records (int32 key, uint32 index) instead of 24;
    :meth:`widen` converts when indices outgrow them.
    """

    __slots__ = ("tab", "count")

    def __init__(self, bits: int = _INITIAL_BITS, compact: bool = False):
        self.tab = np.empty(1 << bits, dtype=_COMPACT_RECORD if compact else _RECORD)
        self.tab["key"] = -1
        self.count = 0

    @property
    def compact(self) -> bool:
        return self.tab.dtype == _COMPACT_RECORD

    def grow(self) -> None:
        with _GROW_LOCK:
            tab = np.empty(2 * len(self.tab), dtype=self.tab.dtype)
            tab["key"] = -1
            _merge_hash(self.tab, tab)
            self.tab = tab

    def widen(self) -> None:
        """Convert to 24-byte records in place of the compact ones (same slots:
        a record's slot depends on its key and the capacity only)."""
        if self.compact:
            with _GROW_LOCK:
                tab = np.empty(len(self.tab), dtype=_RECORD)
                for f in ("key", "r", "idx"):
                    tab[f] = self.tab[f]
                self.tab = tab

    def insert(self, keys, ranges, offset, part, n_parts) -> None:
        start = 0
        while True:
            self.count, start = _insert_part(self.tab, self.count, keys, ranges, offset,
                                             part, n_parts, start)
            if start >= len(keys):
                return
            self.grow()

    @property
    def nbytes(self) -> int:
        return self.tab.nbytes


@njit(cache=True, nogil=True, error_model="numpy")
def _insert_slots(slots, rec, count, keys, ranges, offset, part, n_parts, start):
    """Insert the keys of one share (``_owner(key, n_parts) == part``) into a
    slot table: ``slots[key]`` is the bin's record in ``rec`` or -1.

    Each key has one owner, which sees its points in index order, so a strict
    ``<`` keeps ties on the lowest index. Stops when ``rec`` is full; returns
    (count, next position) so that the caller grows it and goes on.
    """
    last_key = np.int64(-1)
    last = np.int64(0)
    n = keys.shape[0]
    cap = rec.shape[0]
    for i in range(start, n):
        key = keys[i]
        if key < 0 or _owner(key, n_parts) != part:
            continue
        r = ranges[i]
        if key != last_key:
            j = np.int64(slots[key])
            if j < 0:
                if count >= cap:
                    return count, i
                j = count
                slots[key] = j
                rec[j].key = key
                rec[j].r = r
                rec[j].idx = offset + i
                count += 1
                last_key = key
                last = j
                continue
            last_key = key
            last = j
        if r < rec[last].r:
            rec[last].r = r
            rec[last].idx = offset + i
    return count, n


@njit(cache=True, nogil=True, error_model="numpy")
def _clear_slots(slots, rec, count):
    for j in range(count):
        slots[rec[j].key] = -1


class _SlotTable:
    """One thread's bins in a table indexed directly by pulse key.

    ``slots`` (int32 per pulse, shared by the threads: each owns the keys
    ``(key >> 4) % n_threads == part``, i.e. whole 64-byte lines of it) holds
    the position of a bin's ``(key, range, index)`` record in this thread's
    compact record array. No hashing, no probing, and clearing it for the
    next scan costs O(occupied bins). Used for patterns of up to
    :attr:`BinTables.slot_bytes` / 4 pulses (SYNS's 0.036 deg: 37.5 M).
    """

    __slots__ = ("slots", "rec", "count")

    def __init__(self, slots, capacity: int = 1 << _INITIAL_BITS):
        self.slots = slots
        self.rec = np.empty(capacity, dtype=_RECORD)
        self.count = 0

    def insert(self, keys, ranges, offset, part, n_parts) -> None:
        start = 0
        while True:
            self.count, start = _insert_slots(self.slots, self.rec, self.count, keys, ranges,
                                              offset, part, n_parts, start)
            if start >= len(keys):
                return
            rec = np.empty(2 * len(self.rec), dtype=_RECORD)
            rec[: self.count] = self.rec[: self.count]
            self.rec = rec

    def clear(self) -> None:
        _clear_slots(self.slots, self.rec, self.count)
        self.count = 0

    @property
    def tab(self):
        """The occupied records (the layout of a hash table's occupied slots)."""
        return self.rec[: self.count]

    @property
    def nbytes(self) -> int:
        return self.rec.nbytes


def _sort_by_index(keys, ranges, idx):
    """Reorder three parallel arrays by ``idx`` (unique)."""
    m = len(idx)
    bits = max(1, int(m).bit_length())
    if m and int(idx.max()) < 1 << (63 - bits):
        # sorting (index, position) packed in an int64 is much faster than argsort
        packed = np.sort((idx << bits) | np.arange(m, dtype=np.int64))
        order = packed & ((1 << bits) - 1)
        return keys[order], ranges[order], packed >> bits
    order = np.argsort(idx)  # pragma: no cover - beyond 2**40 points
    return keys[order], ranges[order], idx[order]


class BinTables:
    """Per-bin minimum of (range, index) for one scanner position and pattern.

    The state of a streamed binning reduction. :meth:`add` reduces a chunk of
    points (indices continue across chunks); :meth:`winners` returns the
    occupied bins. Used by :func:`slr_ray.simulate_scan` and
    :class:`slr_ray.ScanAccumulator`; most users want those instead.
    """

    #: memory allowed for dense per-pulse arrays, all threads together
    dense_bytes = 256 * 2**20
    #: memory allowed for the shared per-pulse slot array of the slot tables
    slot_bytes = 512 * 2**20

    @property
    def dense(self) -> bool:
        """Per-thread dense per-pulse arrays (patterns with few pulses)."""
        return self.kind == "dense"

    @property
    def reusable(self) -> bool:
        """Whether :meth:`reset` clears in O(occupied bins) (dense and slot tables)."""
        return self.kind in ("dense", "slots")

    def __init__(self, origin, pattern, n_threads: int | None = None, key_range: tuple | None = None,
                 slot_bytes: int | None = None):
        self.origin = origin
        self.pattern = pattern
        #: ``slot_bytes``: this call's allowance for slot tables instead of the class's
        #: (a dense mesh scan allows more: its tables live through 1e9 samples)
        #: ``(lo, hi)``: only pulse keys in [lo, hi) are kept (a band of zenith rows
        #: when lo, hi are multiples of n_azimuth), so a fine pattern can be reduced
        #: band by band in bounded memory; slot and hash tables only
        self.key_range = None if key_range is None else (int(key_range[0]), int(key_range[1]))
        self.n_threads = int(n_threads or default_threads())
        if not 1 <= self.n_threads <= 256:
            raise ValueError(f"n_threads must be in [1, 256], got {n_threads}")
        if pattern.n_pulses * 16 * self.n_threads <= self.dense_bytes:
            self.kind = "dense"
        elif pattern.n_pulses * 4 <= (self.slot_bytes if slot_bytes is None else slot_bytes):
            self.kind = "slots"
        else:
            self.kind = "hash"
        if self.key_range is not None and self.kind == "dense":
            self.kind = "hash"  # a band of a coarse pattern: the tables follow the band, not the pattern
        self._slots = np.full(pattern.n_pulses, -1, np.int32) if self.kind == "slots" else None
        self._compact = self.kind == "hash" and pattern.n_pulses <= _COMPACT_MAX_PULSES
        self.tables = [self._new_table() for _ in range(self.n_threads)]
        self.n_points = 0
        self._params = _kernel_params(origin, pattern)
        #: occupied keys of the merged dense table when no add() came after
        #: the merge: then they are all that reset() has to clear
        self._touched = None

    def reset(self, origin) -> "BinTables":
        """Empty the tables for a new scanner position with the same pattern.

        Reuses the memory: after :meth:`winners`, dense tables are cleared at
        their occupied bins only (O(occupied), not O(pulses)), which is what
        lets a prepared scanner run thousands of positions without allocating
        and faulting in tens of MB per scan.
        """
        self.origin = origin
        self._params = _kernel_params(origin, self.pattern)
        self.n_points = 0
        if self.kind == "dense":
            for t in self.tables:
                t.clear(self._touched)
        elif self.kind == "slots":
            for t in self.tables:
                t.clear()
        else:
            self._compact = self.pattern.n_pulses <= _COMPACT_MAX_PULSES
            self.tables = [self._new_table() for _ in self.tables]
        self._touched = None
        return self

    def _new_table(self):
        if self.kind == "dense":
            return _DenseTable(self.pattern.n_pulses)
        return _SlotTable(self._slots) if self.kind == "slots" else _HashTable(compact=self._compact)

    #: points whose keys are computed before the threads insert them (slot and hash tables)
    superblock = 1 << 21

    def _slices(self, n):
        step = -(-n // self.n_threads)
        return [(s, min(s + step, n)) for s in range(0, n, step)]

    def add(self, points: np.ndarray, finite: bool = False) -> int:
        """Reduce ``points`` ((n, 3) float32/64, C-contiguous) into the tables.

        Returns the number of non-finite rows; when it is not 0 nothing was
        added (the caller raises). ``finite=True``: the caller has already
        checked every row (a prepared scanner), so the counting pass is
        skipped; a non-finite row would then simply not be binned.
        """
        if self.tables is None:
            raise RuntimeError("these tables were released by winners(release=True)")
        n = len(points)
        if n == 0:
            return 0
        self._touched = None
        if not self.dense:
            return self._add_hash(points, finite)
        slices = self._slices(n)
        if len(slices) == 1:
            bad = 0 if finite else _count_nonfinite(points, 0, n)
            if bad:
                return bad
            self.tables[0].reduce(points, self._params, self.n_points, 0, n)
        else:
            with ThreadPoolExecutor(len(slices)) as pool:
                bad = 0 if finite else sum(pool.map(lambda se: _count_nonfinite(points, *se), slices))
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

    def _add_hash(self, points, finite: bool = False) -> int:
        """Slot and hash tables: threads split the *keys* (no merge needed), in two
        phases per superblock: keys computed over point slices, then inserted by owner."""
        n = len(points)
        T = self.n_threads
        pool = ThreadPoolExecutor(T) if T > 1 else None
        run = (lambda f, args: list(pool.map(lambda a: f(*a), args))) if pool else \
            (lambda f, args: [f(*a) for a in args])
        try:
            bad = 0 if finite else sum(run(_count_nonfinite, [(points, s, e) for s, e in self._slices(n)]))
            if bad:
                return bad
            if self._compact and self.n_points + n - 1 > _COMPACT_MAX_POINTS:
                for t in self.tables:  # indices outgrow the compact records
                    t.widen()
                self._compact = False
            size = min(n, self.superblock)
            keys = np.empty(size, np.int64)
            ranges = np.empty(size, np.float64)
            for s0 in range(0, n, size):
                e0 = min(n, s0 + size)
                view = points[s0:e0]
                m = e0 - s0
                step = -(-m // T)
                run(_block_keys_range, [(view, *self._params, keys, ranges, s, min(s + step, m))
                                        for s in range(0, m, step)])
                if self.key_range is not None:
                    lo, hi = self.key_range
                    keys[:m][(keys[:m] < lo) | (keys[:m] >= hi)] = -1
                run(lambda t, part: t.insert(keys[:m], ranges[:m], self.n_points + s0, part, T),
                    [(t, part) for part, t in enumerate(self.tables)])
        finally:
            if pool is not None:
                pool.shutdown()
        self.n_points += n
        return 0

    def _merged(self):
        """Dense tables: fold all into the first (threads split the points; the
        merge splits the keys)."""
        first, *rest = self.tables
        if any(t.count for t in rest):
            with ThreadPoolExecutor(self.n_threads) as pool:
                for t in rest:  # their entries stay; a later merge changes nothing
                    first.absorb(t, pool, self.n_threads)
        return first

    @property
    def n_bins(self) -> int:
        """Number of occupied pulse bins so far."""
        if self.dense:
            return self._merged().count
        return sum(t.count for t in self.tables)

    @property
    def nbytes(self) -> int:
        """Bytes held by the tables."""
        return sum(t.nbytes for t in self.tables) + (0 if self._slots is None else self._slots.nbytes)

    def winners(self, points=None, with_ranges: bool = True, release: bool = False):
        """Occupied bins as ``(keys, ranges, indices)``, sorted by index.

        ``points``: the cloud, when the caller still has it (one-shot scans):
        ranges are then recomputed from it, which is faster than carrying
        them through the sort. ``with_ranges=False`` returns ``None`` for the
        ranges and needs the least memory (the dense-scene path recomputes
        them from the regenerated samples). ``release=True`` frees each
        thread's table as soon as it is read out, so the result never sits
        next to all of them (the 0.00576 deg dense primary: 12.9 GB of hash
        tables against 5 GB of result); the tables cannot be used afterwards.
        """
        if self.tables is None:
            raise RuntimeError("these tables were released by winners(release=True)")
        if self.dense:
            keys, ranges, idx = self._merged().extract()
            self._touched = keys
            return keys, (ranges if with_ranges else None), idx
        m = self.n_bins
        n_pulse_bits = max(1, int(self.pattern.n_pulses - 1).bit_length())
        fits = int(max(self.n_points - 1, 1)).bit_length() + n_pulse_bits <= 63
        if m and fits and (points is not None or not with_ranges):
            packed = np.empty(m, np.int64)
            at = 0
            for i, t in enumerate(self.tables):
                at = _pack_hash(t.tab, packed, n_pulse_bits, at)
                if release:
                    self.tables[i] = None  # freed before the next is read out
            if release:
                self.tables = self._slots = None
            packed.sort()
            keys = np.empty(m, np.int64)
            idx = np.empty(m, np.int64)
            _unpack(packed, n_pulse_bits, keys, idx)
            del packed
            ranges = None
            if with_ranges:
                ranges = np.empty(m, np.float64)
                _ranges_of(points, idx, *self._params[:3], ranges)
            return keys, ranges, idx
        keys = np.empty(m, np.int64)
        ranges = np.empty(m, np.float64)
        idx = np.empty(m, np.int64)
        at = 0
        for t in self.tables:  # threads own disjoint keys: concatenate
            at = _extract_hash(t.tab, keys, ranges, idx, at)
        return _sort_by_index(keys, ranges, idx)


def ranges_of(points: np.ndarray, indices: np.ndarray, origin) -> np.ndarray:
    """``(m,) float64`` distances from ``origin`` of ``points[indices]``, in float64
    (float32 points are widened first), without copying the selected rows."""
    o = as_origin(origin)
    out = np.empty(len(indices), np.float64)
    _ranges_of(points, np.asarray(indices, np.int64), float(o[0]), float(o[1]), float(o[2]), out)
    return out


@dataclass(frozen=True)
class BinningOptions(BackendOptions):
    """Options of the binning backend.

    Attributes
    ----------
    n_threads : int, optional
        Threads reducing the points (default: all cores).
    """

    n_threads: int | None = None

    def __post_init__(self):
        if self.n_threads is not None and (int(self.n_threads) != self.n_threads
                                           or not 1 <= self.n_threads <= 256):
            raise InputValueError(f"n_threads must be an integer in [1, 256], got {self.n_threads!r}")


class BinningScanner(Scanner):
    """The binning backend prepared on a cloud: nothing to build, the points are
    checked once (non-finite rows are refused with their count).

    :meth:`scan` keeps, per occupied pulse, the point with the smallest range
    (ties to the lowest index): the paper's nearest-in-pulse rule, exactly.
    """

    backend = "binning"

    def __init__(self, points: np.ndarray, options: BinningOptions | None = None):
        t0 = time.perf_counter()
        options = options or BinningOptions()
        n = len(points)
        if n:
            bad = _count_nonfinite(points, 0, n)
            if bad:
                raise InputValueError(
                    f"points has {bad} row(s) with NaN or inf out of {n}; "
                    "remove them first (nothing is dropped silently)")
        super().__init__(points, options, time.perf_counter() - t0)
        # the last scan's tables, reused by the next scan with the same pattern
        # (a scan from another thread meanwhile gets its own)
        self._cache = None
        self._lock = threading.Lock()

    def _tables_for(self, origin, pattern) -> BinTables:
        if self._lock.acquire(blocking=False):
            cached, self._cache = self._cache, None
            self._lock.release()
            if cached is not None and cached.pattern == pattern:
                return cached.reset(origin)
        return BinTables(origin, pattern, n_threads=self.options.n_threads)

    def _release(self, tables: BinTables) -> None:
        if tables.reusable and self._lock.acquire(blocking=False):
            self._cache = tables
            self._lock.release()

    def scan(self, origin, pattern) -> Scan:
        t0 = time.perf_counter()
        origin = as_origin(origin)
        pattern = as_pattern(pattern)
        if not isinstance(pattern, ScanPattern):  # a beam table: per-(beam, column) dense reduction
            keys, ranges, idx = pattern.reduce(self.points, origin, self.options.n_threads)
            return Scan.from_keys(keys, ranges, idx, origin, pattern, self.backend, len(self.points),
                                  time.perf_counter() - t0)
        tables = self._tables_for(origin, pattern)
        try:
            tables.add(self.points, finite=True)  # checked when prepared
            keys, ranges, idx = tables.winners(self.points)
        finally:
            self._release(tables)
        return Scan.from_keys(keys, ranges, idx, origin, pattern, self.backend, len(self.points),
                              time.perf_counter() - t0)
