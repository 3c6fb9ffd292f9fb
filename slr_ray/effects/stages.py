"""Every sensor effect as a stage: a small object that owns its options (a frozen
:class:`~slr_ray.effects.settings.EffectOptions` dataclass, whose fields
:class:`Effects`, made from :data:`STAGES`, takes), its command-line flags,
whether it is on, and what it changes.

A stage acts at one or more of three points of :func:`~slr_ray.effects.simulate`:

* :meth:`Stage.rays`, before the geometry: what is cast, and from where (beam
  divergence: each pulse's sub-rays and which returns a pulse reports; motion:
  the poses each sector of columns fires from), a :class:`Rays` plan;
* :meth:`Stage.apply`, on the returns the geometry made (ray drop, range
  limits, noise, intensity);
* :meth:`Stage.place`, on where the returns land (motion: the sensor's frame).

``simulate`` resolves the effects once (:meth:`~slr_ray.effects.Effects.resolve`),
asks each stage of :data:`STAGES` whether it is :meth:`~Stage.on`, runs the
``rays`` of those that are, makes the geometry the plan asks for (the ideal
scan when it asks for nothing, or rays cast), then their ``apply`` and
``place`` in the same order. The command line's effect flags and their help
are generated from the stages' :class:`Flag` s (:data:`EFFECT_FLAGS`). A new
effect is a :class:`Stage` subclass here (its options, and any long
computation, may live in a module of their own; the stage may not: that module
would import this one, which imports it for :data:`STAGES`) and one line in
:data:`STAGES`.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..arrays import as_origin
from ..backends import backends_with, require_rays
from ..backends.embree import estimate_normals
from ..errors import InputValueError
from .intensity import corrected_intensity
from .motion import column_sectors, interpolate_poses, to_firing_frames, to_frame
from .noise import add_range_noise, reflectivity_max_range
from .raydrop import RayDropModel
from .returns import footprint_samples
from .settings import (INTENSITY_MODES, MOTION_FRAMES, RETURN_KINDS, EffectOptions, effects_class, integral, merged,
                       positive)

__all__ = ["Returns", "Rays", "Flag", "Stage", "Context", "Divergence", "Motion", "RayDrop", "RangeLimits",
           "RangeNoise", "Intensity", "STAGES", "SEED_FLAG", "FLAGS", "EFFECT_FLAGS", "Effects", "SIZE_BOUNDS", "NEEDS",
           "DivergenceOptions", "MotionOptions", "RayDropOptions", "RangeLimitsOptions", "RangeNoiseOptions",
           "IntensityOptions"]

#: Sectors of columns a scanner that casts no rays scans one by one under motion (each a whole scan).
SCAN_SECTORS = 72


@dataclass
class Returns:
    """The returns of a scan as they pass through the stages: one row per return,
    in pulse order (the returns of a pulse contiguous)."""

    v: np.ndarray
    h: np.ndarray
    range: np.ndarray
    index: np.ndarray
    dir: np.ndarray
    fire: np.ndarray
    share: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    intensity: np.ndarray | None = None

    @classmethod
    def from_columns(cls, columns: dict) -> "Returns":
        """From the geometry's columns (extra ones, as ``strength``, are left out)."""
        return cls(**{f.name: columns[f.name] for f in dataclasses.fields(cls) if f.name in columns})

    def __len__(self) -> int:
        return len(self.v)

    def take(self, rows) -> "Returns":
        """The returns at ``rows`` (a mask or indices)."""
        return Returns(**{f.name: None if getattr(self, f.name) is None else getattr(self, f.name)[rows]
                          for f in dataclasses.fields(self)})


