"""``embree-rays``: ``rays``' fitted sensor cast with Embree onto each source frame's ring mesh
(:mod:`slr_ray.sequence.embree_rays`). For a held-out frame the sensor is fitted on the *other* frames
of its window (each frame's own fit, the median; the range biases against the other frames' meshes);
a conversion casts the target table's own rays. Each frame's mesh, fit and casts are per-frame state
on the frames cache: a sequence builds each once."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...errors import InputValueError
from ..embree_rays import (EMBREE_GAP, MAX_RATIO, WEAK_RATIO, MeshFrames, cast_embree_rays, fill_missing,
                           fit_embree_model, mesh_problem, union_meshes, with_azimuth_phases)
from ..estimators import PulseReturns
from ..porous import BEYOND, Porosity
from ..porous import MARGIN as POROUS_MARGIN
from ..rays import frame_motion, pattern_ray_model
from ..same_pose import keep_voted
from ..union import to_frame
from .base import HeldOut, MethodOptions, SequenceMethod, TargetFrame

__all__ = ["EmbreeRaysOptions", "EmbreeRays", "METHOD"]


@dataclass(frozen=True)
class EmbreeRaysOptions(MethodOptions):
    """The ``embree-rays`` method's settings (:func:`~slr_ray.sequence.embree_rays.cast_embree_rays`).

    Attributes
    ----------
    gap : float
        The first-peak gap over the frames' meshes (m): the return is the mean of the frames' hits
        within it of the nearest.
    max_ratio : float
        A mesh triangle's ranges (from its frame's origin) differ by at most this share of the nearest.
    weak_ratio : float
        A triangle whose ranges differ by more than this share of the nearest is weak: a ray takes it
        only where no frame's mesh has a strong one (0: no weak rule).
    fill : int
        Pulses no mesh meets that hold at least this many union points take the union's first-peak
        average (0: none; 1: every such pulse: more coverage, less depth and drop accuracy).
    fill_around : int
        With fill: 0, every such pulse; a >= 1, only those with no mesh return within a rows and 2a
        columns (the holes of the meshes, not their edges).
    porous : float
        See-through margin (m): a first surface that more of the window's frames' pulses went through
        (returned this far beyond it) than stopped on (within it) is passed, the ray cast on behind it
        (slr_ray.sequence.porous; 0: first surface always, the previous default).
    porous_window : int
        With porous: 0, each frame's one pulse through the hit votes; w >= 1, its pulses w rows and 2w
        columns around vote too and a ray passes where the region's share that went through exceeds the
        ray's own threshold (a fixed low-discrepancy sequence): about that share of its rays pass.
    porous_beyond : float
        With porous: hits nearer than this (m) are kept (near, the passes were a silhouette's pixels).
    """

    PREFIX: ClassVar[str] = "embree_rays"
    gap: float = EMBREE_GAP
    max_ratio: float = MAX_RATIO
    weak_ratio: float = WEAK_RATIO
    fill: int = 0
    fill_around: int = 0
    porous: float = POROUS_MARGIN
    porous_window: int = 0
    porous_beyond: float = BEYOND

    def check(self) -> None:
        for name in ("gap", "max_ratio"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise InputValueError(f"--embree-rays-{name.replace('_', '-')} must be > 0, got {v}")
        if not (isinstance(self.weak_ratio, (int, float)) and 0 <= self.weak_ratio):
            raise InputValueError(f"--embree-rays-weak-ratio must be >= 0, got {self.weak_ratio}")
        if self.weak_ratio and self.weak_ratio >= self.max_ratio:  # no triangle kept could be weak
            raise InputValueError(f"--embree-rays-weak-ratio ({self.weak_ratio}) must be under --embree-rays-max-ratio "
                                  f"({self.max_ratio}): triangles beyond max-ratio are not meshed, so none would be "
                                  "weak (0 turns the weak rule off)")
        if not (isinstance(self.porous, (int, float)) and self.porous >= 0):
            raise InputValueError(f"--embree-rays-porous must be metres >= 0, got {self.porous}")
        if not (isinstance(self.porous_window, (int, np.integer)) and self.porous_window >= 0):
            raise InputValueError(f"--embree-rays-porous-window must be a count >= 0, got {self.porous_window}")
        if not (isinstance(self.porous_beyond, (int, float)) and self.porous_beyond >= 0):
            raise InputValueError(f"--embree-rays-porous-beyond must be metres >= 0, got {self.porous_beyond}")
        if not (isinstance(self.fill, (int, np.integer)) and self.fill >= 0):
            raise InputValueError(f"--embree-rays-fill must be a count >= 0, got {self.fill}")
        if not (isinstance(self.fill_around, (int, np.integer)) and self.fill_around >= 0):
            raise InputValueError(f"--embree-rays-fill-around must be a count >= 0, got {self.fill_around}")

    @property
    def weak(self):
        return self.weak_ratio or None

    @property
    def meshes(self) -> MeshFrames:
        """The frames' raw meshes of these settings, held on the frames cache."""
        return MeshFrames(self.max_ratio, weak_ratio=self.weak, on_cache=True)


class EmbreeRays(SequenceMethod):
    """The fitted sensor's rays cast by Embree onto the frames' ring meshes (reported as ``ray_model``
    for a held-out frame); a conversion casts the target table's own rays (no motion). Needs the
    frames' own sensor: its rings make the meshes."""

    name = "embree-rays"
    label = "the fitted sensor cast with Embree onto the frames' ring meshes"
    options = EmbreeRaysOptions
    needs_source_sensor = True
    source_why = "their meshes join their own sensor's rings"
    info = "ray_model"

    def source_problem(self, points, attributes, base, options: EmbreeRaysOptions):
        return mesh_problem(points, attributes, base, options.max_ratio)

    def simulate(self, held: HeldOut, options: EmbreeRaysOptions):
        model, surfaces = fit_embree_model(held.seq, held.others, held.base, held.cache, held.drop_moving,
                                           held.see_through, (held.target,))
        if model.source == "fitted":  # where in its column each laser fires (an Ouster's at the edge)
            model = with_azimuth_phases(model, held.cache, held.others, held.base, held.pattern.columns)
        if (options.max_ratio, options.weak) != (MAX_RATIO, WEAK_RATIO):  # the fit's biases on the defaults' meshes
            surfaces = union_meshes(held.cache, held.others, held.base, None, held.drop_moving, held.see_through,
                                    (held.target,), options.meshes)
        ret = cast_embree_rays(held.u, held.pattern, model, frame_motion(held.seq.poses, held.target), options.gap,
                               surfaces=surfaces, pose=held.pose,
                               porosity=_porosity(held.cache, held.others, held.base, options))
        if held.target_base is None:  # the frames' own sensor fired again: those fired from its pose vote
            ret = keep_voted(ret, held.u, held.union.source, held.union.origins, held.pose[:3, 3], held.pattern)
        ret = fill_holes(ret, held.u, held.pattern, options.fill, options.fill_around)
        return ret, ret.points, model.to_dict()

    def convert_frame(self, frame: TargetFrame, options: EmbreeRaysOptions):
        union = frame.union()
        surfaces = union_meshes(frame.cache, frame.frames, frame.source, None, frame.drop_moving,
                                frame.see_through, (), options.meshes)
        u = to_frame(union.points, frame.pose)
        ret = cast_embree_rays(u, frame.pattern, pattern_ray_model(frame.pattern), gap=options.gap, surfaces=surfaces,
                               pose=frame.pose, porosity=_porosity(frame.cache, frame.frames, frame.source, options))
        ret = fill_holes(ret, u, frame.pattern, options.fill, options.fill_around)
        return ret, {n: v[ret.index] for n, v in union.attributes.items()}


def fill_holes(ret: PulseReturns, points, pattern, least: int = 1, around: int = 0) -> PulseReturns:
    """:func:`~slr_ray.sequence.embree_rays.fill_missing`, keeping (``around`` >= 1) only the fills of
    pulses with no return of ``ret`` within ``around`` rows and ``2 around`` columns (columns wrap):
    the meshes' holes (far sparse surfaces one frame saw), not their edges, where a lone union point
    is more often a silhouette's than what the pulse met (docs/sequences.md, the OS1-128's coverage)."""
    filled = fill_missing(ret, points, pattern, least)
    if around < 1 or len(filled) == len(ret):
        return filled
    rows, cols = pattern.shape
    hit = np.zeros((rows + 2 * around, cols), bool)
    hit[around:around + rows].reshape(-1)[ret.keys] = True  # rows padded (no wrap), columns wrap
    near = np.zeros((rows, cols), bool)
    for dr in range(2 * around + 1):
        band = hit[dr:dr + rows]
        for dc in range(-2 * around, 2 * around + 1):
            near |= np.roll(band, dc, axis=1)
    keep = ~near.reshape(-1)[filled.keys] | np.isin(filled.keys, ret.keys)
    return PulseReturns(filled.keys[keep], filled.ranges[keep], filled.points[keep], filled.index[keep])


def _porosity(cache, frames, base, options: EmbreeRaysOptions):
    """The frames' own range images (``base`` fitted to each; made at the first vote) as see-through votes,
    or None."""
    if not options.porous:
        return None
    return Porosity(lambda: [(cache.get(int(i))[0].pose, cache.view(int(i), base)) for i in frames], options.porous,
                    options.porous_window, options.porous_beyond)


METHOD = EmbreeRays()
