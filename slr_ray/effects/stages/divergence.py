"""Beam divergence and multiple returns as a stage (:mod:`slr_ray.effects.returns`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ...backends import backends_with, require_rays
from ...errors import InputValueError
from ..returns import footprint_samples
from ..settings import RETURN_KINDS, EffectOptions, integral, positive
from .base import Flag, Stage

__all__ = ["DivergenceOptions", "Divergence"]


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
