"""Winners of the per-pulse tables in index order, without a sort.

A bin's winner is a point index, unique and below the number of points: one
bit per point marks the winners, a running count of the marked bits per
64-bit word gives each winner its place in index order, and a second pass
writes key (or pulse), range and index there. O(m + points / 64) for m
winners, and the writes follow the records' (nearly ascending) order: no
O(m log m) sort of packed keys, no gather of the ranges from the cloud.
:meth:`slr_ray.core.BinTables.winners` uses it for every table kind.
"""

from __future__ import annotations

import sys
import threading

import numpy as np
from numba import njit

__all__ = ["in_index_order", "OutputPool", "mark_records", "place_records", "place_records_pulses", "mark_alive",
           "place_alive", "place_alive_pulses", "mark_dense", "place_dense"]

_ONE = np.uint64(1)
_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)


@njit(cache=True, inline="always", error_model="numpy")
def _popcount(x):
    x = x - ((x >> _ONE) & _M1)
    x = (x & _M2) + ((x >> np.uint64(2)) & _M2)
    x = (x + (x >> np.uint64(4))) & _M4
    return np.int64((x * _H01) >> np.uint64(56))


@njit(cache=True, inline="always", error_model="numpy")
def _mark(bits, i):
    bits[i >> 6] |= _ONE << np.uint64(i & 63)


@njit(cache=True, inline="always", error_model="numpy")
def _place(bits, rank, i):
    """Position of marked index ``i`` among all marked indices, in index order."""
    return rank[i >> 6] + _popcount(bits[i >> 6] & ((_ONE << np.uint64(i & 63)) - _ONE))


@njit(cache=True, nogil=True, error_model="numpy")
def _ranks(bits, rank):
    """rank[w]: marked bits in the words before w."""
    c = np.int64(0)
    for w in range(bits.shape[0]):
        rank[w] = c
        c += _popcount(bits[w])


@njit(cache=True, nogil=True, error_model="numpy")
def mark_records(tab, bits):
    for j in range(tab.shape[0]):
        if tab[j].key != -1:
            _mark(bits, np.int64(tab[j].idx))


@njit(cache=True, inline="always", error_model="numpy")
def _place_record(tab, j, bits, rank, keys, ranges, idx):
    """Record ``j`` at its point's rank: key, range and index."""
    i = np.int64(tab[j].idx)
    p = _place(bits, rank, i)
    keys[p] = tab[j].key
    ranges[p] = tab[j].r
    idx[p] = i


@njit(cache=True, inline="always", error_model="numpy")
def _place_record_pulse(tab, j, bits, rank, n_columns, pulses, ranges, idx):
    """Record ``j`` at its point's rank, its key written as the pulse ``(row, column)``."""
    i = np.int64(tab[j].idx)
    p = _place(bits, rank, i)
    k = np.int64(tab[j].key)
    v = k // n_columns
    pulses[p, 0] = v
    pulses[p, 1] = k - v * n_columns
    ranges[p] = tab[j].r
    idx[p] = i


@njit(cache=True, nogil=True, error_model="numpy")
def place_records(tab, bits, rank, keys, ranges, idx):
    for j in range(tab.shape[0]):
        if tab[j].key != -1:
            _place_record(tab, j, bits, rank, keys, ranges, idx)


@njit(cache=True, nogil=True, error_model="numpy")
def place_records_pulses(tab, bits, rank, n_columns, pulses, ranges, idx):
    """As :func:`place_records`, each key written as its pulse ``(row, column)``."""
    for j in range(tab.shape[0]):
        if tab[j].key != -1:
            _place_record_pulse(tab, j, bits, rank, n_columns, pulses, ranges, idx)


@njit(cache=True, nogil=True, error_model="numpy")
def mark_alive(tab, lose, bits):
    """:func:`mark_records` of the records ``lose`` does not flag (slot tables beaten by another thread's)."""
    for j in range(tab.shape[0]):
        if not lose[j]:
            _mark(bits, np.int64(tab[j].idx))