@dataclass
class Rays:
    """What the geometry casts, as the stages' :meth:`Stage.rays` leave it: by
    default nothing beyond the ideal scan (one ray a pulse from the origin).

    ``offsets``, ``weights``: each pulse's sub-rays and their shares of the
    footprint (:func:`~slr_ray.effects.returns.footprint_samples`); ``subrays``:
    whether they replace the pulse's own ray; ``separation``, ``min_share``,
    ``returns``: how a pulse's hits group into returns and which it reports.
    ``sectors``: ``(starts, stops, rotations, origins)`` of the column sectors
    that fire from their own poses, and ``n_sectors`` the number asked for (the
    firing frames are made with it).
    """

    offsets: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((1, 2)))
    weights: np.ndarray = dataclasses.field(default_factory=lambda: np.ones(1))
    subrays: bool = False
    separation: float = 1.0
    min_share: float = 0.0
    returns: tuple = ("all",)
    sectors: tuple | None = None
    n_sectors: int | None = None

    @property
    def ideal(self) -> bool:
        """Nothing to cast here: the scanner's own scan is the geometry."""
        return not self.subrays and self.sectors is None


class Flag(NamedTuple):
    """A command-line flag of one :class:`~slr_ray.effects.Effects` field.

    ``kind``: ``'number-or-sensor'``, ``'int'`` or ``'text'``; ``choices`` and
    ``nargs`` as argparse's."""

    field: str
    flag: str
    metavar: str | None
    help: str
    kind: str = "text"
    choices: tuple | None = None
    nargs: str | None = None


@dataclass
class Context:
    """What the stages read beside the returns (the scan's settings, resolved once)."""

    effects: object
    scanner: object
    pattern: object
    origin: np.ndarray
    intensity: np.ndarray | None
    normals: np.ndarray | None
    primary_origin: object
    rng: dict
    info: dict
    #: sensor-to-world poses over the sweep (motion), or None
    poses: np.ndarray | None = None
    #: what the geometry cast (the stages' :meth:`Stage.rays`), once made
    rays: Rays | None = None
    #: the frame the returns' points are in (:class:`~slr_ray.effects.EffectScan`'s ``frame``)
    frame: str = "world"

    def incidence_cos(self, r: Returns, rows) -> np.ndarray:
        """|cos| of each return's incidence on its point's normal (the given normals,
        the scanner's own, or estimated once)."""
        if self.normals is None:
            own = self.scanner.normals
            self.normals = (np.asarray(own, np.float64) if own is not None
                            else estimate_normals(self.scanner.points, k=10, primary_origin=self.origin))
        nrm = self.normals[r.index[rows]]
        return np.abs(np.einsum("ij,ij->i", nrm, r.dir[rows])) / np.linalg.norm(nrm, axis=1)

    def keep(self, r: Returns, mask, what: str) -> Returns:
        """The returns of ``mask``; the number removed goes to ``info`` as ``removed_{what}``."""
        self.info[f"removed_{what}"] = int(np.count_nonzero(~mask))
        return r.take(mask)


class Stage:
    """One effect: its options (``options``, whose fields are ``fields``), its
    flags, :meth:`on`, and what it changes (module docstring: :meth:`rays`,
    :meth:`apply`, :meth:`place`; each unchanged by default). ``name`` keys its
    seconds in the result's ``info``."""

    name: str = ""
    #: its options: a frozen :class:`~slr_ray.effects.settings.EffectOptions` dataclass, whose fields
    #: :class:`~slr_ray.effects.Effects` takes (a scene's ``[effects]`` table and JSON name them)
    options: type | None = None
    #: the Effects fields it owns (its options' fields)
    fields: tuple = ()
    #: its command-line flags (the rest of its fields through --effects FILE)
    flags: tuple = ()

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if cls.__dict__.get("options") is not None:
            cls.fields = tuple(f.name for f in dataclasses.fields(cls.options))

    def on(self, ctx: Context) -> bool:
        """Whether the stage runs with these effects."""
        raise NotImplementedError

    def rays(self, plan: Rays, ctx: Context) -> Rays:
        """What the geometry casts after this effect (before any work: refusals go here)."""
        return plan

    def apply(self, r: Returns, ctx: Context) -> Returns:
        """The returns after this effect."""
        return r

    def place(self, points: np.ndarray, r: Returns, ctx: Context) -> np.ndarray:
        """Where the returns land after this effect (``(m, 3)``, one row a return)."""
        return points


