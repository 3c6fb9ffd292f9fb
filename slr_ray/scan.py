"""The result of a simulated scan (:class:`Scan`), whichever backend made it.

Scans are made by a backend's scanner (:func:`slr_ray.prepare`) or
:func:`slr_ray.simulate_scan`; this module owns only the result type.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import InputValueError
from .pattern import ScanPattern

__all__ = ["Scan", "check_range_image"]


@dataclass(frozen=True, eq=False)
class Scan:
    """Points of a cloud that a simulated scanner returns.

    Attributes
    ----------
    indices : (m,) intp
        Indices into the scanned cloud, ascending: ``points[scan.indices]``,
        and every attribute or label array indexed the same way, is the
        simulated scan.
    ranges : (m,) float64
        Distance of each returned point from the origin.
    pulses : (m, 2) int64
        Pulse bin ``(v, h)`` (zenith, azimuth) of each returned point. Each
        pulse appears at most once.
    origin : (3,) float64
        Scanner position.
    pattern : ScanPattern or BeamPattern
    backend : str
        Backend that produced the scan.
    n_input : int
        Number of points scanned.
    seconds : float
        Wall time of the scan.
    """

    indices: np.ndarray
    ranges: np.ndarray
    pulses: np.ndarray
    origin: np.ndarray
    pattern: ScanPattern
    backend: str = "binning"
    n_input: int = 0
    seconds: float = 0.0
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.indices)

    @classmethod
    def from_keys(cls, keys, ranges, indices, origin, pattern: ScanPattern, backend: str, n_input: int,
                  seconds: float = 0.0, info: dict | None = None) -> "Scan":
        """A scan from flat pulse ids ``keys`` (``v * n_azimuth + h``), as the
        binning reduction produces them; ``indices`` ascending."""
        return cls(indices=np.asarray(indices).astype(np.intp, copy=False), ranges=ranges,
                   pulses=pattern.unravel(keys), origin=origin, pattern=pattern, backend=backend,
                   n_input=int(n_input), seconds=seconds, info=info or {})

    @property
    def pulse_ids(self) -> np.ndarray:
        """``(m,) int64`` flat pulse id ``v * n_azimuth + h``."""
        return self.pattern.ravel(self.pulses)

    @property
    def rings(self) -> np.ndarray:
        """``(m,) int64``: the beam (ring) of each point: its beam id in the sensor's
        table for a :class:`~slr_ray.sensors.BeamPattern`, the zenith row otherwise."""
        rows = self.pulses[:, 0]
        order = getattr(self.pattern, "beam_of_row", None)
        return rows.copy() if order is None else order[rows]

    @property
    def columns(self) -> np.ndarray:
        """``(m,) int64``: the azimuth column of each point."""
        return self.pulses[:, 1].copy()

    def range_image(self, attributes: dict | None = None, max_pixels: int = 2**28) -> dict:
        """The scan as images of the pattern's shape (rows by elevation, highest first; columns by azimuth).

        Parameters
        ----------
        attributes : dict of str -> (n,) array, optional
            Per-point arrays of the *scanned cloud* (indexed like its points),
            drawn into images too.
        max_pixels : int
            Refuse patterns with more pulses (a 0.001 deg pattern has 6.5e10).

        Returns
        -------
        dict
            ``range`` (rows, cols) float32, NaN where no point; ``index``
            (rows, cols) int64 into the scanned cloud, -1 where empty;
            ``ring`` (rows,) int64, the beam id of each row; one image per
            attribute (NaN, or -1 for integers, where empty).
        """
        check_range_image(self.pattern, max_pixels)
        nv, nh = self.pattern.shape
        r, c = self.pulses[:, 0], self.pulses[:, 1]
        out = {"range": np.full((nv, nh), np.nan, np.float32), "index": np.full((nv, nh), -1, np.int64)}
        out["range"][r, c] = self.ranges
        out["index"][r, c] = self.indices
        order = getattr(self.pattern, "beam_of_row", None)
        out["ring"] = np.arange(nv, dtype=np.int64) if order is None else np.asarray(order, np.int64)
        for name, values in (attributes or {}).items():
            v = np.asarray(values)[self.indices]
            if name in out:
                raise InputValueError(f"attribute name {name!r} is taken by the range image")
            img = np.full((nv, nh) + v.shape[1:], np.nan if v.dtype.kind == "f" else -1,
                          dtype=v.dtype if v.dtype.kind in "fi" else np.int64)
            img[r, c] = v
            out[name] = img
        return out

    def summary(self) -> dict:
        """Plain-JSON summary (counts, pattern, timing)."""
        return {
            "backend": self.backend,
            "origin": self.origin.tolist(),
            "pattern": self.pattern.to_dict(),
            "points_in": int(self.n_input),
            "points_out": int(len(self)),
            "pulses": int(self.pattern.n_pulses),
            "seconds": round(float(self.seconds), 6),
            **self.info,
        }


def check_range_image(pattern, max_pixels: int = 2**28) -> None:
    """Refuse a range image of ``pattern`` with more than ``max_pixels`` pulses
    (:class:`~slr_ray.errors.InputValueError`): callers check before the scan."""
    nv, nh = pattern.shape
    if nv * nh > max_pixels:
        raise InputValueError(f"a range image of {nv:,} x {nh:,} pulses is larger than max_pixels={max_pixels:,} "
                              "(a coarser pattern, or no --range-image / --png)")
