"""``nearest``: the nearest point per pulse of the union (SLR's rule, the binning backend's)."""

from __future__ import annotations

from ..estimators import nearest_returns
from ..union import nearest_of_frames
from .base import SequenceMethod, TargetFrame

__all__ = ["Nearest", "METHOD"]


class Nearest(SequenceMethod):
    """SLR's rule on the union; a conversion reduces a frame at a time and merges the winners
    (:func:`~slr_ray.sequence.union.nearest_of_frames`): the union is never held whole."""

    name = "nearest"
    label = "nearest (binning of the union)"
    default = True

    def returns(self, points, pattern, options):
        return nearest_returns(points, pattern)

    def convert_frame(self, frame: TargetFrame, options):
        return nearest_of_frames(frame.seq, frame.frames, frame.pose, frame.pattern, frame.keep, frame.cache)


METHOD = Nearest()