def _cast_by() -> str:
    """The backends that cast rays, from the registry (for help and messages)."""
    return ", ".join(backends_with("casts_rays")) or "none registered"


@dataclass(frozen=True)
class DivergenceOptions(EffectOptions):
    """Beam divergence and multiple returns.

    Attributes
    ----------
    divergence_mrad : float or 'sensor', optional
        Full beam divergence angle, milliradians: each pulse is a cone sampled
        by sub-rays (a backend that casts rays, ``casts_rays``: embree;
        :mod:`slr_ray.effects.returns`). 'sensor': the table's ``beam_divergence_mrad``.
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
    """

    SIZE_BOUNDS = {"divergence_mrad": 50.0, "return_separation": 100.0}
    NEEDS = {"returns": "divergence_mrad", "beam_rings": "divergence_mrad", "return_separation": "divergence_mrad",
             "min_share": "divergence_mrad"}
    SENSOR = {"divergence_mrad": "beam_divergence_mrad"}

    divergence_mrad: float | str | None = None
    beam_rings: int = 3
    returns: tuple = ("first", "strongest", "last")
    return_separation: float = 1.0
    min_share: float = 0.05

    def check(self):
        bounds = DivergenceOptions.SIZE_BOUNDS
        if self.divergence_mrad is not None and self.divergence_mrad != "sensor":
            positive("divergence_mrad", self.divergence_mrad, bounds=bounds)
        if not integral(self.beam_rings, 1, 64):
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
        object.__setattr__(self, "returns", ret)
        positive("return_separation", self.return_separation, bounds=bounds)
        if not (isinstance(self.min_share, (int, float)) and 0 <= self.min_share <= 1):
            raise InputValueError(f"min_share must be in [0, 1], got {self.min_share!r}")


class Divergence(Stage):
    """Beam divergence: each pulse is a cone of sub-rays, its hits grouped into
    returns of which a few are reported (:mod:`.returns`). Needs a scanner that
    casts rays (``casts_rays``)."""

    name = "divergence"
    options = DivergenceOptions
    flags = (
        Flag("divergence_mrad", "--divergence-mrad", "MRAD",
             f"beam divergence (mrad) or 'sensor' (a backend that casts rays: {_cast_by()})", "number-or-sensor"),
        Flag("returns", "--returns", "KIND", f"returns a pulse reports with divergence: {', '.join(RETURN_KINDS)} "
             "(default first strongest last)", choices=RETURN_KINDS, nargs="+"),
    )

    def on(self, ctx):
        return bool(ctx.effects.divergence_mrad)

    def rays(self, plan, ctx):
        require_rays(ctx.scanner, "beam divergence (divergence_mrad)")
        eff = ctx.effects
        offsets, weights = footprint_samples(eff.divergence_mrad * 1e-3, eff.beam_rings)
        return dataclasses.replace(plan, offsets=offsets, weights=weights, subrays=True,
                                   separation=eff.return_separation, min_share=eff.min_share, returns=eff.returns)


@dataclass(frozen=True)
class MotionOptions(EffectOptions):
    """Motion during the sweep.

    Attributes
    ----------
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
    """

    motion: bool = False
    motion_sectors: int | None = None
    sweep_start_deg: float = 0.0
    sweep_clockwise: bool = False
    motion_frame: str = "sensor-end"

    def check(self):
        if not isinstance(self.motion, bool):
            raise InputValueError(f"motion must be true or false, got {self.motion!r}")
        if self.motion_sectors is not None and not integral(self.motion_sectors, 1):
            raise InputValueError(f"motion_sectors must be an integer >= 1, got {self.motion_sectors!r}")
        if not (isinstance(self.sweep_start_deg, (int, float)) and not isinstance(self.sweep_start_deg, bool)
                and -360 <= self.sweep_start_deg <= 360):
            raise InputValueError(f"sweep_start_deg must be an angle in degrees in [-360, 360], got "
                                  f"{self.sweep_start_deg!r}")
        if not isinstance(self.sweep_clockwise, bool):
            raise InputValueError(f"sweep_clockwise must be true or false, got {self.sweep_clockwise!r}")
        if self.motion_frame not in MOTION_FRAMES:
            raise InputValueError(f"motion_frame must be one of {MOTION_FRAMES}, got {self.motion_frame!r}")


