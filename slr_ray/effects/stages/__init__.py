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
are generated from the stages' :class:`Flag` s (:data:`EFFECT_FLAGS`).

A new effect is a module of this package holding its :class:`Stage` subclass
and its options (it imports :mod:`.base`, never this package: no cycle) and
one line in :data:`STAGES` here, which imports every stage module; any long
computation may live in a module of :mod:`slr_ray.effects` of its own, as
:mod:`~slr_ray.effects.returns`, :mod:`~slr_ray.effects.noise` and
:mod:`~slr_ray.effects.raydrop` hold theirs.
"""

from __future__ import annotations

from ..settings import effects_class, merged
from .base import SCAN_SECTORS, Context, Flag, Rays, Returns, Stage
from .divergence import Divergence, DivergenceOptions
from .intensity import Intensity, IntensityOptions
from .motion import Motion, MotionOptions
from .range_limits import RangeLimits, RangeLimitsOptions
from .range_noise import RangeNoise, RangeNoiseOptions
from .ray_drop import RayDrop, RayDropOptions

__all__ = ["Returns", "Rays", "Flag", "Stage", "Context", "Divergence", "Motion", "RayDrop", "RangeLimits",
           "RangeNoise", "Intensity", "STAGES", "SEED_FLAG", "FLAGS", "EFFECT_FLAGS", "Effects", "SIZE_BOUNDS", "NEEDS",
           "DivergenceOptions", "MotionOptions", "RayDropOptions", "RangeLimitsOptions", "RangeNoiseOptions",
           "IntensityOptions", "SCAN_SECTORS"]

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
