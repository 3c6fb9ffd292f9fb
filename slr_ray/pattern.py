"""The scan pattern of an ideal static LiDAR scanner.

A pattern is a regular grid of pulses in (zenith, azimuth). Angles are given in
degrees in the public API and converted to radians once here.

Pulse bin of a direction (docs/backends.md, "What a scan returns (the ideal scanner)")::

    v = floor((theta - theta_min) / d_theta)      zenith bin, 0 .. n_zenith - 1
    h = floor(phi / d_phi)                        azimuth bin, 0 .. n_azimuth - 1

``theta`` is the zenith angle in [0, pi] (0 = straight up) and ``phi`` the
azimuth in [0, 2 pi), counter-clockwise from +x. When the field of view is not
a whole number of resolutions the last bin is narrower than the others.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .arrays import refuse_nonfinite_rows
from .core.grid import grid_keys
from .core.protocol import Pattern
from .core.tables import BinTables
from .errors import InputTypeError, InputValueError
from .sensors import SENSORS, sensor

__all__ = ["Pattern", "ScanPattern", "PRESETS", "preset", "as_pattern", "pulse_rays", "pulse_directions"]


#: Most pulses a pattern may have: pulse keys are int64 with negative values
#: reserved, and ``v * n_azimuth + h`` must not overflow (2**62 leaves margin).
MAX_PULSES = 2**62


def _bin_count(extent: float, step: float) -> int:
    """Number of bins of width ``step`` covering ``extent`` (a whole number when
    ``extent / step`` is one up to rounding: 360 / 0.144 is 2500, not 2501)."""
    ratio = extent / step
    if not math.isfinite(ratio) or ratio > MAX_PULSES:
        return MAX_PULSES + 1  # refused by ScanPattern
    nearest = round(ratio)
    if nearest >= 1 and abs(ratio - nearest) <= 1e-9 * max(1.0, ratio):
        return int(nearest)
    return int(math.ceil(ratio))


def _check_number(name: str, value) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputValueError(f"{name} must be a real number, got {value!r}") from None
    if math.isnan(out):
        raise InputValueError(f"{name} must not be NaN")
    return out


@dataclass(frozen=True)
class ScanPattern(Pattern):
    """Angular grid, field of view and range limits of an ideal scanner.

    Parameters
    ----------
    resolution : float, optional
        Sets both ``azimuth_resolution`` and ``zenith_resolution`` (degrees).
    azimuth_resolution, zenith_resolution : float, optional
        Angular size of one pulse in degrees, in (0, 180]. Either overrides
        ``resolution`` for its axis.
    zenith_range : (2,) float
        Zenith field of view ``(min_deg, max_deg)``, 0 = straight up, within
        [0, 180] and ``min < max``. Default the full sphere ``(0, 180)``.
    min_range, max_range : float or None
        Range limits in metres (inclusive). ``None`` means no limit. Points at
        range 0 are never seen, whatever ``min_range`` is.

    Examples
    --------
    >>> ScanPattern(resolution=0.144).n_pulses
    3125000
    >>> ScanPattern(0.036, zenith_range=(0, 135), max_range=120).shape
    (3750, 10000)
    """

    resolution: float | None = None
    azimuth_resolution: float | None = None
    zenith_resolution: float | None = None
    zenith_range: tuple[float, float] = (0.0, 180.0)
    min_range: float | None = None
    max_range: float | None = None
    name: str | None = field(default=None, compare=False)

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        res = None if self.resolution is None else _check_number("resolution", self.resolution)
        az = self.azimuth_resolution if self.azimuth_resolution is not None else res
        ze = self.zenith_resolution if self.zenith_resolution is not None else res
        if az is None or ze is None:
            raise InputValueError(
                "give resolution (degrees, both axes) or both azimuth_resolution "
                f"and zenith_resolution; got resolution={self.resolution!r}, "
                f"azimuth_resolution={self.azimuth_resolution!r}, "
                f"zenith_resolution={self.zenith_resolution!r}"
            )
        for name, value in (("azimuth_resolution", az), ("zenith_resolution", ze)):
            value = _check_number(name, value)
            if not 0.0 < value <= 180.0:
                raise InputValueError(f"{name} must be in (0, 180] degrees, got {value!r}")
            set_(name, value)
        try:
            lo, hi = (float(x) for x in self.zenith_range)
        except (TypeError, ValueError):
            raise InputValueError(
                f"zenith_range must be two numbers (min_deg, max_deg), got {self.zenith_range!r}"
            ) from None
        if not (0.0 <= lo < hi <= 180.0):
            raise InputValueError(
                "zenith_range must satisfy 0 <= min < max <= 180 degrees, "
                f"got {self.zenith_range!r}"
            )
        set_("zenith_range", (lo, hi))
        for name in ("min_range", "max_range"):
            value = getattr(self, name)
            if value is not None:
                value = _check_number(name, value)
                if value < 0:
                    raise InputValueError(f"{name} must be >= 0 metres, got {value!r}")
                set_(name, value)
        if (
            self.min_range is not None
            and self.max_range is not None
            and self.min_range > self.max_range
        ):
            raise InputValueError(
                f"min_range ({self.min_range}) must not exceed max_range ({self.max_range})"
            )
        if self.n_pulses > MAX_PULSES:
            lo, hi = self.zenith_range
            finest = math.sqrt((hi - lo) * 360.0 / MAX_PULSES) * 1.001
            raise InputValueError(
                f"a pattern of azimuth_resolution={self.azimuth_resolution!r}, zenith_resolution="
                f"{self.zenith_resolution!r} over zenith {lo:g}-{hi:g} deg has more pulses than the 63-bit "
                f"pulse keys hold (2**62); the finest resolution for this field of view is {finest:.3g} deg")
        if self.resolution is None and self.azimuth_resolution == self.zenith_resolution:
            set_("resolution", self.azimuth_resolution)
        elif self.resolution is not None and self.azimuth_resolution != self.zenith_resolution:
            set_("resolution", None)

    # --- capabilities (the pattern protocol) -------------------------------
    @property
    def streamable(self) -> bool:
        """A uniform grid reduces chunk by chunk (:class:`slr_ray.ScanAccumulator`)."""
        return True

    # --- derived quantities -------------------------------------------------
    @property
    def n_azimuth(self) -> int:
        """Number of azimuth bins (the last may be narrower)."""
        return _bin_count(360.0, self.azimuth_resolution)

    @property
    def n_zenith(self) -> int:
        """Number of zenith bins over the field of view (the last may be narrower)."""
        lo, hi = self.zenith_range
        return _bin_count(hi - lo, self.zenith_resolution)

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_zenith, n_azimuth)``."""
        return self.n_zenith, self.n_azimuth

    @property
    def radians(self) -> tuple[float, float, float, float]:
        """``(d_theta, d_phi, theta_min, theta_max)`` in radians."""
        lo, hi = self.zenith_range
        return (
            math.radians(self.zenith_resolution),
            math.radians(self.azimuth_resolution),
            math.radians(lo),
            math.radians(hi),
        )

    @property
    def range_limits(self) -> tuple[float, float]:
        """``(min_range, max_range)`` with ``None`` replaced by 0 and inf."""
        return (
            0.0 if self.min_range is None else self.min_range,
            math.inf if self.max_range is None else self.max_range,
        )

    @property
    def pulse_steps(self) -> tuple[float, float]:
        """``(d_theta, 2 pi / n_azimuth)``, radians."""
        return self.radians[0], 2 * math.pi / self.n_azimuth

    def pulse_ids(self, points, origin, beams=None):
        """Pulse id ``v * n_azimuth + h`` and range of every point (:mod:`slr_ray.core.grid`).

        -1: not seen; -2: not finite. ``beams`` is for beam tables only."""
        if beams is not None:
            raise InputValueError("beams (a point's beam id) need a beam-table pattern, not a uniform grid")
        return grid_keys(points, origin, self)

    def reduce(self, points, origin, n_threads: int | None = None):
        """Nearest point per pulse, ties to the lowest index: ``(keys, ranges,
        indices)`` of the occupied pulses, indices ascending."""
        tables = BinTables(origin, self, n_threads=n_threads)
        bad = tables.add(points)
        refuse_nonfinite_rows(bad, len(points))
        return tables.winners(points)

    def rays(self, rows: slice | None = None, k: int = 1):
        """Rays of the pulses of zenith rows ``rows``, ``k x k`` sub-rays per pulse
        (:func:`pulse_rays`)."""
        rows = slice(0, self.n_zenith) if rows is None else rows
        d_theta, d_phi, th0, th1 = self.radians
        nh = self.n_azimuth
        v = np.arange(rows.start, rows.stop, dtype=np.int64)
        theta = _sub_angles(th0, d_theta, th1, v, k)
        phi = _sub_angles(0.0, d_phi, 2 * math.pi, np.arange(nh, dtype=np.int64), k)
        st, ct = np.sin(theta), np.cos(theta)
        dirs = np.empty((len(theta), len(phi), 3))
        dirs[..., 0] = st[:, None] * np.cos(phi)[None, :]
        dirs[..., 1] = st[:, None] * np.sin(phi)[None, :]
        dirs[..., 2] = ct[:, None]
        vv = np.broadcast_to(np.repeat(v, k)[:, None], (len(theta), len(phi)))
        hh = np.broadcast_to(np.repeat(np.arange(nh, dtype=np.int64), k)[None, :], (len(theta), len(phi)))
        return dirs.reshape(-1, 3), vv.ravel(), hh.ravel()

    def aligned(self) -> "ScanPattern":
        """Itself: a uniform grid's neighbouring pulses are neighbours in space."""
        return self

    def with_(self, **changes) -> "ScanPattern":
        """A copy with some fields changed (``pattern.with_(max_range=50)``)."""
        values = {
            "azimuth_resolution": self.azimuth_resolution,
            "zenith_resolution": self.zenith_resolution,
            "zenith_range": self.zenith_range,
            "min_range": self.min_range,
            "max_range": self.max_range,
            "name": None,
        }
        if "resolution" in changes:
            values["azimuth_resolution"] = values["zenith_resolution"] = None
        values.update(changes)
        return ScanPattern(**values)

    def to_dict(self) -> dict:
        """Plain-JSON description (degrees and metres)."""
        return {
            "azimuth_resolution": self.azimuth_resolution,
            "zenith_resolution": self.zenith_resolution,
            "zenith_range": list(self.zenith_range),
            "min_range": self.min_range,
            "max_range": self.max_range,
            "shape": list(self.shape),
            **({"name": self.name} if self.name else {}),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "ScanPattern":
        keys = ("resolution", "azimuth_resolution", "zenith_resolution", "zenith_range",
                "min_range", "max_range", "name")
        return cls(**{k: (tuple(v) if k == "zenith_range" else v) for k, v in d.items() if k in keys})


#: The paper's patterns, by name.
PRESETS: dict[str, ScanPattern] = {
    "slr": ScanPattern(0.144, name="slr"),
    "syns": ScanPattern(0.036, zenith_range=(0.0, 135.0), max_range=120.0, name="syns"),
    "primary": ScanPattern(0.0144, name="primary"),
    "primary-fine": ScanPattern(0.00576, name="primary-fine"),
}


def preset(name: str) -> ScanPattern:
    """The named pattern of the paper.

    ``"slr"``: 0.144 deg, full sphere (the secondary and SLR scans).
    ``"syns"``: 0.036 deg, zenith 0-135 deg, 120 m (the SYNS scanner).
    ``"primary"``: 0.0144 deg (validation primaries, questions 1 and 2).
    ``"primary-fine"``: 0.00576 deg (validation primary, question 3).
    """
    try:
        return PRESETS[name]
    except KeyError:
        raise InputValueError(
            f"unknown pattern preset {name!r}; choose one of {sorted(PRESETS)}"
        ) from None


def as_pattern(pattern) -> Pattern:
    """A pattern from a pattern, a preset or sensor name, or a resolution in degrees.

    A :class:`~slr_ray.core.Pattern` (a :class:`ScanPattern`, a
    :class:`~slr_ray.sensors.BeamPattern`) is returned as it is; a string
    names a preset (:data:`PRESETS`), a shipped sensor
    (:data:`slr_ray.sensors.SENSORS`) or a sensor card (a ``.json`` path).

    Raises
    ------
    InputTypeError
        for anything else.
    InputValueError
        for an unknown preset or an impossible resolution.
    """
    if isinstance(pattern, Pattern):
        return pattern
    if isinstance(pattern, str):
        if pattern in PRESETS:
            return preset(pattern)
        if pattern in SENSORS or pattern.lower().endswith(".json"):  # a shipped sensor or a sensor card
            return sensor(pattern)
        raise InputValueError(f"unknown pattern {pattern!r}: presets {sorted(PRESETS)}, sensors {list(SENSORS)}")
    if isinstance(pattern, (int, float, np.integer, np.floating)) and not isinstance(pattern, (bool, np.bool_)):
        return ScanPattern(resolution=float(pattern))
    raise InputTypeError(
        "pattern must be a ScanPattern, a preset name or a resolution in degrees, "
        f"got {type(pattern).__name__}"
    )


def _sub_angles(start, step, stop, bins, k):
    """Angles of k sub-rays in each bin of ``bins``: ``(len(bins) * k,)``.

    One rule for every caller: a bin spans ``[start + b * step, min(start + (b + 1)
    * step, stop)]`` (the last bin may be narrower), and sub-ray ``j`` sits at
    ``(j + 1/2) / k`` of the bin's own width: k = 1 is the bin's centre.
    """
    lo = start + bins * step
    width = np.minimum(step, stop - lo)
    frac = (np.arange(k) + 0.5) / k
    return (lo[:, None] + frac[None, :] * width[:, None]).ravel()


def pulse_directions(pulses, pattern: ScanPattern) -> np.ndarray:
    """Unit vectors through the centres of pulses ``(v, h)``.

    Parameters
    ----------
    pulses : (m, 2) int
        Zenith and azimuth bins.
    pattern : ScanPattern

    Returns
    -------
    directions : (m, 3) float64
        Through the middle of each bin; a narrower last bin (a field of view
        that is not a whole number of resolutions) has its own middle.
    """
    pulses = np.asarray(pulses, dtype=np.int64).reshape(-1, 2)
    d_theta, d_phi, th0, th1 = pattern.radians
    theta = _sub_angles(th0, d_theta, th1, pulses[:, 0], 1)
    phi = _sub_angles(0.0, d_phi, 2 * math.pi, pulses[:, 1], 1)
    s = np.sin(theta)
    return np.column_stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)])


def pulse_rays(pattern: Pattern, rows: slice | None = None, k: int = 1):
    """Rays of the pulses of zenith rows ``rows``, ``k x k`` sub-rays per pulse.

    Parameters
    ----------
    pattern : Pattern
        A uniform grid, or a beam table (one ray per (beam, column): ``k = 1`` only).
    rows : slice, optional
        Zenith rows (default all); bounds memory when cast in batches.
    k : int
        Sub-rays per axis, at ``(j + 1/2) / k`` of the pulse's width
        (:func:`pulse_directions`' rule); ``k = 1`` is the pulse centre.

    Returns
    -------
    directions : (m, 3) float64
        Unit vectors, row-major over (zenith sub-row, azimuth sub-column).
    v, h : (m,) int64
        The pulse of each ray.
    """
    return pattern.rays(rows, k)