class Motion(Stage):
    """Motion during the sweep (:mod:`.motion`): each sector of columns fires from
    its own pose (every column, where the scanner casts rays; else
    :data:`SCAN_SECTORS` sectors, each scanned whole), and the returns are written
    in the sensor's frame at the sweep's end, or each in its firing pose's. On
    when ``simulate`` is given poses."""

    name = "motion"
    options = MotionOptions

    def on(self, ctx):
        return ctx.poses is not None

    def rays(self, plan, ctx):
        eff, nh = ctx.effects, ctx.pattern.shape[1]
        n = eff.motion_sectors or (nh if ctx.scanner.casts_rays else SCAN_SECTORS)
        starts, stops, times = column_sectors(nh, n, eff.sweep_start_deg, eff.sweep_clockwise)
        rotations, origins = interpolate_poses(ctx.poses, times)
        return dataclasses.replace(plan, sectors=(starts, stops, rotations, origins), n_sectors=n)

    def place(self, points, r, ctx):
        eff = ctx.effects
        if eff.motion_frame == "firing":
            ctx.frame = "firing"
            return to_firing_frames(points, r.h, ctx.pattern.shape[1], ctx.poses, ctx.rays.n_sectors,
                                    eff.sweep_start_deg, eff.sweep_clockwise)
        ctx.frame = "sensor-end"
        return to_frame(points, ctx.poses[-1])


@dataclass(frozen=True)
class RayDropOptions(EffectOptions):
    """Ray drop.

    Attributes
    ----------
    ray_drop : RayDropModel, dict or str, optional
        A fitted drop model (:mod:`slr_ray.effects.raydrop`), its dict, or a
        JSON file of it.
    """

    ray_drop: object = None

    def check(self):
        if isinstance(self.ray_drop, (str, Path)):
            if not str(self.ray_drop).strip():  # an unset $MODEL: Path("") is the current directory
                raise InputValueError("ray_drop: no model file given (an empty path)")
            path = Path(self.ray_drop)
            if not path.is_file():
                raise InputValueError(f"ray_drop: no model file {str(path)!r} (a JSON of RayDropModel.to_dict())")
            try:
                object.__setattr__(self, "ray_drop", json.loads(path.read_text()))
            except ValueError as exc:
                raise InputValueError(f"ray_drop: {str(path)!r} is not valid JSON: {exc}") from None
            if not isinstance(self.ray_drop, dict):
                raise InputValueError(f"ray_drop: {str(path)!r} does not hold a model (a JSON object of "
                                      "RayDropModel.to_dict())")
        if isinstance(self.ray_drop, dict):
            object.__setattr__(self, "ray_drop", RayDropModel.from_dict(self.ray_drop))
        if self.ray_drop is not None and not isinstance(self.ray_drop, RayDropModel):
            raise InputValueError(f"ray_drop must be a RayDropModel, its dict or a JSON path, "
                                  f"got {type(self.ray_drop).__name__}")


class RayDrop(Stage):
    """One draw per pulse, from its first return's range, incidence and intensity
    (:mod:`.raydrop`); a dropped pulse loses all its returns."""

    name = "ray_drop"
    options = RayDropOptions
    flags = (Flag("ray_drop", "--ray-drop", "MODEL", "a ray-drop model (JSON of 'slr-ray effects fit-drop')"),)

    def on(self, ctx):
        return ctx.effects.ray_drop is not None

    def apply(self, r, ctx):
        model = ctx.effects.ray_drop
        key = r.v * ctx.pattern.shape[1] + r.h  # the returns of a pulse are contiguous
        first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        inc = np.degrees(np.arccos(np.clip(ctx.incidence_cos(r, first), 0.0, 1.0)))
        i_first = None if ctx.intensity is None else ctx.intensity[r.index[first]]
        dropped = model.sample(r.range[first], inc, i_first if model.uses_intensity else None, rng=ctx.rng["drop"])
        return ctx.keep(r, ~np.repeat(dropped, np.diff(np.r_[first, len(key)])), "ray_drop")


