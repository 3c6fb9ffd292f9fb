"""Per-pulse minimum of (range, index): the tables of the nearest-in-pulse rule.

Per occupied pulse bin the point with the smallest range wins; ties go to the
lowest input index (docs/backends.md, "What a scan returns (the ideal
scanner)"). Each point goes into a table that keeps, per pulse key ``v * n_azimuth + h`` (:mod:`slr_ray.core.grid`),
the smallest ``(range, index)``. Non-finite rows are counted first and
refused, so a bad chunk leaves the state untouched.

Tables are of three kinds, by the pattern's size:

- **dense** (``16 * n_pulses * n_threads`` bytes within
  :attr:`BinTables.dense_bytes`, 256 MiB; 0.144 deg has 3.1e6 pulses): plain
  per-pulse arrays, one per thread; threads split the points and the tables
  merge, in parallel, in O(pulses) when the result is asked for;
- **slots** (``4 * n_pulses`` within :attr:`BinTables.slot_bytes`, 512 MiB;
  SYNS's 0.036 deg has 3.75e7 pulses): int32 slots per pulse pointing into
  compact records ``(key, range, index)`` (:mod:`slr_ray.core.slots`). While
  a slot array per thread fits the allowance (:attr:`BinTables.own_slots`),
  each thread has its own and keys and inserts chunks of the points in one
  pass; the tables are folded into the first when the result is asked for.
  Otherwise one shared array, whose whole 64-byte lines the threads own, so
  nothing is merged or hashed;
- **hash** (finer patterns: 0.001 deg would be 6.5e10 pulses): an
  open-addressing hash table of 24-byte records per thread that grows with
  the number of *occupied* bins (at most twice that while growing), never
  with the number of points or of possible pulses. Neighbouring pulses hash
  to neighbouring slots in groups of 16, so scan-ordered clouds touch memory
  in order.

With shared slot and hash tables the threads split the *keys*: keys are
computed for a superblock of points in parallel, then each thread inserts the
keys it owns. The winners come out in index order without a sort
(:mod:`slr_ray.core.order`). Dense and slot tables are cleared in O(occupied bins) and reused from
one scan to the next by a prepared binning scanner. The tables outlive a
call, which is what :class:`slr_ray.ScanAccumulator` uses to reduce a cloud
chunk by chunk to exactly the one-shot answer, and what the dense mesh scans
(:mod:`slr_ray.meshscan`) reduce their samples with.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from ..arrays import unravel_ids
from ..errors import InputValueError, StateError
from ..threads import default_threads
from .grid import BLOCK, block_keys, block_keys_range, count_nonfinite, kernel_params, ranges_into, scratch
from .order import (in_index_order, mark_alive, mark_dense, mark_records, place_alive, place_alive_pulses,
                    place_dense, place_records, place_records_pulses)
from .slots import GROUP, INITIAL_CAPACITY, RECORD, SlotTable, mark_losers, owner

__all__ = ["BinTables"]

_HASH = np.uint64(0x9E3779B97F4A7C15)
#: neighbouring keys share a group of 2**_GROUP consecutive slots
_GROUP = GROUP
_INITIAL_BITS = 12
_RECORD = RECORD
#: the hash tables' compact record (16 bytes instead of 24): for patterns of fewer
#: than 2**31 pulses while point indices stay below 2**32 (a 0.00576 deg pattern
#: has 1.95e9 pulses; its dense primary's 2e8 bins take 8 GiB of tables, not 12)
_COMPACT_RECORD = np.dtype([("key", np.int32), ("idx", np.uint32), ("r", np.float64)])
_COMPACT_MAX_PULSES = 2**31 - 1
_COMPACT_MAX_POINTS = 2**32 - 1
#: one hash table grows at a time: two threads doubling theirs at once held
#: old and new tables of both (18.4 GiB for that primary instead of 12)
_GROW_LOCK = threading.Lock()


# --- dense per-pulse arrays ----------------------------------------------------

@njit(cache=True, nogil=True, error_model="numpy")
def _reduce_dense(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                  branges, bidx, offset, start, stop):
    """Bin points[start:stop] into dense per-pulse arrays; returns new bins."""
    x, y, z, th, ph, keys, ranges = scratch()
    new = 0
    for s in range(start, stop, BLOCK):
        e = min(stop, s + BLOCK)
        block_keys(points, s, e, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
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


@njit(cache=True, nogil=True, error_model="numpy")
def _insert_part(tab, count, keys, ranges, offset, part, n_parts, start):
    """Insert the keys of one share (``owner(key, n_parts) == part``).

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
        if key < 0 or owner(key, n_parts) != part:
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

    def extract(self, n_points: int):
        """Occupied bins ``(keys, ranges, indices)`` sorted by index (every index below ``n_points``)."""
        return in_index_order(n_points, self.count, lambda bits: mark_dense(self.idx, bits),
                               lambda *out: place_dense(self.idx, self.ranges, *out))

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
    #: memory allowed for the per-pulse slot arrays of the slot tables
    slot_bytes = 512 * 2**20
    #: records of a table beyond which reading out own slot tables (finding the bins two tables
    #: hold, or folding) is split over the threads
    parallel_records = 1 << 16
    #: each thread keeps a slot array of its own while they all fit ``slot_bytes``
    #: (threads split the points and key and insert them in one pass); else the
    #: threads share one and insert the keys they own
    own_slots = True

    @property
    def dense(self) -> bool:
        """Per-thread dense per-pulse arrays (patterns with few pulses)."""
        return self.kind == "dense"

    @property
    def reusable(self) -> bool:
        """Whether :meth:`reset` clears in O(occupied bins) (dense and slot tables)."""
        return self.kind in ("dense", "slots")

    def __init__(self, origin, pattern, n_threads: int | None = None, key_range: tuple | None = None,
                 slot_bytes: int | None = None, own_slots: bool | None = None, expected_bins: int | None = None):
        self.origin = origin
        #: ``expected_bins``: about how many bins a scan will fill (a prepared scanner's
        #: previous scan): slot tables start with room for them rather than growing by
        #: doubling from a few thousand (each growth a fresh array and a copy)
        self._expected = int(expected_bins or 0)
        self.pattern = pattern
        #: ``slot_bytes``: this call's allowance for slot tables instead of the class's
        #: (a dense mesh scan allows more: its tables live through 1e9 samples)
        #: ``(lo, hi)``: only pulse keys in [lo, hi) are kept (a band of zenith rows
        #: when lo, hi are multiples of n_azimuth), so a fine pattern can be reduced
        #: band by band in bounded memory; slot and hash tables only
        self.key_range = None if key_range is None else (int(key_range[0]), int(key_range[1]))
        self.n_threads = int(n_threads or default_threads())
        if not 1 <= self.n_threads <= 256:
            raise InputValueError(f"n_threads must be in [1, 256], got {n_threads}")
        if pattern.n_pulses * 16 * self.n_threads <= self.dense_bytes:
            self.kind = "dense"
        elif pattern.n_pulses * 4 <= (self.slot_bytes if slot_bytes is None else slot_bytes):
            self.kind = "slots"
        else:
            self.kind = "hash"
        if self.key_range is not None and self.kind == "dense":
            self.kind = "hash"  # a band of a coarse pattern: the tables follow the band, not the pattern
        allowance = self.slot_bytes if slot_bytes is None else slot_bytes
        #: slot tables of their own per thread (threads split the points, one pass) while they fit
        #: ``own_slots``: this call's choice instead of the class's (a one-shot scan
        #: allocates one shared slot array rather than one per thread)
        self._private = (self.kind == "slots" and (self.own_slots if own_slots is None else own_slots)
                         and pattern.n_pulses * 4 * self.n_threads <= allowance)
        self.could_own_slots = (self.kind == "slots" and self.own_slots and not self._private
                                and pattern.n_pulses * 4 * self.n_threads <= allowance)
        self._slots = np.zeros(pattern.n_pulses, np.int32) if self.kind == "slots" and not self._private \
            else None
        self._compact = self.kind == "hash" and pattern.n_pulses <= _COMPACT_MAX_PULSES
        self.tables = [self._new_table(i) for i in range(self.n_threads)]
        self.n_points = 0
        self._params = kernel_params(origin, pattern)
        #: occupied keys of the merged dense table when no add() came after
        #: the merge: then they are all that reset() has to clear
        self._touched = None
        #: own slot tables: the others are folded into the first since the last add()
        self._folded = False
        #: own slot tables: (records of each table, which of them another table beats, winners) since the last add()
        self._resolution = None
        #: own slot tables: every add so far began on a 64-point word (tables never share a word of winners)
        self._word_aligned = True

    def reset(self, origin) -> "BinTables":
        """Empty the tables for a new scanner position with the same pattern.

        Reuses the memory: after :meth:`winners`, dense tables are cleared at
        their occupied bins only (O(occupied), not O(pulses)), which is what
        lets a prepared scanner run thousands of positions without allocating
        and faulting in tens of MB per scan.
        """
        self.origin = origin
        self._params = kernel_params(origin, self.pattern)
        self.n_points = 0
        self._folded = False
        self._resolution = None
        self._word_aligned = True
        if self.kind == "dense":
            for t in self.tables:
                t.clear(self._touched)
        elif self.kind == "slots":
            if self._private and len(self.tables) > 1 and self.tables[0].count > self.parallel_records:
                with ThreadPoolExecutor(len(self.tables)) as pool:  # each its own slot array: in parallel
                    list(pool.map(SlotTable.clear, self.tables))
            else:
                for t in self.tables:
                    t.clear()
        else:
            self._compact = self.pattern.n_pulses <= _COMPACT_MAX_PULSES
            self.tables = [self._new_table(i) for i in range(len(self.tables))]
        self._touched = None
        return self

    def _new_table(self, i: int = 0):
        if self.kind == "dense":
            return _DenseTable(self.pattern.n_pulses)
        if self.kind == "slots":
            # own tables: the first takes the others' bins when they are folded in; each
            # other holds about its share. Shared: each thread owns about 1/n of the keys
            share = self._expected if (self._private and i == 0) else self._expected // self.n_threads
            capacity = max(INITIAL_CAPACITY, share + share // 8)
            return SlotTable(np.zeros(self.pattern.n_pulses, np.int32) if self._private else self._slots,
                             capacity)
        return _HashTable(compact=self._compact)

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
            raise StateError("these tables were released by winners(release=True)")
        n = len(points)
        if n == 0:
            return 0
        self._touched = None
        if self._private:
            return self._add_private(points, finite)
        if not self.dense:
            return self._add_hash(points, finite)
        slices = self._slices(n)
        if len(slices) == 1:
            bad = 0 if finite else count_nonfinite(points, 0, n)
            if bad:
                return bad
            self.tables[0].reduce(points, self._params, self.n_points, 0, n)
        else:
            with ThreadPoolExecutor(len(slices)) as pool:
                bad = 0 if finite else sum(pool.map(lambda se: count_nonfinite(points, *se), slices))
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

    def _add_private(self, points, finite: bool = False) -> int:
        """Slot tables of their own: each thread keys and inserts chunks of the points in one pass."""
        n = len(points)
        self._word_aligned = self._word_aligned and self.n_points % 64 == 0
        slices = self._slices(n)
        key_range = self.key_range or (0, self.pattern.n_pulses)
        lo, hi = np.int64(key_range[0]), np.int64(key_range[1])

        if len(slices) == 1:
            bad = 0 if finite else count_nonfinite(points, 0, n)
            if bad:
                return bad
            self.tables[0].reduce(points, self._params, (lo, hi), self.n_points, 0, n)
        else:
            # chunks handed out in ascending order as threads come free (parts of a cloud
            # differ in cost: SYNS's first half makes 5.1 M bins, its second 0.46 M); a
            # thread's table still sees its points in ascending order, so ties hold
            # chunks of whole 64-point words (BLOCK is one): while every add starts on a word,
            # no two tables hold winners in one word of the read-out's bitmap, which the
            # tables then mark side by side
            step = max(BLOCK, -(-n // (8 * len(slices))))
            step = -(-step // BLOCK) * BLOCK
            starts = iter(range(0, n, step))
            lock = threading.Lock()

            def run(t):
                while True:
                    with lock:
                        s = next(starts, None)
                    if s is None:
                        return
                    t.reduce(points, self._params, (lo, hi), self.n_points, s, min(n, s + step))

            with ThreadPoolExecutor(len(slices)) as pool:
                bad = 0 if finite else sum(pool.map(lambda se: count_nonfinite(points, *se), slices))
                if bad:
                    return bad
                list(pool.map(run, self.tables[: len(slices)]))
        self.n_points += n
        self._folded = False
        self._resolution = None
        return 0

    def _resolved(self):
        """Own slot tables, unfolded: each table's records and a mask of those
        another table beats in the same bin (farther, or as near with a higher
        index: pairwise, so the nearest of any number of tables is the one
        never beaten), and the number of winners. Cheaper than a fold (a look-up
        per record of the later tables, no record moved) and leaves each table
        only its own records to clear. Computed once per add."""
        if self._folded:  # the release path folded them all into the first
            first = self.tables[0]
            return [first.tab], [np.zeros(first.count, np.bool_)], first.count
        if self._resolution is None:
            tabs = [t.tab for t in self.tables]
            lose = [np.zeros(len(tab), np.bool_) for tab in tabs]
            jobs = []
            for b in range(1, len(tabs)):
                n = len(tabs[b])
                parts = self.n_threads if n > self.parallel_records else 1
                jobs += [(a, b, n * k // parts, n * (k + 1) // parts) for a in range(b) if len(tabs[a])
                         for k in range(parts)]

            def run(job):
                a, b, start, stop = job
                mark_losers(self.tables[a].slots, tabs[a], lose[a], tabs[b], lose[b], start, stop)

            if len(jobs) > 1 and self.n_threads > 1:
                with ThreadPoolExecutor(self.n_threads) as pool:  # losers only ever set to True: races are benign
                    list(pool.map(run, jobs))
            else:
                for job in jobs:
                    run(job)
            m = sum(len(tab) - int(np.count_nonzero(x)) for tab, x in zip(tabs, lose))
            self._resolution = (tabs, lose, m)
        return self._resolution

    def _merged_slots(self) -> "SlotTable":
        """Own slot tables: fold all into the first (their records stay; once
        per add: a second fold would change nothing)."""
        first, *rest = self.tables
        if not self._folded:
            pool = None
            try:
                for t in rest:
                    if self.n_threads > 1 and t.count > self.parallel_records:  # millions of records: split over the threads
                        pool = pool or ThreadPoolExecutor(self.n_threads)
                        first.absorb_parallel(t, pool, self.n_threads)
                    elif t.count:
                        first.absorb(t)
            finally:
                if pool is not None:
                    pool.shutdown()
            self._folded = True
        return first

    def _add_hash(self, points, finite: bool = False) -> int:
        """Slot and hash tables: threads split the *keys* (no merge needed), in two
        phases per superblock: keys computed over point slices, then inserted by owner."""
        n = len(points)
        T = self.n_threads
        pool = ThreadPoolExecutor(T) if T > 1 else None
        run = (lambda f, args: list(pool.map(lambda a: f(*a), args))) if pool else \
            (lambda f, args: [f(*a) for a in args])
        try:
            bad = 0 if finite else sum(run(count_nonfinite, [(points, s, e) for s, e in self._slices(n)]))
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
                run(block_keys_range, [(view, *self._params, keys, ranges, s, min(s + step, m))
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
        if self._private:
            return self._resolved()[2]
        return sum(t.count for t in self.tables)

    @property
    def nbytes(self) -> int:
        """Bytes held by the tables."""
        own = sum(t.slots.nbytes for t in self.tables) if self._private else 0
        return sum(t.nbytes for t in self.tables) + own + (0 if self._slots is None else self._slots.nbytes)

    def winners(self, points=None, with_ranges: bool = True, release: bool = False, as_pulses: bool = False,
                pool=None):
        """Occupied bins as ``(keys, ranges, indices)``, sorted by index.

        ``as_pulses=True``: ``(m, 2) int64`` pulses ``(row, column)`` in place
        of the flat keys (what :class:`~slr_ray.Scan` holds: written once,
        with no flat keys in between). ``pool``: an
        :class:`~slr_ray.core.order.OutputPool` those arrays come from (slot
        and hash tables, ``as_pulses=True``).

        Winners are put in index order without a sort (one bit a point, then
        each bin's record written at its rank), carrying key and range along.
        ``points``: the cloud, when the caller still has it: with
        ``release=True`` ranges are recomputed from it (that path packs and
        sorts, to hold no more than the tables while they are freed one by
        one). ``with_ranges=False`` returns ``None`` for the
        ranges and needs the least memory (the dense-scene path recomputes
        them from the regenerated samples). ``release=True`` frees each
        thread's table as soon as it is read out, so the result never sits
        next to all of them (the 0.00576 deg dense primary: 12.9 GB of hash
        tables against 5 GB of result); the tables cannot be used afterwards.
        """
        if self.tables is None:
            raise StateError("these tables were released by winners(release=True)")
        if self.dense:
            keys, ranges, idx = self._merged().extract(self.n_points)
            self._touched = keys
            return self._out(keys, as_pulses), (ranges if with_ranges else None), idx
        m = self.n_bins
        if not release:
            return self._winners_in_place(m, with_ranges, as_pulses, pool)
        final = [self._merged_slots()] if self._private else self.tables  # freed one by one: folded first
        n_pulse_bits = max(1, int(self.pattern.n_pulses - 1).bit_length())
        fits = int(max(self.n_points - 1, 1)).bit_length() + n_pulse_bits <= 63
        if m and fits and (points is not None or not with_ranges):
            packed = np.empty(m, np.int64)
            at = 0
            if self._private:
                self.tables = final  # the others are folded in
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
                ranges_into(points, idx, *self._params[:3], ranges)
            return self._out(keys, as_pulses), ranges, idx
        keys = np.empty(m, np.int64)
        ranges = np.empty(m, np.float64)
        idx = np.empty(m, np.int64)
        at = 0
        for t in final:  # threads own disjoint keys: concatenate
            at = _extract_hash(t.tab, keys, ranges, idx, at)
        keys, ranges, idx = _sort_by_index(keys, ranges, idx)
        return self._out(keys, as_pulses), ranges, idx

    def _winners_in_place(self, m: int, with_ranges: bool, as_pulses: bool, pool):
        """:meth:`winners` without ``release``: each bin's record written at its index's rank."""
        # every bin's record carries its range: no sort, no gather from the cloud
        if self._private:  # each table's records, less those another table's beat: no fold
            tabs, lose, _ = self._resolved()
        else:
            tabs, lose = [t.tab for t in self.tables], None
        nh = np.int64(self.pattern.shape[1])

        def mark(bits):
            if lose is not None and self._word_aligned and len(tabs) > 1 and self.n_threads > 1 \
                    and m > self.parallel_records:
                # own tables of whole-word chunks: no word holds two tables' winners
                with ThreadPoolExecutor(min(self.n_threads, len(tabs))) as pool:
                    list(pool.map(lambda i: mark_alive(tabs[i], lose[i], bits), range(len(tabs))))
                return
            for i, tab in enumerate(tabs):  # one after the other: threads would race on a word
                if lose is None:
                    mark_records(tab, bits)
                else:
                    mark_alive(tab, lose[i], bits)

        def place(*out):
            # every record has its own place: shares of the records are written out in
            # parallel (and the fresh output pages are faulted in by all threads)
            if lose is None and as_pulses:
                run = lambda tab, _: place_records_pulses(tab, out[0], out[1], nh, *out[2:])  # noqa: E731
            elif lose is None:
                run = lambda tab, _: place_records(tab, *out)  # noqa: E731
            elif as_pulses:
                run = lambda tab, x: place_alive_pulses(tab, x, out[0], out[1], nh, *out[2:])  # noqa: E731
            else:
                run = lambda tab, x: place_alive(tab, x, *out)  # noqa: E731
            parts = max(1, min(self.n_threads, m >> 16))
            shares = [(tab[len(tab) * i // parts: len(tab) * (i + 1) // parts],
                       None if lose is None else lose[t][len(tab) * i // parts: len(tab) * (i + 1) // parts])
                      for t, tab in enumerate(tabs) for i in range(parts)]
            if parts > 1:
                with ThreadPoolExecutor(parts) as pool:
                    list(pool.map(lambda sh: run(*sh), shares))
            else:
                for share in shares:
                    run(*share)

        keys, ranges, idx = in_index_order(self.n_points, m, mark, place, (2,) if as_pulses else (),
                                           pool.take if pool is not None and as_pulses else None)
        return keys, (ranges if with_ranges else None), idx

    def _out(self, keys, as_pulses: bool):
        return unravel_ids(keys, self.pattern.shape[1]) if as_pulses else keys


