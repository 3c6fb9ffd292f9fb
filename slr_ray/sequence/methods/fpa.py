"""``fpa``: PCGen's first-peak average (:func:`~slr_ray.sequence.estimators.fpa_returns`)."""

from __future__ import annotations

from ..estimators import fpa_returns
from .base import FirstPeakOptions, SequenceMethod

__all__ = ["FirstPeakAverage", "METHOD"]


class FirstPeakAverage(SequenceMethod):
    """The nearest cluster of the union's points along each pulse, averaged (its ``gap``: ``--fpa-gap``)."""

    name = "fpa"
    label = "first-peak average (union)"
    options = FirstPeakOptions
    default = True

    def returns(self, points, pattern, options: FirstPeakOptions):
        return fpa_returns(points, pattern, options.gap)


METHOD = FirstPeakAverage()