@dataclass(frozen=True)
class RangeLimitsOptions(EffectOptions):
    """The blind zone and the maximum range by reflectivity.

    Attributes
    ----------
    min_range : float, optional
        Blind zone, metres: nearer returns are dropped.
    max_range_at : (2,) float or 'sensor', optional
        ``(range_m, reflectivity)`` a datasheet quotes (50 m at 0.10): a return
        of reflectivity rho is kept up to ``range_m * sqrt(rho / reflectivity)``
        (received power ~ rho / R^2). Needs intensity; 'sensor': the table's
        ``max_range_at_reflectivity`` (its first pair).
    reflectivity_scale : float
        The intensity value that means reflectivity 1 (KITTI: 1; 8-bit: 255).
    """

    SIZE_BOUNDS = {"min_range": 1000.0, "max_range_at range": 1e5, "max_range_at reflectivity": 1.0,
                   "reflectivity_scale": 1e6}
    NEEDS = {"reflectivity_scale": "max_range_at"}
    SENSOR = {"max_range_at": "max_range_at_reflectivity"}

    min_range: float | None = None
    max_range_at: object = None
    reflectivity_scale: float = 1.0

    def check(self):
        bounds = RangeLimitsOptions.SIZE_BOUNDS
        if self.min_range is not None:
            positive("min_range", self.min_range, allow_zero=True, bounds=bounds)
        if self.max_range_at is not None and self.max_range_at != "sensor":
            try:
                r, rho = (float(x) for x in self.max_range_at)
            except (TypeError, ValueError):
                raise InputValueError(f"max_range_at must be (range_m, reflectivity) or 'sensor', "
                                      f"got {self.max_range_at!r}") from None
            positive("max_range_at range", r, bounds=bounds)
            positive("max_range_at reflectivity", rho, bounds=bounds)
            object.__setattr__(self, "max_range_at", (r, rho))
        positive("reflectivity_scale", self.reflectivity_scale, bounds=bounds)


class RangeLimits(Stage):
    """The blind zone and the maximum range of each return's reflectivity (:mod:`.noise`)."""

    name = "range_limits"
    options = RangeLimitsOptions

    def on(self, ctx):
        eff = ctx.effects
        if eff.max_range_at is not None and ctx.intensity is None:
            ctx.info["max_range_at"] = "not applied: the cloud has no intensity"
        return eff.min_range is not None or (eff.max_range_at is not None and ctx.intensity is not None)

    def apply(self, r, ctx):
        eff = ctx.effects
        ok = np.ones(len(r), bool)
        if eff.min_range is not None:
            ok &= r.range >= eff.min_range
        if eff.max_range_at is not None and ctx.intensity is not None:
            rho = ctx.intensity[r.index] / eff.reflectivity_scale * r.share
            ok &= r.range <= reflectivity_max_range(rho, *eff.max_range_at)
        return ctx.keep(r, ok, "range_limits")


@dataclass(frozen=True)
class RangeNoiseOptions(EffectOptions):
    """Range noise.

    Attributes
    ----------
    range_noise : float or 'sensor', optional
        Gaussian range noise, sigma in metres ('sensor': ``range_accuracy_m``).
    range_noise_slope : float
        Sigma grows by this many metres per metre of range.
    """

    SIZE_BOUNDS = {"range_noise": 1.0, "range_noise_slope": 0.1}
    NEEDS = {"range_noise_slope": "range_noise"}
    SENSOR = {"range_noise": "range_accuracy_m"}

    range_noise: float | str | None = None
    range_noise_slope: float = 0.0

    def check(self):
        bounds = RangeNoiseOptions.SIZE_BOUNDS
        if self.range_noise is not None and self.range_noise != "sensor":
            positive("range_noise", self.range_noise, allow_zero=True, bounds=bounds)
        positive("range_noise_slope", self.range_noise_slope, allow_zero=True, bounds=bounds)


