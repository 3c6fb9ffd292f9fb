"""Ray drop as a stage (:mod:`slr_ray.effects.raydrop`)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import InputValueError
from ..raydrop import RayDropModel
from ..settings import EffectOptions
from .base import Flag, Stage

__all__ = ["RayDropOptions", "RayDrop"]


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
