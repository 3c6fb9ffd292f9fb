"""Beam tables of spinning multi-beam sensors: :class:`BeamPattern` and the shipped sensors.

A spinning LiDAR (Velodyne, Ouster, ...) fires a fixed set of beams, each at
its own elevation (unevenly spaced) and its own azimuth offset, once per
column of a revolution. :class:`BeamPattern` describes that pattern and is
accepted wherever a :class:`~slr_ray.pattern.ScanPattern` is: by both
backends and by :func:`~slr_ray.meshscan.scan_mesh` (pulse centres).

Binning (exact, documented definition)
--------------------------------------
Of a point less the scanner origin, in float64: ``r = sqrt(x² + y² + z²)``,
``c = z / r`` (the cosine of its zenith) and ``azimuth = atan2(y, x)``
(counter-clockwise from +x, in [0, 2π)). Beams are ordered by elevation,
highest first (that order is the *row* of the range image). A point belongs
to the beam whose **elevation band** holds it: its zenith lies in ``[e_i,
e_{i+1})``, tested as ``cos(e_{i+1}) < c <= cos(e_i)`` with the edges'
cosines computed once in float64; band edges lie halfway between neighbouring beams;
the outermost bands reach half a gap beyond the outermost beams (the gap to
their one neighbour). Its **column** is ``floor(((azimuth - offset) mod 360) /
(360 / columns))`` with that beam's azimuth offset. Points outside every band,
or outside ``[min_range, max_range]``, are not seen. The binning backend keeps
the nearest point per (beam, column), ties to the lowest index; the embree
backend and ``scan_mesh`` cast one ray per (beam, column) in the beam's true
direction: zenith ``90 - elevation``, azimuth ``offset + (column + 0.5) *
360 / columns`` (the centre of its bin, so a sensor's own frame re-scanned
from its origin returns every point).

Azimuth offsets are applied as the calibration gives them; slr_ray's azimuth
is counter-clockwise from +x, so column 0 and the sense of the columns may
differ from a vendor's by a fixed rotation or mirror (the same for every
beam: the pattern of bins is the sensor's). Per-beam origin offsets
(Velodyne's vertical and horizontal offsets, Ouster's beam-origin distance)
are kept in :attr:`BeamPattern.meta` for reference; beams are cast from the
one scanner origin (the offsets are a few centimetres).

Shipped sensors (:func:`sensor`, :data:`SENSORS`): Velodyne VLP-16, VLP-32C,
HDL-32E, HDL-64E S2 and S3 (one unit's calibration each), VLS-128 (from the
BSD-licensed ros-drivers/velodyne calibration files) and Ouster OS1-64 and
OS1-128 (from ouster-sdk's BSD-licensed test metadata); each file records its
source. Your own calibration: :func:`read_ouster_metadata`,
:func:`read_velodyne_calibration`.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .arrays import as_origin, as_points
from .core.beams import beam_keys, beam_keys_given, beam_reduce, beam_reduce_posed, beam_reduce_serial
from .core.protocol import Pattern
from .errors import FormatError, InputValueError, SlrError, SlrWarning
from .threads import default_threads

__all__ = ["BeamPattern", "sensor", "SENSORS", "SENSORS_DIR", "read_ouster_metadata", "read_sensor_file",
           "read_sensor_table", "read_velodyne_calibration", "read_card", "write_card", "card_dict", "is_sensor_name",
           "beams_outside", "source_elevation_range", "conversion_reach", "miscalibrated", "sensor_noise",
           "scan_order_beams", "fitted_pattern"]

#: Directory of the shipped beam tables (package data).
SENSORS_DIR = Path(__file__).resolve().parent / "data" / "sensors"


def _names() -> tuple:
    return tuple(sorted(p.stem for p in SENSORS_DIR.glob("*.json")))


#: Names of the shipped sensors.
SENSORS = _names()


@dataclass(frozen=True, eq=False)
class BeamPattern(Pattern):
    """The beam table of a spinning multi-beam sensor (module docstring).

    Parameters
    ----------
    elevation_deg : sequence of float
        Elevation of each beam above the horizontal, degrees, in the table's
        order (the beam id is the position in it). Any order; distinct values.
    columns : int
        Columns (firings) per revolution: the azimuth resolution is ``360 / columns``.
    azimuth_offset_deg : sequence of float, optional
        Each beam's azimuth offset, degrees (default 0).
    min_range, max_range : float, optional
        Metres.
    name : str, optional
    meta : dict
        Anything else of the table (source, offsets); not used by the scan.
    """

    elevation_deg: tuple
    columns: int
    azimuth_offset_deg: tuple | None = None
    min_range: float | None = None
    max_range: float | None = None
    name: str | None = None
    meta: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        el = np.asarray(self.elevation_deg, dtype=np.float64).ravel()
        if len(el) < 1 or not np.all(np.isfinite(el)) or np.any(np.abs(el) >= 90):
            raise InputValueError("elevation_deg must be one or more finite angles in (-90, 90) degrees")
        if len(np.unique(el)) != len(el):
            raise InputValueError("elevation_deg has repeated values: beams must have distinct elevations")
        off = np.zeros(len(el)) if self.azimuth_offset_deg is None else \
            np.asarray(self.azimuth_offset_deg, dtype=np.float64).ravel()
        if off.shape != el.shape or not np.all(np.isfinite(off)):
            raise InputValueError(f"azimuth_offset_deg must be {len(el)} finite angles, got {off.shape}")
        if int(self.columns) != self.columns or not 1 <= self.columns <= 2**24:
            raise InputValueError(f"columns must be an integer in [1, 2**24], got {self.columns!r}")
        for k in ("min_range", "max_range"):
            v = getattr(self, k)
            if v is not None and not (math.isfinite(float(v)) and float(v) >= 0):
                raise InputValueError(f"{k} must be a finite number >= 0, got {v!r}")
        if self.min_range is not None and self.max_range is not None and self.min_range > self.max_range:
            raise InputValueError(f"min_range ({self.min_range}) must not exceed max_range ({self.max_range})")
        set_("elevation_deg", tuple(el.tolist()))
        set_("azimuth_offset_deg", tuple(off.tolist()))
        set_("columns", int(self.columns))

    # --- the rows: beams by elevation, highest first -------------------------------------------------------
    @property
    def n_beams(self) -> int:
        return len(self.elevation_deg)

    @property
    def beam_of_row(self) -> np.ndarray:
        """``(n_beams,) int64``: the beam id (table position) of each range-image row."""
        return np.argsort(-np.asarray(self.elevation_deg), kind="stable").astype(np.int64)

    @property
    def row_zenith(self) -> np.ndarray:
        """Zenith of each row's beam, radians, ascending."""
        return np.radians(90.0 - np.asarray(self.elevation_deg)[self.beam_of_row])

    @property
    def band_edges(self) -> np.ndarray:
        """``(n_beams + 1,)`` zenith edges of the rows' bands, radians, ascending."""
        z = self.row_zenith
        if len(z) == 1:  # one beam: a band of 1 degree around it (no neighbour to take a gap from)
            return np.array([z[0] - math.radians(0.5), z[0] + math.radians(0.5)])
        mid = 0.5 * (z[1:] + z[:-1])
        return np.concatenate([[z[0] - 0.5 * (z[1] - z[0])], mid, [z[-1] + 0.5 * (z[-1] - z[-2])]])

    @property
    def row_offsets(self) -> np.ndarray:
        """Azimuth offset of each row's beam, radians."""
        return np.radians(np.asarray(self.azimuth_offset_deg)[self.beam_of_row])

    # --- the pattern protocol (slr_ray.core.Pattern) -----------------------------------------------------
    @property
    def has_beams(self) -> bool:
        """A point may carry the beam that fired it (:meth:`pulse_ids`, :meth:`rows_of_beams`)."""
        return True

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_beams, columns)``: rows by elevation, columns by azimuth."""
        return self.n_beams, self.columns

    @property
    def azimuth_resolution(self) -> float:
        return 360.0 / self.columns

    @property
    def range_limits(self) -> tuple[float, float]:
        return (0.0 if self.min_range is None else float(self.min_range),
                math.inf if self.max_range is None else float(self.max_range))

    @property
    def pulse_steps(self) -> tuple[float, float]:
        """The mean row gap (the bands' zenith extent over the rows) and ``2 pi / columns``, radians."""
        edges = self.band_edges
        return float(edges[-1] - edges[0]) / self.n_beams, 2 * math.pi / self.columns

    def aligned(self) -> "BeamPattern":
        """The table with every beam's azimuth offset 0: column ``h`` of two
        adjacent beams then lies at the same absolute azimuth (the offsets put
        it up to 8 deg apart between an HDL-64E's beams)."""
        if not any(self.azimuth_offset_deg):
            return self
        return dataclasses.replace(self, azimuth_offset_deg=(0.0,) * self.n_beams)

    def to_dict(self) -> dict:
        return {"name": self.name, "beams": self.n_beams, "columns": self.columns,
                "azimuth_resolution": self.azimuth_resolution,
                "elevation_range_deg": [min(self.elevation_deg), max(self.elevation_deg)],
                "min_range": self.min_range, "max_range": self.max_range,
                "source": self.meta.get("source")}

    def with_(self, **changes) -> "BeamPattern":
        return dataclasses.replace(self, **changes)

    def keys(self, points, origin, beams=None):
        """Deprecated name of :meth:`pulse_ids`."""
        warnings.warn("BeamPattern.keys is deprecated; use BeamPattern.pulse_ids", DeprecationWarning, stacklevel=2)
        return self.pulse_ids(points, origin, beams)

    def pulse_ids(self, points, origin, beams=None):
        """Flat pulse ids ``row * columns + column`` (``-1``: not seen) and ranges of ``points``.

        ``beams`` (optional, ``(n,)`` integers): the beam (table position) that
        fired each point, as a frame's ``ring`` field records it; -1 where
        unknown. A point with a beam takes that beam's row whatever its
        elevation (a real unit's beams depart from the table, and a beam's
        vertical offset moves near points' elevation by degrees); the others
        take the row of the band their elevation falls in.
        """
        pts = np.ascontiguousarray(points, dtype=np.float64)
        o = np.asarray(origin, dtype=np.float64)
        keys = np.empty(len(pts), np.int64)
        ranges = np.empty(len(pts))
        rmin, rmax = self.range_limits
        if beams is None:
            beam_keys(pts, o[0], o[1], o[2], self._cos_edges, self.row_offsets, self.columns, rmin, rmax, keys,
                       ranges)
        else:
            rows = self.rows_of_beams(beams, len(pts))
            beam_keys_given(pts, o[0], o[1], o[2], self._cos_edges, self.row_offsets, self.columns, rmin, rmax,
                             rows, keys, ranges)
        return keys, ranges

    def rows_of_beams(self, beams, n: int | None = None) -> np.ndarray:
        """``(n,) int64``: the range-image row of each point's beam (-1 stays -1).

        Raises :class:`InputValueError` for a length other than ``n``,
        non-integers, or beams outside ``[-1, n_beams)``."""
        b = np.asarray(beams)
        if b.ndim != 1 or (n is not None and len(b) != n):
            raise InputValueError(f"beams must be one integer a point ({n} values), got shape {b.shape}")
        if b.dtype.kind not in "iu":
            if b.dtype.kind != "f" or not np.all(np.isfinite(b)) or np.any(b != np.round(b)):
                raise InputValueError(f"beams must be integers (beam ids, -1 unknown), got dtype {b.dtype}")
        b = b.astype(np.int64)
        if len(b) and (b.min() < -1 or b.max() >= self.n_beams):
            raise InputValueError(f"beams must lie in [-1, {self.n_beams}) for a {self.n_beams}-beam table, "
                                  f"got {b.min()} ... {b.max()}")
        row_of_beam = np.empty(self.n_beams, np.int64)
        row_of_beam[self.beam_of_row] = np.arange(self.n_beams)
        return np.where(b >= 0, row_of_beam[np.maximum(b, 0)], -1)

    @property
    def _cos_edges(self) -> np.ndarray:
        """Cosines of the band edges, negated so that they ascend (for a binary search)."""
        return -np.cos(self.band_edges)

    def rays(self, rows: slice | None = None, k: int = 1):
        """Unit directions of the pulses of ``rows`` (row-major), with their ``(row, column)``.

        Only pulse centres (``k = 1``): a beam is a direction, not a solid angle."""
        if k != 1:
            raise InputValueError("beam patterns cast one ray per pulse (mode 'center'); "
                                  "sub-rays (mode 'nearest') are defined for uniform patterns only")
        r = np.arange(self.n_beams, dtype=np.int64)[slice(None) if rows is None else rows]
        c = np.arange(self.columns, dtype=np.int64)
        v = np.repeat(r, self.columns)
        h = np.tile(c, len(r))
        zen = self.row_zenith[v]
        az = self.row_offsets[v] + (h + 0.5) * (2 * math.pi / self.columns)
        s = np.sin(zen)
        dirs = np.column_stack([s * np.cos(az), s * np.sin(az), np.cos(zen)])
        return dirs, v, h

    def reduce(self, points, origin, n_threads: int | None = None):
        """The binning reduction: nearest point per (beam, column), ties to the lowest index.

        Returns ``(keys, ranges, indices)`` of the occupied pulses, indices ascending.
        float32 points are widened point by point in the kernel (no float64 copy)."""
        pts = np.ascontiguousarray(points)
        if pts.dtype not in (np.float32, np.float64):
            pts = pts.astype(np.float64)
        o = np.asarray(origin, dtype=np.float64)
        t = max(1, min(n_threads or default_threads(), max(1, len(pts) // 100_000)))
        best_r = np.full((t, self.n_pulses), np.inf)
        best_i = np.full((t, self.n_pulses), -1, np.int64)
        rmin, rmax = self.range_limits
        if t == 1:  # no parallel region for one thread's share (beam_reduce_serial: its cost)
            beam_reduce_serial(pts, o[0], o[1], o[2], self._cos_edges, self.row_offsets, self.columns, rmin, rmax,
                               best_r[0], best_i[0])
        else:
            beam_reduce(pts, o[0], o[1], o[2], self._cos_edges, self.row_offsets, self.columns, rmin, rmax,
                        best_r, best_i)
        r, i = best_r[0], best_i[0]
        for j in range(1, t):
            better = (best_r[j] < r) | ((best_r[j] == r) & (best_i[j] >= 0) & ((i < 0) | (best_i[j] < i)))
            r = np.where(better, best_r[j], r)
            i = np.where(better, best_i[j], i)
        keys = np.flatnonzero(i >= 0)
        idx, ranges = i[keys], r[keys]
        order = np.argsort(idx, kind="stable")
        return keys[order], ranges[order], idx[order]

    def reduce_posed(self, points, pose):
        """:meth:`reduce` of world points ``points`` ((n, 3) float64) seen by the sensor at ``pose``
        (4 x 4, the sensor's axes and origin in the world): the same returns as
        ``reduce(slr_ray.effects.motion.to_frame(points, pose), zeros(3))``, one thread, each point
        moved in the kernel (no moved copy). Returns ``(keys, ranges, indices)``, indices ascending."""
        pts = np.ascontiguousarray(points, dtype=np.float64)
        T = np.asarray(pose, dtype=np.float64)
        rot = np.ascontiguousarray(T[:3, :3].T)
        best_r = np.full(self.n_pulses, np.inf)
        best_i = np.full(self.n_pulses, -1, np.int64)
        rmin, rmax = self.range_limits
        beam_reduce_posed(pts, rot, T[0, 3], T[1, 3], T[2, 3], self._cos_edges, self.row_offsets, self.columns,
                          rmin, rmax, best_r, best_i)
        keys = np.flatnonzero(best_i >= 0)
        idx, ranges = best_i[keys], best_r[keys]
        order = np.argsort(idx, kind="stable")
        return keys[order], ranges[order], idx[order]

    @classmethod
    def from_table(cls, table: dict, **changes) -> "BeamPattern":
        """From a beam-table dict (the shipped JSON layout: ``elevation_deg``,
        ``azimuth_offset_deg``, ``columns``, ``max_range_m_nominal``, ...)."""
        meta = {k: v for k, v in table.items()
                if k not in ("elevation_deg", "azimuth_offset_deg", "columns", "min_range_m", "max_range_m")}
        kw = {"elevation_deg": table["elevation_deg"], "azimuth_offset_deg": table.get("azimuth_offset_deg"),
              "columns": table.get("columns", 1024),
              "max_range": table.get("max_range_m", table.get("max_range_m_nominal")),
              "min_range": table.get("min_range_m"), "name": table.get("name"), "meta": meta}
        return cls(**(kw | changes))


def sensor(name: str, **changes) -> BeamPattern:
    """A shipped sensor's :class:`BeamPattern` by name (:data:`SENSORS`), or a
    sensor card's by its path (a ``.json`` file: :func:`read_card`).

    Keywords override fields (``columns=1024``, ``max_range=80``).

    >>> slr_ray.sensor("velodyne_vlp16").shape  # doctest: +SKIP
    (16, 1800)
    """
    if isinstance(name, Path):
        name = str(name)
    if not isinstance(name, str):
        raise InputValueError(f"a sensor is named by a string, got {name!r}; shipped: {list(SENSORS)}")
    if name not in SENSORS and name.lower().endswith(".json"):
        return read_card(name, **changes)
    return BeamPattern.from_table(copy.deepcopy(_shipped_table(name)), **changes)


@functools.cache
def _shipped_table(name: str) -> dict:
    """A shipped table, read once per process (options naming a sensor resolve it often)."""
    path = SENSORS_DIR / f"{name}.json"
    if not path.is_file():
        raise InputValueError(f"unknown sensor {name!r}; shipped: {list(SENSORS)}")
    return json.loads(path.read_text())


#: what a sensor card's ``card`` key says (:func:`write_card`)
CARD = "slr_ray sensor card"
#: the keys of a card that are the pattern's fields (the others are its ``meta``)
_CARD_FIELDS = ("name", "elevation_deg", "azimuth_offset_deg", "columns", "min_range_m", "max_range_m")


def is_sensor_name(name) -> bool:
    """Whether ``name`` names a shipped sensor or a ``.json`` file (a card, read when used)."""
    return isinstance(name, (str, Path)) and (str(name) in SENSORS or str(name).lower().endswith(".json"))


def card_dict(pattern: BeamPattern) -> dict:
    """A :class:`BeamPattern` as a sensor card (plain JSON-ready dict): the pattern's fields and its ``meta``
    (source, per-beam heights, drop rates, the fit's quality, where a fit gave them)."""
    if not isinstance(pattern, BeamPattern):
        raise InputValueError(f"a card is written from a BeamPattern, got {type(pattern).__name__}")
    d = {"card": CARD, "version": 1, **{k: v for k, v in pattern.meta.items() if k not in ("card", "version")}}
    d.update({"name": pattern.name, "beams": pattern.n_beams, "columns": pattern.columns,
              "min_range_m": pattern.min_range, "max_range_m": pattern.max_range,
              "elevation_deg": list(pattern.elevation_deg), "azimuth_offset_deg": list(pattern.azimuth_offset_deg)})
    return d


def write_card(path, pattern: BeamPattern) -> None:
    """``pattern`` as a sensor card at ``path`` (JSON; :func:`read_card` gives the same pattern back).
    Never overwrites a file."""
    text = json.dumps(card_dict(pattern), indent=1) + "\n"
    with open(path, "x") as f:
        f.write(text)


#: a card's per-beam lists (one a beam) and the range of each value: (low, high, integers)
_CARD_BEAM_LISTS = {"drop_rate": (0.0, 1.0, False), "height_m": (-math.inf, math.inf, False),
                    "points": (0, math.inf, True), "vertical_offset_m": (-math.inf, math.inf, False),
                    "horizontal_offset_m": (-math.inf, math.inf, False)}
#: a card's scalars and their ranges (low, high): a range's accuracy, a nominal reach
_CARD_SCALARS = {"range_accuracy_m": (0.0, math.inf), "max_range_m_nominal": (0.0, math.inf)}


def _check_card_meta(path, d: dict) -> None:
    """A card's own fields beyond the pattern's checked on load, each refused in one line naming it: its
    ``beams`` the count of ``elevation_deg``, each per-beam list (:data:`_CARD_BEAM_LISTS`: a drop rate
    in [0, 1], heights and offsets finite, points counts) one finite value a beam in its range, each scalar
    (:data:`_CARD_SCALARS`) finite in its range. A drop rate of 1.5 was read as it was."""
    n = len(d["elevation_deg"])
    beams = d.get("beams")
    if beams is not None and (isinstance(beams, bool) or beams != n):
        raise FormatError(f"{path}: its beams ({beams!r}) is not the number of its elevation_deg ({n})")
    for key, (lo, hi, whole) in _CARD_BEAM_LISTS.items():
        v = d.get(key)
        if v is None:
            continue
        ok = isinstance(v, list) and len(v) == n
        bad = None if ok else v
        for k, x in enumerate(v if ok else []):
            if (isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or not lo <= x <= hi
                    or whole and x != int(x)):
                bad = f"{x!r} (beam {k})"
                break
        if bad is not None:
            what = {(0.0, 1.0): "a rate in [0, 1]", (0, math.inf): "a count >= 0"}.get((lo, hi), "a finite number")
            raise FormatError(f"{path}: its {key} must be a list of {n} values, one a beam, each {what}; got {bad}"
                              if ok else f"{path}: its {key} must be a list of {n} values, one a beam; got "
                              f"{type(v).__name__}{f' of {len(v)}' if isinstance(v, list) else ''}")
    for key, (lo, hi) in _CARD_SCALARS.items():
        x = d.get(key)
        if x is not None and (isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x)
                              or not lo <= x <= hi):
            raise FormatError(f"{path}: its {key} must be a finite number >= {lo:g}, got {x!r}")


def read_card(path, **changes) -> BeamPattern:
    """A :class:`BeamPattern` from a sensor card (:func:`write_card`; the shipped tables are cards too;
    an Ouster metadata JSON is read by :func:`read_ouster_metadata`). Keywords override fields.

    Raises :class:`FormatError` (one line, naming the file) for a JSON that is not a card."""
    try:
        d = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: not a sensor card (not JSON: {exc})") from None
    except OSError as exc:
        raise InputValueError(f"{path}: no such sensor card or shipped sensor ({exc.strerror}); "
                              f"shipped: {list(SENSORS)}") from None
    if isinstance(d, dict) and "elevation_deg" not in d and (
            "beam_altitude_angles" in d or "beam_altitude_angles" in (d.get("beam_intrinsics") or {})):
        return read_ouster_metadata(path, **changes)
    if not isinstance(d, dict) or not isinstance(d.get("elevation_deg"), list):
        raise FormatError(f"{path}: not a sensor card (a JSON object with an elevation_deg list and columns; "
                          "`slr-ray sensor fit` writes one)")
    _check_card_meta(path, d)
    try:
        return _degrees_checked(BeamPattern.from_table(d, **changes), path)
    except SlrError as exc:
        raise FormatError(f"{path}: not a sensor card ({exc})") from None
    except (TypeError, ValueError) as exc:
        raise FormatError(f"{path}: not a sensor card ({type(exc).__name__}: {exc})") from None


#: a unit's file whose beams (4 or more) span less than this (degrees) is warned of: radians written as
#: degrees (a VLP-16's 30 deg are 0.52 rad); every shipped unit spans 26 deg or more
RADIANS_SPAN_DEG = 2.0


_RADIANS_SAID: set = set()  # said once a process: a command reads a card more than once (checks, then use)


def _degrees_checked(pattern: BeamPattern, path) -> BeamPattern:
    """``pattern``, with one warning where its elevations look like radians."""
    el = np.asarray(pattern.elevation_deg)
    if len(el) >= 4 and el.max() - el.min() < RADIANS_SPAN_DEG:
        text = (f"{path}: its {len(el)} beams span {el.max() - el.min():.3g} deg ({el.min():+.3g} ... "
                f"{el.max():+.3g}): radians? (elevations are degrees; as radians they would span "
                f"{math.degrees(el.max() - el.min()):.3g} deg)")
        if text not in _RADIANS_SAID:
            _RADIANS_SAID.add(text)
            warnings.warn(text, SlrWarning, stacklevel=3)
    return pattern


def beams_outside(target: BeamPattern, elevation_range_deg) -> np.ndarray:
    """The beam ids of ``target`` whose elevation lies outside ``elevation_range_deg`` (``(low, high)``
    degrees: what the source frames ever saw), ascending: beams a conversion cannot fill."""
    lo, hi = (float(v) for v in elevation_range_deg)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise InputValueError(f"elevation_range_deg must be two finite angles, low first, got {elevation_range_deg!r}")
    el = np.asarray(target.elevation_deg)
    return np.flatnonzero((el < lo) | (el > hi))


def source_elevation_range(points, origin=None, percentiles=(1.0, 99.0)) -> tuple[float, float]:
    """The elevations (degrees) a frame saw from ``origin`` (default 0): the ``percentiles`` of its points'
    (the 1st to 99th: a stray point above or below is not a beam's)."""
    p = as_points(points, "points") - (np.zeros(3) if origin is None else as_origin(origin))
    if not len(p):
        raise InputValueError("a frame of no points saw no elevation")
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    lo, hi = np.percentile(el, percentiles)
    return float(lo), float(hi)


def conversion_reach(target: BeamPattern, source_points, points_out: int, source_origin=None) -> dict:
    """What a conversion to ``target`` could get from frames like ``source_points``: the target's beams
    outside the elevations the source saw (:func:`source_elevation_range`, from its own origin) are said
    once (an :class:`~slr_ray.errors.SlrWarning` with the count); ``points_out`` 0 (the conversion
    returned nothing) is an :class:`InputValueError`. Returns the summary's entries."""
    lo, hi = source_elevation_range(source_points, source_origin)
    out = beams_outside(target, (lo, hi))
    el = sorted(round(float(target.elevation_deg[b]), 3) for b in out)
    if len(out):
        warnings.warn(f"{len(out)} of the target's {target.n_beams} beams ({el[0]:+g} ... {el[-1]:+g} deg) lie "
                      f"outside what the source frames saw ({lo:+.1f} ... {hi:+.1f} deg, 1st-99th percentile "
                      "from their origin): those beams stay (nearly) empty", SlrWarning, stacklevel=3)
    if points_out == 0:
        raise InputValueError(f"the conversion returned no point: the target's beams ({min(target.elevation_deg):+g}"
                              f" ... {max(target.elevation_deg):+g} deg, ranges {target.range_limits}) meet nothing "
                              f"the source frames saw ({lo:+.1f} ... {hi:+.1f} deg)")
    return {"beams_outside_source": len(out), "beams_outside_source_deg": el,
            "source_elevation_range_deg": [round(lo, 3), round(hi, 3)]}


def miscalibrated(pattern: BeamPattern, elevation_sd: float = 0.1, azimuth_sd: float = 0.1,
                  seed: int = 0) -> BeamPattern:
    """``pattern`` with every beam moved off its table: each beam's elevation
    and azimuth offset plus a normal draw of ``elevation_sd`` / ``azimuth_sd``
    degrees (``seed``: the same draws every time).

    A real unit's beams are not where its nominal table says. Scan a mesh
    with the miscalibrated pattern (:func:`~slr_ray.meshscan.scan_mesh`),
    then re-scan the frame described by the nominal table, to see what the
    difference does (``benchmarks/bench_sensors.py``, part 5).
    """
    if not isinstance(pattern, BeamPattern):
        raise InputValueError(f"miscalibrated needs a BeamPattern, got {type(pattern).__name__}")
    for name, v in (("elevation_sd", elevation_sd), ("azimuth_sd", azimuth_sd)):
        if not (math.isfinite(v) and v >= 0):
            raise InputValueError(f"{name} must be a finite number >= 0, got {v!r}")
    rng = np.random.default_rng(seed)
    n = len(pattern.elevation_deg)
    el = np.asarray(pattern.elevation_deg) + rng.normal(0.0, elevation_sd, n)
    az = np.asarray(pattern.azimuth_offset_deg) + rng.normal(0.0, azimuth_sd, n)
    return dataclasses.replace(pattern, elevation_deg=tuple(el.tolist()), azimuth_offset_deg=tuple(az.tolist()))


def sensor_noise(points, origin, beams, range_sd: float = 0.01, beam_range_sd: float = 0.03,
                 dropout: float = 0.1, seed: int = 0):
    """Points of a frame with a real sensor's range errors and lost pulses.

    Every point moves along its ray from ``origin`` by a normal draw of
    ``range_sd`` metres plus its beam's own offset (one normal draw of
    ``beam_range_sd`` per value of ``beams``, the beam id or range-image row
    of each point: the beam-to-beam range offsets of a real unit), and a share ``dropout`` of the points is dropped
    (pulses with no return). The input is not changed.

    Returns
    -------
    points : (m, 3) float64
        The kept points, moved.
    kept : (m,) intp
        Their indices in the input (labels and attributes follow them).
    """
    pts = np.asarray(points, dtype=np.float64)
    beams = np.asarray(beams)
    if pts.ndim != 2 or pts.shape[1] != 3 or beams.shape != (len(pts),):
        raise InputValueError(f"points must be (n, 3) and beams (n,), got {pts.shape} and {beams.shape}")
    if not 0 <= dropout < 1:
        raise InputValueError(f"dropout must be in [0, 1), got {dropout!r}")
    for name, v in (("range_sd", range_sd), ("beam_range_sd", beam_range_sd)):
        if not (math.isfinite(v) and v >= 0):
            raise InputValueError(f"{name} must be a finite number >= 0, got {v!r}")
    if len(beams) and (beams.dtype.kind not in "iu" or beams.min() < 0):
        raise InputValueError("beams must be integers >= 0 (a beam id or range-image row per point)")
    rng = np.random.default_rng(seed)
    d = pts - as_origin(origin)
    r = np.linalg.norm(d, axis=1)
    offsets = rng.normal(0.0, beam_range_sd, beams.max(initial=-1) + 1)
    step = rng.normal(0.0, range_sd, len(pts)) + offsets[beams]
    moved = pts + d * np.divide(step, r, out=np.zeros_like(r), where=r > 0)[:, None]
    kept = np.flatnonzero(rng.random(len(pts)) >= dropout)
    return moved[kept], kept


def _sensor_file(what: str):
    """A reader of a calibration file whose malformed content (bad JSON/YAML, a
    key missing or of the wrong type) raises one :class:`FormatError` naming the file."""
    def wrap(reader):
        @functools.wraps(reader)
        def read(path, *args, **kwargs):
            try:
                return reader(path, *args, **kwargs)
            except OSError:
                raise
            except SlrError as exc:  # the content's values (angles, columns): said with the file's name
                if str(path) in str(exc):
                    raise
                raise type(exc)(f"{path}: {exc}") from exc
            except Exception as exc:  # json/yaml errors, KeyError, TypeError, AttributeError of odd content
                msg = str(exc).splitlines()[0] if str(exc) else ""
                raise FormatError(f"{path}: not a readable {what} ({type(exc).__name__}: {msg})") from exc
        return read
    return wrap


@_sensor_file("Ouster metadata JSON")
def read_ouster_metadata(path, **changes) -> BeamPattern:
    """A :class:`BeamPattern` from an Ouster sensor metadata JSON (ouster-sdk's
    ``beam_intrinsics``: ``beam_altitude_angles``, ``beam_azimuth_angles``; the
    columns from ``data_format.columns_per_frame`` or ``lidar_mode``)."""
    d = json.loads(Path(path).read_text())
    bi = d.get("beam_intrinsics", d)
    try:
        alt = bi["beam_altitude_angles"]
        az = bi["beam_azimuth_angles"]
    except KeyError:
        raise InputValueError(f"{path}: no beam_altitude_angles / beam_azimuth_angles (not Ouster metadata?; "
                              "a beam table as slr_ray/data/sensors/*.json has elevation_deg)") from None
    cols = (d.get("data_format") or {}).get("columns_per_frame") or d.get("columns_per_frame")
    if cols is None:
        mode = (d.get("config_params") or {}).get("lidar_mode") or d.get("lidar_mode") or "1024x10"
        cols = int(str(mode).split("x")[0])
    name = (d.get("sensor_info") or {}).get("prod_line") or Path(path).stem
    # offsets as the metadata gives them (the shipped ouster tables are these files' numbers)
    return _degrees_checked(BeamPattern(alt, int(cols), az, name=name,
                                        meta={"source": str(path), "format": "ouster metadata"}).with_(**changes), path)


@_sensor_file("sensor table JSON")
def read_sensor_table(path, **changes) -> BeamPattern:
    """A :class:`BeamPattern` from a beam table in the shipped layout (``slr_ray/data/sensors/*.json``:
    ``elevation_deg``, ``azimuth_offset_deg``, ``columns``, ``max_range_m_nominal``...), a shipped
    table's copy edited, say."""
    d = json.loads(Path(path).read_text())
    if not isinstance(d, dict) or "elevation_deg" not in d:
        raise InputValueError(f"{path}: no elevation_deg (not a beam table as slr_ray/data/sensors/*.json?)")
    return _degrees_checked(BeamPattern.from_table({"name": Path(path).stem, **d, "file": str(path)}, **changes), path)


def read_sensor_file(path, **changes) -> BeamPattern:
    """A :class:`BeamPattern` from a calibration file, whichever of the three it is: a ``.json`` beam
    table in the shipped layout (``elevation_deg``: :func:`read_sensor_table`) or Ouster metadata
    (:func:`read_ouster_metadata`), else a Velodyne calibration YAML (:func:`read_velodyne_calibration`)."""
    if Path(path).suffix.lower() != ".json":
        return read_velodyne_calibration(path, **changes)
    try:
        table = "elevation_deg" in json.loads(Path(path).read_text())
    except (ValueError, TypeError):  # not JSON: the Ouster reader says so, with the file's name
        table = False
    return (read_sensor_table if table else read_ouster_metadata)(path, **changes)


@_sensor_file("Velodyne calibration YAML")
def read_velodyne_calibration(path, columns: int = 1800, **changes) -> BeamPattern:
    """A :class:`BeamPattern` from a Velodyne calibration YAML (the ros-drivers/velodyne
    ``lasers:`` list: ``vert_correction`` and ``rot_correction`` in radians)."""
    d = yaml.safe_load(Path(path).read_text())
    lasers = sorted(d.get("lasers") or [], key=lambda x: x["laser_id"])
    if not lasers:
        raise InputValueError(f"{path}: no 'lasers' list (not a Velodyne calibration?)")
    el = [math.degrees(x["vert_correction"]) for x in lasers]
    # offsets as the file gives them, in degrees (the shipped velodyne tables are these files' numbers)
    az = [math.degrees(x.get("rot_correction", 0.0)) for x in lasers]
    return BeamPattern(el, columns, az, name=Path(path).stem,
                       meta={"source": str(path), "format": "velodyne calibration",
                             "vertical_offset_m": [x.get("vert_offset_correction", 0.0) for x in lasers]}
                       ).with_(**changes)


# --- a frame's own beams and table (slr_ray.evaluate, the embree backend's primary_pattern='fit') ------------

def scan_order_beams(points, n_beams: int = 64) -> np.ndarray | None:
    """Each point's beam from the order of a frame stored beam by beam (a KITTI ``.bin``).

    KITTI's HDL-64E frames hold the points ring after ring, highest beam
    first, each ring one turn of azimuth (counter-clockwise) starting at the
    front. The azimuth, unwrapped along the file, grows by one turn per ring,
    so ``floor(unwrapped azimuth / 2 pi)`` is the ring, which is the row of
    the range image (beam 0 highest). Returns ``None`` when that does not give
    exactly ``n_beams`` rings whose median elevations fall from first to last
    (the file is not in scan order).
    """
    p = as_points(points, "points")
    if len(p) < n_beams:
        return None
    u = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    ring = np.floor((u - u[0]) / (2 * math.pi) + 1e-9).astype(np.int64)
    if ring.min() < 0 or ring.max() != n_beams - 1 or np.any(np.diff(ring) < 0):
        return None
    r = np.linalg.norm(p, axis=1)
    el = np.arcsin(np.divide(p[:, 2], r, out=np.zeros_like(r), where=r > 0))
    cut = np.searchsorted(ring, np.arange(n_beams + 1))  # ring never falls: each a slice, in file order
    med = np.array([np.median(el[a:b]) if b > a else np.nan for a, b in zip(cut[:-1], cut[1:])])
    if not np.all(np.isfinite(med)) or np.any(np.diff(med) >= 0):
        return None
    return ring


def fitted_pattern(points, beams, base: BeamPattern, columns: int | None = None, rows: bool = False) -> BeamPattern:
    """``base`` with each beam's elevation the median elevation of its points in this frame.

    A real unit's beams are not where another unit's table says (the shipped
    HDL-64E S2 table tops out at +5 deg, KITTI's unit at +2.6): a frame whose
    points carry their beams gives its own elevations. Azimuth offsets are
    zero (the points' azimuths are where they were measured); ``columns``
    defaults to ``360 /`` the median azimuth step between a beam's
    points next in azimuth (not in the file's order: a Hesai PCD lists them out of firing order), rounded. Beams with no point keep ``base``'s elevation.

    ``beams`` are ``base``'s beam ids (table positions, as a ``ring`` field records them); ``rows``:
    they are its range-image rows instead (0 the highest: a KITTI ``.bin``'s scan order,
    :func:`scan_order_beams`), taken to the ids first. Either way beam ``i`` of the result is ``base``'s
    beam ``i`` (its ``meta``'s per-beam values stay its own): a table whose ids are not in elevation
    order (a VLP-16's, a Pandar64's) read by row gave a row's median to the beam of that id, and a row
    with no point the elevation of another beam.
    """
    p = as_points(points, "points")
    if rows:
        r = np.asarray(beams)
        if r.ndim != 1 or len(r) != len(p) or r.dtype.kind not in "iu" or (
                len(r) and (r.min() < -1 or r.max() >= base.n_beams)):
            raise InputValueError(f"beams (rows=True) must be one range-image row a point in [-1, {base.n_beams}) "
                                  f"({len(p)} integers), got shape {r.shape}, dtype {r.dtype}")
        r = r.astype(np.int64)
        beams = np.where(r >= 0, base.beam_of_row[np.maximum(r, 0)], -1)
    base.rows_of_beams(beams, len(p))  # checks the beam ids
    b = np.asarray(beams, np.int64)
    r = np.linalg.norm(p, axis=1)
    el = np.degrees(np.arcsin(np.divide(p[:, 2], r, out=np.zeros_like(r), where=r > 0)))
    az = np.arctan2(p[:, 1], p[:, 0])
    elev = np.array(base.elevation_deg, dtype=np.float64)
    steps = []
    for i in range(base.n_beams):
        mine = b == i
        if np.any(mine):
            elev[i] = np.median(el[mine])
            d = np.diff(np.sort(az[mine]))  # sorted: a file need not list a beam's points in firing order
            d = d[d > 1e-9]  # duplicate points are no step
            if len(d):
                steps.append(np.median(d))
    if columns is None:
        columns = int(round(2 * math.pi / np.median(steps))) if steps else base.columns
    while len(np.unique(elev)) != len(elev):  # two beams at one median: part them by a micro-degree
        _, first = np.unique(elev, return_index=True)
        dup = np.setdiff1d(np.arange(len(elev)), first)
        elev[dup] += 1e-6
    return base.with_(elevation_deg=tuple(elev.tolist()), azimuth_offset_deg=None, columns=int(columns),
                      name=f"{base.name or 'sensor'} fitted to the frame",
                      meta={**base.meta, "fitted": "elevations: median of each beam's points; offsets 0"})
