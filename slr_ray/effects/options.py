"""Which sensor effects a simulated scan carries (:class:`Effects`), every one off by default.

The same names serve the library, a scene's ``[effects]`` table
(:func:`slr_ray.scenes.scene_effects`) and JSON; an unknown name is an error
that lists the known ones. Values a sensor's datasheet gives (``'sensor'``)
are read from the shipped table's fields (``range_accuracy_m``,
``max_range_at_reflectivity``, ``beam_divergence_mrad``) when the pattern is
a :class:`~slr_ray.sensors.BeamPattern`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputValueError, dataclass_from_mapping
from .raydrop import RayDropModel

__all__ = ["Effects", "RETURN_KINDS", "INTENSITY_MODES", "MOTION_FRAMES", "SIZE_BOUNDS", "NEEDS"]

#: Which returns of a pulse a multiple-return scan reports.
RETURN_KINDS = ("first", "last", "strongest", "all")
#: What happens to the primary point's intensity.
INTENSITY_MODES = ("carry", "correct")
#: The frame a scan with motion is written in: the end pose's (compensated), or each column's (raw).
MOTION_FRAMES = ("sensor-end", "firing")


#: The largest value of each effect size: what a sensor can be (docs/effects.md says why each).
SIZE_BOUNDS = {"divergence_mrad": 50.0, "range_noise": 1.0, "range_noise_slope": 0.1, "return_separation": 100.0,
               "min_range": 1000.0, "max_range_at range": 1e5, "max_range_at reflectivity": 1.0,
               "reflectivity_scale": 1e6}
#: Options that tune another effect, and the option that turns it on: set away from its default
#: while that one is off, an option would be ignored, so it is refused.
NEEDS = {"returns": "divergence_mrad", "beam_rings": "divergence_mrad", "return_separation": "divergence_mrad",
         "min_share": "divergence_mrad", "range_noise_slope": "range_noise", "reflectivity_scale": "max_range_at"}


def _positive(name, v, allow_zero=False):
    if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            and (v >= 0 if allow_zero else v > 0)):
        raise InputValueError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {v!r}")
    top = SIZE_BOUNDS.get(name)
    if top is not None and v > top:
        raise InputValueError(f"{name} must be at most {top:g} (what a sensor can be; docs/effects.md), got {v!r}")
    return float(v)


def _integral(v, lo=None, hi=None):
    """Whether ``v`` is a whole number (an int, or a float with no fraction; not a bool, not a string) in [lo, hi]."""
    if isinstance(v, bool) or not isinstance(v, (numbers.Integral, float)):
        return False
    if isinstance(v, float) and not v.is_integer():  # also refuses nan and inf
        return False
    return (lo is None or v >= lo) and (hi is None or v <= hi)


@dataclass(frozen=True)
class Effects:
    """Sensor effects of a simulated scan (module docstring); all off by default.

    Attributes
    ----------
    divergence_mrad : float or 'sensor', optional
        Full beam divergence angle, milliradians: each pulse is a cone sampled
        by sub-rays (a backend that casts rays, ``casts_rays``: embree;
        :mod:`slr_ray.effects.returns`).
        'sensor': the table's ``beam_divergence_mrad``.
    beam_rings : int
        Rings of sub-rays across the footprint (HELIOS++'s
        ``beamSampleQuality``): 1 + 6 + 12 + ... + 6 (beam_rings - 1) rays.
    returns : tuple of {'first', 'last', 'strongest', 'all'}
        Which returns of a pulse are reported (a dual-return unit: first and
        strongest). Duplicates (first is also strongest) are reported once.
    return_separation : float
        Metres: hits of one pulse nearer than this along the range are one
        return (a receiver's minimum separation).
    min_share : float
        A return needs at least this share of the footprint (0-1).
    range_noise : float or 'sensor', optional
        Gaussian range noise, sigma in metres ('sensor': ``range_accuracy_m``).
    range_noise_slope : float
        Sigma grows by this many metres per metre of range.
    min_range : float, optional
        Blind zone, metres: nearer returns are dropped.
    max_range_at : (2,) float or 'sensor', optional
        ``(range_m, reflectivity)`` a datasheet quotes (50 m at 0.10): a return
        of reflectivity rho is kept up to ``range_m * sqrt(rho / reflectivity)``
        (received power ~ rho / R^2). Needs intensity; 'sensor': the table's
        ``max_range_at_reflectivity`` (its first pair).
    reflectivity_scale : float
        The intensity value that means reflectivity 1 (KITTI: 1; 8-bit: 255).
    ray_drop : RayDropModel, dict or str, optional
        A fitted drop model (:mod:`slr_ray.effects.raydrop`), its dict, or a
        JSON file of it.
    intensity : {'carry', 'correct'}, optional
        'carry' the primary point's intensity; 'correct' it for the new range
        and incidence (:mod:`slr_ray.effects.intensity`). Never invented: a
        cloud without intensity has none.
    motion : bool
        The scan needs poses (motion during the sweep): :func:`simulate`
        refuses a call without them.
    motion_sectors : int, optional
        Azimuth sectors with one pose each (default: every column with a
        backend that casts rays, 72 with one that does not, as binning,
        which scans once per sector).
    sweep_start_deg : float
        Azimuth (``atan2(y, x)``, degrees) where the sweep starts (KITTI: 180).
    sweep_clockwise : bool
        The sweep turns clockwise seen from above (Velodyne units, KITTI);
        default counter-clockwise (:mod:`slr_ray.effects.motion`).
    motion_frame : {'sensor-end', 'firing'}
        With motion: every return in the sensor frame at the sweep's end (a
        motion-compensated frame) or in the frame of the pose its column fired
        from (a raw frame, as KITTI raw's).
    seed : int
        Seed of every random draw (noise, drop); the same seed, the same scan.
    """

    divergence_mrad: float | str | None = None
    beam_rings: int = 3
    returns: tuple = ("first", "strongest", "last")
    return_separation: float = 1.0
    min_share: float = 0.05
    range_noise: float | str | None = None
    range_noise_slope: float = 0.0
    min_range: float | None = None
    max_range_at: object = None
    reflectivity_scale: float = 1.0
    ray_drop: object = None
    intensity: str | None = None
    motion: bool = False
    motion_sectors: int | None = None
    sweep_start_deg: float = 0.0
    sweep_clockwise: bool = False
    motion_frame: str = "sensor-end"
    seed: int = 0

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        if self.divergence_mrad is not None and self.divergence_mrad != "sensor":
            _positive("divergence_mrad", self.divergence_mrad)
        if not _integral(self.beam_rings, 1, 64):
            raise InputValueError(f"beam_rings must be an integer in [1, 64], got {self.beam_rings!r}")
        ret = (self.returns,) if isinstance(self.returns, str) else self.returns
        ret = tuple(ret) if isinstance(ret, (tuple, list)) else ()
        bad = [r for r in ret if not isinstance(r, str) or r not in RETURN_KINDS]
        if not ret or bad:
            raise InputValueError(f"returns must be one or more of {RETURN_KINDS}, got {self.returns!r}")
        twice = sorted({r for r in ret if ret.count(r) > 1})
        if twice:
            raise InputValueError(f"returns: {', '.join(twice)} given twice")
        if "all" in ret and len(ret) > 1:
            raise InputValueError(f"returns: 'all' already holds {', '.join(r for r in ret if r != 'all')}")
        set_("returns", ret)
        _positive("return_separation", self.return_separation)
        if not (isinstance(self.min_share, (int, float)) and 0 <= self.min_share <= 1):
            raise InputValueError(f"min_share must be in [0, 1], got {self.min_share!r}")
        if self.range_noise is not None and self.range_noise != "sensor":
            _positive("range_noise", self.range_noise, allow_zero=True)
        _positive("range_noise_slope", self.range_noise_slope, allow_zero=True)
        if self.min_range is not None:
            _positive("min_range", self.min_range, allow_zero=True)
        if self.max_range_at is not None and self.max_range_at != "sensor":
            try:
                r, rho = (float(x) for x in self.max_range_at)
            except (TypeError, ValueError):
                raise InputValueError(f"max_range_at must be (range_m, reflectivity) or 'sensor', "
                                      f"got {self.max_range_at!r}") from None
            _positive("max_range_at range", r)
            _positive("max_range_at reflectivity", rho)
            set_("max_range_at", (r, rho))
        _positive("reflectivity_scale", self.reflectivity_scale)
        if self.intensity is not None and self.intensity not in INTENSITY_MODES:
            raise InputValueError(f"intensity must be one of {INTENSITY_MODES} or None, got {self.intensity!r}")
        if not isinstance(self.motion, bool):
            raise InputValueError(f"motion must be true or false, got {self.motion!r}")
        if self.motion_sectors is not None and not _integral(self.motion_sectors, 1):
            raise InputValueError(f"motion_sectors must be an integer >= 1, got {self.motion_sectors!r}")
        if not (isinstance(self.sweep_start_deg, (int, float)) and not isinstance(self.sweep_start_deg, bool)
                and -360 <= self.sweep_start_deg <= 360):
            raise InputValueError(f"sweep_start_deg must be an angle in degrees in [-360, 360], got "
                                  f"{self.sweep_start_deg!r}")
        if not isinstance(self.sweep_clockwise, bool):
            raise InputValueError(f"sweep_clockwise must be true or false, got {self.sweep_clockwise!r}")
        if self.motion_frame not in MOTION_FRAMES:
            raise InputValueError(f"motion_frame must be one of {MOTION_FRAMES}, got {self.motion_frame!r}")
        if isinstance(self.ray_drop, (str, Path)):
            if not str(self.ray_drop).strip():  # an unset $MODEL: Path("") is the current directory
                raise InputValueError("ray_drop: no model file given (an empty path)")
            path = Path(self.ray_drop)
            if not path.is_file():
                raise InputValueError(f"ray_drop: no model file {str(path)!r} (a JSON of RayDropModel.to_dict())")
            try:
                set_("ray_drop", json.loads(path.read_text()))
            except ValueError as exc:
                raise InputValueError(f"ray_drop: {str(path)!r} is not valid JSON: {exc}") from None
            if not isinstance(self.ray_drop, dict):
                raise InputValueError(f"ray_drop: {str(path)!r} does not hold a model (a JSON object of "
                                      "RayDropModel.to_dict())")
        if isinstance(self.ray_drop, dict):
            set_("ray_drop", RayDropModel.from_dict(self.ray_drop))
        if self.ray_drop is not None and not isinstance(self.ray_drop, RayDropModel):
            raise InputValueError(f"ray_drop must be a RayDropModel, its dict or a JSON path, "
                                  f"got {type(self.ray_drop).__name__}")
        if not _integral(self.seed, 0):  # numpy's generators take no negative seed
            raise InputValueError(f"seed must be an integer >= 0, got {self.seed!r}")

    @classmethod
    def from_dict(cls, options: dict | None = None, *, relative_to=None, **more) -> "Effects":
        """Effects from a mapping (a scene's ``[effects]`` table) and keywords.

        ``relative_to``: the directory a relative ``ray_drop`` path of
        ``options`` is read from (the file's that holds them; default the
        working directory).

        Raises
        ------
        InputValueError
            naming unknown keys and listing the known ones.
        """
        options = dict(options or {})
        drop = options.get("ray_drop")
        if relative_to is not None and isinstance(drop, str) and not Path(drop).is_absolute():
            options["ray_drop"] = str(Path(relative_to) / drop)
        return dataclass_from_mapping(cls, options, more, "effect option(s)")

    @classmethod
    def load(cls, path) -> "Effects":
        """Effects from a TOML or JSON file (by its extension) of :class:`Effects`
        fields, at the top level or in an ``[effects]`` table (a scene file's);
        a relative ``ray_drop`` path is read from the file's directory.

        Raises
        ------
        InputValueError
            a missing or unreadable file, or bad fields; the message names the file.
        """
        path = Path(path)
        if not path.is_file():
            raise InputValueError(f"no effects file {str(path)!r}")
        suffix = path.suffix.lower()
        if suffix not in (".toml", ".json"):
            raise InputValueError(f"{path}: an effects file is .toml or .json, got {suffix!r}")
        try:
            data = tomllib.loads(path.read_text()) if suffix == ".toml" else json.loads(path.read_text())
        except (tomllib.TOMLDecodeError, ValueError) as exc:
            raise InputValueError(f"{path}: not valid {suffix[1:].upper()}: {exc}") from None
        if not isinstance(data, dict):
            raise InputValueError(f"{path}: expected a table of effect options, got {type(data).__name__}")
        table = data["effects"] if isinstance(data.get("effects"), dict) else data
        if table is not data:  # fields beside the table would be ignored: say so instead
            stray = sorted(set(data) & {f.name for f in dataclasses.fields(cls)} - {"seed"})
            if stray:
                raise InputValueError(f"{path}: effect option(s) {stray} lie outside its [effects] table, "
                                      "where they would be ignored: move them into it")
        try:
            return cls.from_dict(table, relative_to=path.parent)
        except InputValueError as exc:
            raise InputValueError(f"{path}: {exc}") from None

    def check_needs(self) -> "Effects":
        """``self``, refused when an option that tunes another effect (:data:`NEEDS`) is set away from
        its default while that effect is off: it would be ignored. Checked where the effects are used
        (:func:`~slr_ray.effects.simulate`, the command line), not by each part: a file may set
        ``returns`` for a ``--divergence-mrad`` given beside it."""
        defaults = {f.name: f.default for f in dataclasses.fields(self)}
        for name, on in NEEDS.items():
            if getattr(self, name) != defaults[name] and not getattr(self, on):
                raise InputValueError(f"{name} needs {on} (without it, {name} would be ignored)")
        return self

    @property
    def any(self) -> bool:
        """Whether any effect is on."""
        return self != Effects(seed=self.seed)

    def to_dict(self) -> dict:
        """Plain-JSON description."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = v.to_dict() if hasattr(v, "to_dict") else list(v) if isinstance(v, tuple) else v
        return out

    @property
    def resolved(self) -> bool:
        """Whether these are the settings a scan runs with: made by :meth:`resolve`
        (checked, no 'sensor' value left), which :func:`~slr_ray.effects.simulate`
        then takes as they are instead of resolving them again."""
        return getattr(self, "_resolved", False)

    def with_seed(self, seed: int) -> "Effects":
        """A copy with another ``seed`` (one scan's own stream), still :attr:`resolved` if this is."""
        out = dataclasses.replace(self, seed=seed)
        if self.resolved:
            object.__setattr__(out, "_resolved", True)
        return out

    def resolve(self, pattern) -> "Effects":
        """The settings a scan of ``pattern`` runs with, done once: :meth:`check_needs`, then a
        copy with every 'sensor' value read from ``pattern``'s table, marked :attr:`resolved`.

        Raises
        ------
        InputValueError
            an option that needs another, off; or a 'sensor' value when the pattern is not a
            sensor's or its table lacks the field.
        """
        if self.resolved:
            return self
        self.check_needs()
        meta = getattr(pattern, "meta", None)
        fields = {"divergence_mrad": "beam_divergence_mrad", "range_noise": "range_accuracy_m",
                  "max_range_at": "max_range_at_reflectivity"}
        changes = {}
        for name, key in fields.items():
            if getattr(self, name) != "sensor":
                continue
            if meta is None or meta.get(key) is None:
                who = getattr(pattern, "name", None) or type(pattern).__name__
                raise InputValueError(f"{name}='sensor': the pattern {who!r} has no {key!r} in its table; "
                                      f"give {name} as a number")
            v = meta[key]
            changes[name] = tuple(v[0]) if name == "max_range_at" else float(v)
        out = dataclasses.replace(self, **changes)
        object.__setattr__(out, "_resolved", True)  # not a field: equality and to_dict are the same
        return out
