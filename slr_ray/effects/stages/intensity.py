"""Intensity carried or corrected as a stage (:mod:`slr_ray.effects.intensity`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...arrays import as_origin
from ...errors import InputValueError
from ..intensity import corrected_intensity
from ..settings import INTENSITY_MODES, EffectOptions
from .base import Flag, Stage

__all__ = ["IntensityOptions", "Intensity"]


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
