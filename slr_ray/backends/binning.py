"""The binning backend: keep the closest point in every pulse bin (exact).

This is the reference implementation of the paper's nearest-in-pulse rule
(docs/backends.md, "What a scan returns (the ideal scanner)"). Per occupied
pulse bin ``(v, h)`` the point with the smallest range wins; ties go to the
lowest input index.

The paper sorts all points by ``(h, v, R)``: O(N log N). Here a per-bin
minimum needs no sort: the pulse keys come from the compiled angle kernels of
:mod:`slr_ray.core.grid` (exactly the definition's bins) and go into the
per-pulse tables of :class:`slr_ray.core.BinTables`. A prepared
:class:`BinningScanner` checks its cloud once and reuses the tables of the
previous scan with the same pattern (cleared in O(occupied bins)). Patterns
that do not stream (:attr:`slr_ray.core.Pattern.streamable` false: beam
tables) are reduced by their own :meth:`~slr_ray.core.Pattern.reduce`.
"""

from __future__ import annotations

import threading
import time
import warnings
from dataclasses import dataclass

import numpy as np

from .. import core, threads
from ..arrays import as_origin, file_mapping, refuse_nonfinite_rows, release_pages
from ..core.order import OutputPool
from ..errors import InputValueError
from ..pattern import as_pattern
from ..scan import Scan
from .base import Backend, BackendOptions, Scanner

__all__ = ["BinningOptions", "BinningScanner"]

#: points a scan of a file-mapped cloud bins at a time before releasing their pages (384 MB of float64)
MAPPED_CHUNK = 1 << 24

#: names this module had before the pulse geometry moved to slr_ray.core (deprecated here)
_MOVED = {"pulse_keys": (core.pulse_ids, "slr_ray.core.pulse_ids"),
          "ranges_of": (core.ranges_of, "slr_ray.core.ranges_of"),
          "BinTables": (core.BinTables, "slr_ray.core.BinTables"),
          "default_threads": (threads.default_threads, "slr_ray.threads.default_threads")}


def __getattr__(name):
    if name in _MOVED:
        value, new = _MOVED[name]
        warnings.warn(f"slr_ray.backends.binning.{name} is deprecated; use {new}", DeprecationWarning,
                      stacklevel=2)
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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

    backend = Backend.BINNING
    streamable = True  # a file's chunks reduce to the scan of the whole (slr_ray.streaming)

    def __init__(self, points: np.ndarray, options: BinningOptions | None = None):
        t0 = time.perf_counter()
        options = options or BinningOptions()
        n = len(points)
        if n:
            refuse_nonfinite_rows(core.grid.count_nonfinite(points, 0, n), n)
        super().__init__(points, options, time.perf_counter() - t0)
        # the last scan's tables, reused by the next scan with the same pattern
        # (a scan from another thread meanwhile gets its own)
        self._cache = None
        self._lock = threading.Lock()
        #: output arrays of fine patterns' scans, reused once the scans are dropped
        self._outputs = OutputPool()

    def _tables_for(self, origin, pattern) -> "core.BinTables":
        # a pattern's first scan shares one slot array between the threads (a one-shot
        # scan allocates no more); its second builds tables with one per thread (one
        # pass, no key arrays), which the later scans reuse
        if self._lock.acquire(blocking=False):
            cached, self._cache = self._cache, None
            self._lock.release()
            if cached is not None and cached.pattern == pattern:
                if not cached.could_own_slots:
                    return cached.reset(origin)
                # sized from the first scan's bins: no growing by doubling in the second
                return core.BinTables(origin, pattern, n_threads=self.options.n_threads,
                                      expected_bins=cached.n_bins)
        return core.BinTables(origin, pattern, n_threads=self.options.n_threads, own_slots=False)

    def _release(self, tables: "core.BinTables") -> None:
        if tables.reusable and self._lock.acquire(blocking=False):
            self._cache = tables
            self._lock.release()

    def scan(self, origin, pattern) -> Scan:
        t0 = time.perf_counter()
        origin = as_origin(origin)
        pattern = as_pattern(pattern)
        if not pattern.streamable:  # e.g. a beam table: its own one-shot reduction
            keys, ranges, idx = pattern.reduce(self.points, origin, self.options.n_threads)
            return Scan.from_keys(keys, ranges, idx, origin, pattern, self.backend, len(self.points),
                                  time.perf_counter() - t0)
        tables = self._tables_for(origin, pattern)
        try:
            if not self.release_mapped or file_mapping(self.points) is None:
                tables.add(self.points, finite=True)  # checked when prepared
            else:
                # a file-mapped cloud (a validation's spilled primary) in chunks, each chunk's pages
                # released once binned: the scan holds its tables, not the cloud (same answer: the
                # tables merge chunks as one pass, ties to the lowest index)
                for a in range(0, len(self.points), MAPPED_CHUNK):
                    part = self.points[a:a + MAPPED_CHUNK]
                    tables.add(part, finite=True)
                    release_pages(part)
            pulses, ranges, idx = tables.winners(self.points, as_pulses=True, pool=self._outputs)
        finally:
            self._release(tables)
        return Scan(indices=idx.astype(np.intp, copy=False), ranges=ranges, pulses=pulses, origin=origin,
                    pattern=pattern, backend=self.backend, n_input=len(self.points),
                    seconds=time.perf_counter() - t0)
