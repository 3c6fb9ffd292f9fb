"""The shipped backends' names, :class:`Backend`: a module of its own, so that what
names a scan (:class:`~slr_ray.accumulator.ScanAccumulator`'s) needs nothing else of
the backends (:mod:`slr_ray.backends.base` re-exports it)."""

from __future__ import annotations

from enum import Enum

__all__ = ["Backend"]


class Backend(str, Enum):
    """Names of the subsampling backends: a scanner's identity (:attr:`Scanner.backend`)."""

    BINNING = "binning"
    EMBREE = "embree"

    def __str__(self) -> str:  # "binning" in f-strings and file names, as enum.StrEnum (Python 3.11+)
        return self.value
