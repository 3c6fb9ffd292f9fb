"""``rays``: each beam cast along the sensor's own modelled ray onto the union's planes
(:mod:`slr_ray.sequence.rays`); for a held-out frame the rays are fitted on the *other* frames
of its window (:func:`holdout_ray_model`), the motion taken from the poses."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ...errors import SlrWarning
from ..embree_rays import table_unfitted
from ..rays import (RayModel, cast_grid_rays, cast_rays, fit_azimuth_phases, fit_range_bias, fit_ray_model,
                    frame_motion, pattern_ray_model)
from ..sources import known_beams
from .base import HeldOut, RaysOptions, SequenceMethod

__all__ = ["Rays", "METHOD", "holdout_ray_model", "GRID_RAYS"]

#: what ``rays`` casts for a terrestrial scanner's frame (its ``ray_model``'s ``what``)
GRID_RAYS = ("a terrestrial scanner has no beams: each pulse of its fitted grid cast from its origin through the "
             "pulse's centre onto the union's planes (no lasers, no sweep, no range bias fitted)")


def holdout_ray_model(seq, others, base, pattern, cache) -> RayModel:
    """The sensor's rays fitted from the frames ``others`` (never the held-out frame): their own points,
    their beams (a ``ring`` field or the scan order) and their motion from the poses
    (:func:`~slr_ray.sequence.rays.fit_ray_model`; a laser with too few points to fit at its table's
    elevation, :func:`~slr_ray.sequence.embree_rays.table_unfitted`, as ``embree-rays``'s), where in its column each laser fires
    (:func:`~slr_ray.sequence.rays.fit_azimuth_phases`, in ``pattern``'s columns), and each laser's
    range bias against the others' frames (:func:`~slr_ray.sequence.rays.fit_range_bias`). Where a frame's beams are not known, the
    pattern's own rays."""
    frames, worlds, unknown = [], [], []
    for i in others:
        f, w = cache.get(i)
        beams = known_beams(f.points, f.attributes, base, f"frame {seq.names[i]} ({seq.paths[i]})")  # out of the table: refused, named
        if beams is None or len(f.points) == 0:
            unknown.append(seq.names[i])
            continue
        base.rows_of_beams(beams, len(f.points))  # one a point
        known = beams >= 0  # -1: a point whose beam is not known
        frames.append((f.points[known], beams[known], frame_motion(seq.poses, i)))
        worlds.append((w[known], beams[known], seq.poses[i], frames[-1][2]))
    if unknown:
        warnings.warn(f"frame(s) {', '.join(unknown)}: beams not known (no ring field, not in {base.name}'s scan "
                      f"order of {base.n_beams} rings): left out of the rays' fit"
                      + ("" if frames else "; rays casts the table's ideal rays"), SlrWarning, stacklevel=2)
    if not frames:
        return pattern_ray_model(pattern)
    model = fit_ray_model(frames, base.n_beams)  # stride 2: a laser too sparse to fit keeps its table's elevation
    model = table_unfitted(model, np.concatenate([p[::2] for p, _, _ in frames]),
                           np.concatenate([b[::2] for _, b, _ in frames]), base)
    if pattern is not None:  # where in its column each laser fires (an Ouster's at the edge): its rays cast there
        offset, _ = fit_azimuth_phases([(p, b) for p, b, _ in frames], base.n_beams, pattern.columns)
        model = dataclasses.replace(model, azimuth_offset=offset)
    return fit_range_bias(model, worlds)


class Rays(SequenceMethod):
    """The sensor's rays onto the union's planes: a held-out frame's rays fitted from the other frames
    (reported as ``ray_model``); a terrestrial scanner's frame (no beams: ``held.base`` None) its fitted
    grid's pulse centres (:data:`GRID_RAYS`); a conversion casts the target table's own rays (no motion)."""

    name = "rays"
    label = "beam rays onto the union's planes"
    options = RaysOptions
    default = True
    info = "ray_model"

    def returns(self, points, pattern, options: RaysOptions):
        return cast_rays(points, pattern, gap=options.gap, neighbours=options.neighbours, max_shift=options.max_shift)

    def simulate(self, held: HeldOut, options: RaysOptions):
        if held.base is None:  # a terrestrial scanner: no beams, its grid's pulse centres from its origin
            ret = cast_grid_rays(held.u, held.pattern, gap=options.gap, neighbours=options.neighbours,
                                 max_shift=options.max_shift)
            return ret, ret.points, {"source": "grid", "what": GRID_RAYS}
        if held.target_base is not None:  # another unit than the frames': its table's own rays, as convert casts
            ret = self.returns(held.u, held.pattern, options)
            return ret, ret.points, pattern_ray_model(held.pattern).to_dict() | {
                "why": "the held-out frame is of another unit (target sensor): its table's ideal rays"}
        model = holdout_ray_model(held.seq, held.others, held.base, held.pattern, held.cache)
        ret = cast_rays(held.u, held.pattern, model, frame_motion(held.seq.poses, held.target), gap=options.gap,
                        neighbours=options.neighbours, max_shift=options.max_shift)
        return ret, ret.points, model.to_dict()


METHOD = Rays()
