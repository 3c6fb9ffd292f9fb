"""Range noise as a stage (:mod:`slr_ray.effects.noise`)."""

from __future__ import annotations

from dataclasses import dataclass

from ..noise import add_range_noise
from ..settings import EffectOptions, positive
from .base import Flag, Stage

__all__ = ["RangeNoiseOptions", "RangeNoise"]


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
