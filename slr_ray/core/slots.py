"""Slot tables: one thread's per-pulse minimum of (range, index) for patterns of
up to tens of millions of pulses (SYNS's 0.036 deg: 37.5 M), used by
:class:`slr_ray.core.BinTables` (module docstring of :mod:`slr_ray.core.tables`).

A per-pulse int32 slot points into compact records ``(key, range, index)``
(it holds the record's position plus one: 0 is empty, so a fresh slot array
is ``np.zeros``, whose pages the system maps as they are first touched, with
no pass filling it): no hashing, no probing, and clearing for the next scan
costs O(occupied bins).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .grid import BLOCK, block_keys, scratch

__all__ = ["SlotTable", "RECORD", "GROUP", "INITIAL_CAPACITY", "owner", "mark_losers"]

#: a bin's record (the hash tables' wide record too)
RECORD = np.dtype([("key", np.int64), ("r", np.float64), ("idx", np.int64)])
#: neighbouring keys share a group of 2**GROUP consecutive slots (hash tables) or owner
GROUP = 4
INITIAL_CAPACITY = 1 << 12


@njit(cache=True, inline="always", error_model="numpy")
def owner(key, n_parts):
    """The thread (of ``n_parts``, at most 256) that owns a key's bin: groups of
    16 neighbouring keys, dealt out in runs of 256 groups. A multiply and a shift:
    an integer ``%`` here cost as much as the whole insertion."""
    return (((key >> GROUP) & 255) * n_parts) >> 8



@njit(cache=True, nogil=True, error_model="numpy")
def _insert_slots(slots, rec, count, keys, ranges, offset, part, n_parts, start):
    """Insert the keys of one share (``owner(key, n_parts) == part``) into a
    slot table: ``slots[key]`` is one more than the bin's record in ``rec``, 0 for none.

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
        if key < 0 or owner(key, n_parts) != part:
            continue
        r = ranges[i]
        if key != last_key:
            j = np.int64(slots[key]) - 1
            if j < 0:
                if count >= cap:
                    return count, i
                j = count
                slots[key] = j + 1
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
        slots[rec[j].key] = 0


@njit(cache=True, nogil=True, error_model="numpy")
def _reduce_slots(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax, lo, hi,
                  slots, rec, count, offset, start, stop):
    """Key points[start:stop] and insert them straight into one thread's own slot
    table (keys in [lo, hi) only): no key arrays in between. Stops before a
    block that might overflow ``rec``; returns (count, next position) so that
    the caller grows it and goes on."""
    x, y, z, th, ph, keys, ranges = scratch()
    cap = rec.shape[0]
    last_key = np.int64(-1)
    last = np.int64(0)
    for s in range(start, stop, BLOCK):
        e = min(stop, s + BLOCK)
        if count + (e - s) > cap:
            return count, s
        block_keys(points, s, e, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                   x, y, z, th, ph, keys, ranges)
        for i in range(e - s):
            key = keys[i]
            if key < lo or key >= hi:  # not seen (-1, -2) or outside the band
                continue
            r = ranges[i]
            if key != last_key:  # scans are ordered: neighbours often share a pulse
                last_key = key
                j = np.int64(slots[key]) - 1
                if j < 0:
                    slots[key] = count + 1
                    rec[count].key = key
                    rec[count].r = r
                    rec[count].idx = offset + s + i
                    last = count
                    count += 1
                    continue
                last = j
            # indices only grow within a table: a strict < keeps ties on the lowest
            if r < rec[last].r:
                rec[last].r = r
                rec[last].idx = offset + s + i
    return count, stop


@njit(cache=True, nogil=True, error_model="numpy")
def _merge_slots(slots, rec, count, other, start):
    """Fold the records ``other[start:]`` of another thread's table in (ties to the
    lower index); returns (count, next position) when ``rec`` is full."""
    cap = rec.shape[0]
    for j in range(start, other.shape[0]):
        key = other[j].key
        r = other[j].r
        i = other[j].idx
        s = np.int64(slots[key]) - 1
        if s < 0:
            if count >= cap:
                return count, j
            slots[key] = count + 1
            rec[count].key = key
            rec[count].r = r
            rec[count].idx = i
            count += 1
        elif r < rec[s].r or (r == rec[s].r and i < rec[s].idx):
            rec[s].r = r
            rec[s].idx = i
    return count, other.shape[0]


