"""``embree-sources``: discs from each source frame's own pulse grid, one scene a frame
(:func:`~slr_ray.sequence.union.discs_of_frames`), reused by the targets that hold it."""

from __future__ import annotations

from ..union import discs_of_frames
from .base import HeldOut, SequenceMethod, TargetFrame

__all__ = ["EmbreeSources", "METHOD"]


class EmbreeSources(SequenceMethod):
    """Each frame's discs sized from its own pulse grid (its sensor fitted to it): needs the frames'
    own sensor; its scenes are per-frame state on the frames cache."""

    name = "embree-sources"
    label = "embree discs from each source frame's pulse grid"
    needs_source_sensor = True
    source_why = "their discs come from their own pulse grids"

    def simulate(self, held: HeldOut, options):
        ret, _ = discs_of_frames(held.cache, held.others, held.pose, held.pattern, held.base, held.keep)
        return ret, ret.points, None

    def convert_frame(self, frame: TargetFrame, options):
        return discs_of_frames(frame.cache, frame.frames, frame.pose, frame.pattern, frame.source, frame.keep)


METHOD = EmbreeSources()
