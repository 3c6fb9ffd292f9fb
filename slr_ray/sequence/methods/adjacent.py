"""``adjacent``: the binning of the frame next to the held-out one alone (no accumulation)."""

from __future__ import annotations

from ..estimators import nearest_returns
from .base import HeldOut, SequenceMethod

__all__ = ["Adjacent", "METHOD", "adjacent_frame"]


def adjacent_frame(frames, target):
    """The nearest frame to ``target`` in index, the one before on a tie."""
    return min(frames, key=lambda i: (abs(i - target), i > target))


class Adjacent(SequenceMethod):
    """The nearest point per pulse of the adjacent frame's points (:func:`adjacent_frame`). Scores only."""

    name = "adjacent"
    label = "binning, adjacent frame alone"
    convert = False
    default = True

    def simulate(self, held: HeldOut, options):
        mine = held.union.frame_of_point == adjacent_frame(held.others, held.target)
        ret = nearest_returns(held.u[mine], held.pattern)
        return ret, ret.points, None


METHOD = Adjacent()