@njit(cache=True, nogil=True, error_model="numpy")
def _merge_existing(slots, rec, other, new, start, stop):
    """First half of a parallel fold, over ``other[start:stop]``: records whose bin
    this table has are compared in place (ties to the lower index); the others are
    flagged in ``new``. Returns how many were flagged. Shares of one fold touch
    disjoint bins (a table holds a key once): threads run it side by side."""
    n_new = 0
    for j in range(start, stop):
        s = np.int64(slots[other[j].key]) - 1
        if s < 0:
            new[j] = True
            n_new += 1
        else:
            new[j] = False
            r = other[j].r
            i = other[j].idx
            if r < rec[s].r or (r == rec[s].r and i < rec[s].idx):
                rec[s].r = r
                rec[s].idx = i
    return n_new


@njit(cache=True, nogil=True, error_model="numpy")
def _append_new(slots, rec, other, new, start, stop, at):
    """Second half: the flagged records of ``other[start:stop]`` appended at ``rec[at:]``."""
    for j in range(start, stop):
        if new[j]:
            rec[at] = other[j]
            slots[other[j].key] = at + 1
            at += 1
    return at


@njit(cache=True, nogil=True, error_model="numpy")
def mark_losers(slots_a, tab_a, lose_a, tab_b, lose_b, start, stop):
    """Of each bin held by table ``b`` (records ``tab_b[start:stop]``) and by
    table ``a`` (its ``slots_a``), flag the record that loses: the farther,
    or as near with the higher index. Shares of ``tab_b`` meet distinct
    records of ``a``: threads run them side by side."""
    for j in range(start, stop):
        s = np.int64(slots_a[tab_b[j].key]) - 1
        if s >= 0:
            rb = tab_b[j].r
            ra = tab_a[s].r
            if rb < ra or (rb == ra and tab_b[j].idx < tab_a[s].idx):
                lose_a[s] = True
            else:
                lose_b[j] = True


class SlotTable:
    """One thread's bins in a table indexed directly by pulse key.

    ``slots`` (int32 per pulse) holds one more than the position of a bin's ``(key, range,
    index)`` record in this thread's compact record array. Either each thread
    has its own ``slots`` (while they all fit :attr:`BinTables.slot_bytes`):
    threads split the points, key and insert them in one pass, and the tables
    are folded into the first when the result is asked for; or the threads
    share one (each owns the keys ``(key >> 4) % n_threads == part``, i.e.
    whole 64-byte lines of it) and insert the keys they own from key arrays
    computed in parallel. No hashing, no probing, and clearing it for the
    next scan costs O(occupied bins). Used for patterns of up to
    :attr:`BinTables.slot_bytes` / 4 pulses (SYNS's 0.036 deg: 37.5 M).
    """

    __slots__ = ("slots", "rec", "count")

    def __init__(self, slots, capacity: int = INITIAL_CAPACITY):
        self.slots = slots
        self.rec = np.empty(capacity, dtype=RECORD)
        self.count = 0

    def _grow(self) -> None:
        rec = np.empty(2 * len(self.rec), dtype=RECORD)
        rec[: self.count] = self.rec[: self.count]
        self.rec = rec

    def insert(self, keys, ranges, offset, part, n_parts) -> None:
        start = 0
        while True:
            self.count, start = _insert_slots(self.slots, self.rec, self.count, keys, ranges,
                                              offset, part, n_parts, start)
            if start >= len(keys):
                return
            self._grow()

    def reduce(self, points, params, key_range, offset, start, stop) -> None:
        """Key and insert points[start:stop] (a table with its own slots: threads split the points)."""
        while True:
            self.count, start = _reduce_slots(points, *params, *key_range, self.slots, self.rec, self.count,
                                              offset, start, stop)
            if start >= stop:
                return
            self._grow()

    def absorb(self, other: "SlotTable") -> None:
        """Fold another thread's own table in (its records stay: a later absorb
        of the same table changes nothing it has not improved since)."""
        start = 0
        while True:
            self.count, start = _merge_slots(self.slots, self.rec, self.count, other.tab, start)
            if start >= other.count:
                return
            self._grow()

    def absorb_parallel(self, other: "SlotTable", pool, parts: int) -> None:
        """:meth:`absorb` split over ``parts`` threads of ``pool``: the records this
        table has compared in place, then the new ones appended at offsets known
        from the first pass (the same records in the same order as :meth:`absorb`)."""
        tab = other.tab
        n = len(tab)
        cuts = [n * k // parts for k in range(parts + 1)]
        new = np.empty(n, np.bool_)
        counts = list(pool.map(lambda k: _merge_existing(self.slots, self.rec, tab, new, cuts[k], cuts[k + 1]),
                               range(parts)))
        need = self.count + sum(counts)
        while len(self.rec) < need:
            self._grow()
        starts = np.cumsum([self.count] + counts[:-1]).tolist()
        list(pool.map(lambda k: _append_new(self.slots, self.rec, tab, new, cuts[k], cuts[k + 1], starts[k]),
                      range(parts)))
        self.count = need

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
