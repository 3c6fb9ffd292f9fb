"""The blind zone and the maximum range by reflectivity as a stage (:mod:`slr_ray.effects.noise`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputValueError
from ..noise import reflectivity_max_range
from ..settings import EffectOptions, positive
from .base import Stage

__all__ = ["RangeLimitsOptions", "RangeLimits"]


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