class RangeNoise(Stage):
    """Gaussian noise along each return's ray, sigma growing with range (:mod:`.noise`)."""

    name = "range_noise"
    options = RangeNoiseOptions
    flags = (Flag("range_noise", "--range-noise", "SIGMA", "Gaussian range noise (m), or 'sensor'",
                  "number-or-sensor"),)

    def on(self, ctx):
        return bool(ctx.effects.range_noise)

    def apply(self, r, ctx):
        r.range = add_range_noise(r.range, ctx.effects.range_noise, ctx.effects.range_noise_slope, ctx.rng["noise"])
        return r


@dataclass(frozen=True)
class IntensityOptions(EffectOptions):
    """Intensity.

    Attributes
    ----------
    intensity : {'carry', 'correct'}, optional
        'carry' the primary point's intensity; 'correct' it for the new range
        and incidence (:mod:`slr_ray.effects.intensity`). Never invented: a
        cloud without intensity has none.
    """

    intensity: str | None = None

    def check(self):
        if self.intensity is not None and self.intensity not in INTENSITY_MODES:
            raise InputValueError(f"intensity must be one of {INTENSITY_MODES} or None, got {self.intensity!r}")


class Intensity(Stage):
    """Intensity carried or corrected for the new range and incidence (:mod:`.intensity`),
    times each return's share of its footprint (``Returns.intensity``)."""

    name = "intensity"
    options = IntensityOptions
    flags = (Flag("intensity", "--intensity", None, "the input's intensity carried, or corrected",
                  choices=INTENSITY_MODES),)

    def on(self, ctx):
        return ctx.intensity is not None and (ctx.effects.intensity is not None or bool(ctx.effects.divergence_mrad))

    def apply(self, r, ctx):
        i0 = ctx.intensity[r.index]
        if ctx.effects.intensity == "correct":
            if ctx.primary_origin is None:
                raise InputValueError("intensity='correct' needs primary_origin (where the cloud was scanned from)")
            po = as_origin(ctx.primary_origin, "primary_origin")
            cos_new = ctx.incidence_cos(r, np.arange(len(r)))
            d0 = ctx.scanner.points[r.index] - po
            r0 = np.linalg.norm(d0, axis=1)
            nrm = ctx.normals[r.index]
            cos_old = np.abs(np.einsum("ij,ij->i", nrm, d0)) / np.maximum(r0 * np.linalg.norm(nrm, axis=1), 1e-300)
            i0 = corrected_intensity(i0, r.range, r0, cos_new, cos_old, ceiling=ctx.intensity.max(initial=0.0))
        r.intensity = i0 * r.share
        return r


#: Every effect, in the order :func:`~slr_ray.effects.simulate` runs them: a new effect is one line here.
STAGES: tuple[Stage, ...] = (Divergence(), Motion(), RayDrop(), RangeLimits(), RangeNoise(), Intensity())
#: Every effect's options in one frozen dataclass (:class:`~slr_ray.effects.settings.EffectsBase`): the
#: fields of the stages' options, in their order, and ``seed``; what a scene's ``[effects]`` table and
#: JSON name, every one off by default.
Effects = effects_class(STAGES, "Effects", __name__)
#: The largest value of each effect size: what a sensor can be (docs/effects.md says why each).
SIZE_BOUNDS = merged(Effects, "SIZE_BOUNDS")
#: Options that tune another effect, and the option that turns it on: set away from its default
#: while that one is off, an option would be ignored, so it is refused.
NEEDS = merged(Effects, "NEEDS")
#: The seed of every random draw: no stage's own.
SEED_FLAG = Flag("seed", "--effects-seed", "N", "seed of noise and drop (default 0)", "int")
#: Every effect flag, in the order ``--help`` lists them (generated from the stages).
FLAGS: tuple[Flag, ...] = (*(f for stage in STAGES for f in stage.flags), SEED_FLAG)
#: Effects fields with a flag of their own: field -> flag (the rest through --effects FILE).
EFFECT_FLAGS = {f.field: f.flag for f in FLAGS}
