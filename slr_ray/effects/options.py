"""Which sensor effects a simulated scan carries (:class:`Effects`), every one off by default.

The same names serve the library, a scene's ``[effects]`` table
(:func:`slr_ray.scenes.scene_effects`) and JSON; an unknown name is an error
that lists the known ones. Values a sensor's datasheet gives (``'sensor'``)
are read from the shipped table's fields (``range_accuracy_m``,
``max_range_at_reflectivity``, ``beam_divergence_mrad``) when the pattern is
a :class:`~slr_ray.sensors.BeamPattern`.

:class:`Effects` is made from the stages (:data:`~slr_ray.effects.stages.STAGES`):
its fields are every stage's options (each a frozen
:class:`~slr_ray.effects.settings.EffectOptions` dataclass in the stage's
module, with its checks, bounds and needs) and ``seed``; its methods are
:class:`~slr_ray.effects.settings.EffectsBase`'s. A new effect's options are
its own module's: no field is added here.
"""

from __future__ import annotations

from .settings import INTENSITY_MODES, MOTION_FRAMES, RETURN_KINDS
from .stages import NEEDS, SIZE_BOUNDS, Effects

__all__ = ["Effects", "RETURN_KINDS", "INTENSITY_MODES", "MOTION_FRAMES", "SIZE_BOUNDS", "NEEDS"]
