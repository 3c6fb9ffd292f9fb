"""The result of a simulated scan (:class:`Scan`), whichever backend made it.

Scans are made by a backend's scanner (:func:`slr_ray.prepare`) or
:func:`slr_ray.simulate_scan`; this module owns only the result type.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .pattern import ScanPattern

__all__ = ["Scan"]


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
    pattern : ScanPattern
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

    def select(self, array):
        """``array[self.indices]``: the scanned points, or any per-point attribute."""
        return np.asarray(array)[self.indices]

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
