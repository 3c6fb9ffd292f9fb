"""The pattern protocol: what every scan pattern offers the rest of slr_ray.

A pattern is a grid of pulses, ``rows x columns`` (:attr:`Pattern.shape`):
zenith rows and azimuth columns of a uniform grid
(:class:`~slr_ray.pattern.ScanPattern`), or the beams and firings of a
spinning sensor (:class:`~slr_ray.sensors.BeamPattern`). Backends, mesh scans
and the embree backend's pulse grid talk to a pattern only through this
protocol; what a kind of pattern can do is a capability property
(:attr:`Pattern.streamable`, :attr:`Pattern.has_beams`, as PDAL's
``Pipeline.streamable``), never a test of its class. A new kind of pattern (a
solid-state sensor's grid, a MEMS rosette) implements the abstract members
and states its capabilities.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from ..arrays import unravel_ids
from ..errors import InputValueError

__all__ = ["Pattern"]


class Pattern(ABC):
    """A scanner's pulses: ``rows x columns`` of them, each with a pulse id
    ``row * columns + column``.

    Abstract members: :attr:`shape`, :attr:`range_limits`,
    :attr:`pulse_steps`, :meth:`pulse_ids`, :meth:`rays`, :meth:`reduce`,
    :meth:`aligned`, :meth:`to_dict`, :meth:`with_`.
    """

    # --- capabilities -----------------------------------------------------------------------------------
    @property
    def streamable(self) -> bool:
        """Whether the binning reduction of this pattern runs chunk by chunk
        (:class:`slr_ray.ScanAccumulator`, streamed LAS scans and augments, the
        reusable pulse tables of :class:`slr_ray.core.BinTables`). False: a
        scan reduces the whole cloud at once with :meth:`reduce`."""
        return False

    @property
    def has_beams(self) -> bool:
        """Whether the pulses are fired by a fixed set of beams, so that a
        point can carry the beam that fired it (``pulse_ids(..., beams=...)``,
        ``rows_of_beams``): a real sensor's frame."""
        return False

    # --- the grid ---------------------------------------------------------------------------------------
    @property
    @abstractmethod
    def shape(self) -> tuple[int, int]:
        """``(rows, columns)``: zenith rows (or beams) by azimuth columns."""

    @property
    def n_zenith(self) -> int:
        """Rows."""
        return self.shape[0]

    @property
    def n_azimuth(self) -> int:
        """Columns."""
        return self.shape[1]

    @property
    def n_pulses(self) -> int:
        """Pulses of one scan, ``rows * columns``."""
        return self.n_zenith * self.n_azimuth

    @property
    @abstractmethod
    def range_limits(self) -> tuple[float, float]:
        """``(min_range, max_range)`` in metres, 0 and inf where there is no limit."""

    @property
    @abstractmethod
    def pulse_steps(self) -> tuple[float, float]:
        """Zenith and azimuth step of the pulses, radians (a beam table: its
        mean row gap)."""

    def ravel(self, pulses) -> np.ndarray:
        """Flat pulse ids ``row * columns + column`` (int64) of ``(m, 2)`` pulses ``(row, column)``."""
        p = np.asarray(pulses, dtype=np.int64).reshape(-1, 2)
        return p[:, 0] * self.n_azimuth + p[:, 1]

    def unravel(self, ids) -> np.ndarray:
        """``(m, 2) int64`` pulses ``(row, column)`` of flat pulse ids (the inverse of :meth:`ravel`)."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        if len(ids) and ids.min() < 0:
            raise InputValueError("pulse ids must be >= 0")
        return unravel_ids(ids, self.n_azimuth)

    # --- binning and rays -------------------------------------------------------------------------------
    @abstractmethod
    def pulse_ids(self, points, origin, beams=None):
        """Pulse id (``-1``: not seen; ``-2``: not finite) and range of every point.

        Parameters
        ----------
        points : (n, 3) float
        origin : (3,) float
        beams : (n,) int, optional
            The beam that fired each point (patterns with :attr:`has_beams` only).

        Returns
        -------
        ids : (n,) int64
        ranges : (n,) float64
        """

    @abstractmethod
    def reduce(self, points, origin, n_threads: int | None = None):
        """The nearest-in-pulse rule in one call: per occupied pulse the point
        of smallest range, ties to the lowest index.

        Returns
        -------
        keys, ranges, indices : (m,) arrays
            Of the occupied pulses, indices ascending.
        """

    @abstractmethod
    def rays(self, rows: slice | None = None, k: int = 1):
        """Unit directions of the pulses of ``rows`` (default all), row-major,
        ``k x k`` sub-rays per pulse where the pattern defines them.

        Returns
        -------
        directions : (m, 3) float64
        v, h : (m,) int64
            The pulse of each ray.
        """

    @abstractmethod
    def aligned(self) -> "Pattern":
        """The pattern whose neighbouring pulses are neighbours in space:
        itself, or (a beam table) with per-beam azimuth offsets set to 0
        (the embree backend's pulse grid)."""

    # --- description ------------------------------------------------------------------------------------
    @abstractmethod
    def to_dict(self) -> dict:
        """Plain-JSON description."""

    @abstractmethod
    def with_(self, **changes) -> "Pattern":
        """A copy with some fields changed."""