@njit(cache=True, nogil=True, error_model="numpy")
def place_alive(tab, lose, bits, rank, keys, ranges, idx):
    """:func:`place_records` of the records ``lose`` does not flag."""
    for j in range(tab.shape[0]):
        if not lose[j]:
            _place_record(tab, j, bits, rank, keys, ranges, idx)


@njit(cache=True, nogil=True, error_model="numpy")
def place_alive_pulses(tab, lose, bits, rank, n_columns, pulses, ranges, idx):
    """:func:`place_records_pulses` of the records ``lose`` does not flag."""
    for j in range(tab.shape[0]):
        if not lose[j]:
            _place_record_pulse(tab, j, bits, rank, n_columns, pulses, ranges, idx)


@njit(cache=True, nogil=True, error_model="numpy")
def mark_dense(bidx, bits):
    for k in range(bidx.shape[0]):
        if bidx[k] >= 0:
            _mark(bits, bidx[k])


@njit(cache=True, nogil=True, error_model="numpy")
def place_dense(bidx, branges, bits, rank, keys, ranges, idx):
    for k in range(bidx.shape[0]):
        i = bidx[k]
        if i >= 0:
            p = _place(bits, rank, i)
            keys[p] = k
            ranges[p] = branges[k]
            idx[p] = i


def in_index_order(n_points: int, m: int, mark, place, first_shape=(), alloc=None):
    """``(keys, ranges, indices)`` of ``m`` winners in index order: ``mark(bits)``
    and ``place(bits, rank, keys, ranges, idx)`` visit every source of winners.
    ``first_shape=(2,)``: the first array is ``(m, 2)`` (pulses) instead of keys.
    ``alloc(m)``: the three output arrays (default: new ones)."""
    words = (max(n_points, 1) + 63) >> 6
    bits = np.zeros(words, np.uint64)
    mark(bits)
    rank = np.empty(words, np.int64)
    _ranks(bits, rank)
    if alloc is None:
        keys = np.empty((m,) + tuple(first_shape), np.int64)
        ranges = np.empty(m, np.float64)
        idx = np.empty(m, np.int64)
    else:
        keys, ranges, idx = alloc(m)
    place(bits, rank, keys, ranges, idx)
    return keys, ranges, idx


class OutputPool:
    """Output arrays ``(pulses (m, 2), ranges, indices)`` of a scanner's last
    scans, handed out again once nothing refers to them any more.

    Fresh arrays of tens of MB cost more in page faults than the scan writes
    into them (on a VM that maps pages in slowly: 80 ms for a SYNS scan's
    96 MB of output on 8 M points, against 10 ms of writing). A scan's arrays
    are views of a pooled set; a set is free again when no view of it is left
    (CPython's reference count: a kept :class:`~slr_ray.Scan`, or any array
    taken from it, keeps its set). At most ``sets`` sets are kept (two: a
    scan written out in the background while the next one runs); each is
    sized with 1/8 to spare, so that scans from nearby positions share one.
    """

    def __init__(self, sets: int = 2):
        self.sets = sets
        self._pool = []  # [pulses, ranges, idx, references of a free set]
        self._lock = threading.Lock()

    @staticmethod
    def _refs(entry) -> int:
        return sys.getrefcount(entry[0]) + sys.getrefcount(entry[1]) + sys.getrefcount(entry[2])

    def take(self, m: int):
        with self._lock:
            for entry in self._pool:
                if len(entry[1]) >= m and self._refs(entry) == entry[3]:
                    return entry[0][:m], entry[1][:m], entry[2][:m]  # views: the set is taken
            cap = m + m // 8
            entry = [np.empty((cap, 2), np.int64), np.empty(cap, np.float64), np.empty(cap, np.int64), 0]
            entry[3] = self._refs(entry)
            if len(self._pool) >= self.sets:
                self._pool.pop(0)  # the oldest (if still referenced, its owner keeps it)
            self._pool.append(entry)
            return entry[0][:m], entry[1][:m], entry[2][:m]

    @property
    def nbytes(self) -> int:
        return sum(e[0].nbytes + e[1].nbytes + e[2].nbytes for e in self._pool)
