"""The result of a simulated scan, and the one function that makes one."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .arrays import as_origin, as_points
from .errors import InputTypeError, InputValueError
from .pattern import ScanPattern

__all__ = ["Scan", "simulate_scan"]


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

    @property
    def pulse_ids(self) -> np.ndarray:
        """``(m,) int64`` flat pulse id ``v * n_azimuth + h``."""
        return self.pulses[:, 0] * self.pattern.n_azimuth + self.pulses[:, 1]

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


def _scan_from_bins(keys, ranges, idx, origin, pattern, backend, n_input, seconds, info=None):
    nh = pattern.n_azimuth
    pulses = np.empty((len(keys), 2), dtype=np.int64)
    np.floor_divide(keys, nh, out=pulses[:, 0])
    np.remainder(keys, nh, out=pulses[:, 1])
    return Scan(
        indices=idx.astype(np.intp, copy=False),
        ranges=ranges,
        pulses=pulses,
        origin=origin,
        pattern=pattern,
        backend=backend,
        n_input=n_input,
        seconds=seconds,
        info=info or {},
    )


def _check_pattern(pattern) -> ScanPattern:
    if isinstance(pattern, ScanPattern):
        return pattern
    if isinstance(pattern, str):
        from .pattern import preset

        return preset(pattern)
    if isinstance(pattern, (int, float)) and not isinstance(pattern, bool):
        return ScanPattern(resolution=pattern)
    raise InputTypeError(
        "pattern must be a ScanPattern, a preset name or a resolution in degrees, "
        f"got {type(pattern).__name__}"
    )


def simulate_scan(points, origin, pattern, backend: str = "binning", **options) -> Scan:
    """Simulate the scan an ideal static scanner at ``origin`` would record.

    Parameters
    ----------
    points : (n, 3) float
        The cloud, float64 or float32 (widened to float64 before the origin is
        subtracted, so float32 input gives exactly what its float64 copy gives).
    origin : (3,) float
        Scanner position, in the same coordinates as ``points``.
    pattern : ScanPattern, str or float
        The scan pattern, a preset name (``"slr"``, ``"syns"``...) or a
        resolution in degrees.
    backend : {'binning', 'embree'}
        ``'binning'`` (default) keeps, per pulse bin, the point with the
        smallest range (ties to the lowest index): the paper's rule, exact,
        and the fastest. ``'embree'`` splats the points as discs and returns
        the point whose disc the ray through each pulse centre meets first
        (see :mod:`slr_ray.backends.embree`); a point hit by several rays
        appears once.
    **options
        Backend options. binning: ``n_threads`` (default: all cores).
        embree: those of :class:`slr_ray.backends.embree.DiscScene`
        (``radius``, ``orientation``, ``segments``, ``engine``...).

    Returns
    -------
    Scan
        Indices into ``points`` (ascending), ranges and pulse bins.

    Raises
    ------
    InputValueError
        bad shape, non-finite rows (with their count), bad origin or options.
    InputTypeError
        complex, object or boolean data.

    Examples
    --------
    >>> import numpy as np, slr_ray
    >>> pts = np.array([[1.0, 0, 0], [2.0, 0, 0], [0, 1.0, 0]])
    >>> scan = slr_ray.simulate_scan(pts, [0, 0, 0], 0.144)
    >>> scan.indices.tolist()     # the point at 2 m hides behind the one at 1 m
    [0, 2]
    """
    from .backends import get_backend

    pattern = _check_pattern(pattern)
    impl = get_backend(backend)
    pts = as_points(points, check_finite=False)  # backends count non-finite rows
    o = as_origin(origin)
    t0 = time.perf_counter()
    scan = impl(pts, o, pattern, **options)
    return replace(scan, seconds=time.perf_counter() - t0)


def _binning(points, origin, pattern, n_threads=None) -> Scan:
    from .backends.binning import BinTables

    tables = BinTables(origin, pattern, n_threads=n_threads)
    bad = tables.add(points)
    if bad:
        raise InputValueError(
            f"points has {bad} row(s) with NaN or inf out of {len(points)}; "
            "remove them first (nothing is dropped silently)"
        )
    keys, ranges, idx = tables.winners(points)
    return _scan_from_bins(keys, ranges, idx, origin, pattern, "binning", len(points), 0.0)
