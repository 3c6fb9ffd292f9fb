"""The ``embree-rays`` estimator: the fitted sensor (``rays``' model) cast with Embree onto the frames' meshes.

``rays`` (:mod:`slr_ray.sequence.rays`) casts each laser of the target along
its fitted ray (its height on the spin axis, its elevation, the sweep's skew,
its range bias) and finds where the ray meets the plane of the union's 64
points nearest its first cluster: two k-d tree queries and two eigen
decompositions a ray, seconds a frame. Here the surface is built once a
source frame instead, and the rays are cast by Embree:

* **a frame's mesh** (:func:`frame_mesh`): a frame's points are its rings
  (beams), each in azimuth order; two rings adjacent in elevation are joined
  by a zipper of triangles (each triangle two points of one ring and one of
  the other, in azimuth order), kept where the triangle spans at most
  ``max_step`` of azimuth (no pulses lost between) and its ranges from the
  frame's origin differ by at most ``max_ratio`` of the nearest (no jump from
  a foreground edge to what lies behind it). It is the surface the frame's own
  pulses sampled, seen from where they were fired; the road between two rings
  metres apart is the triangle between them. A triangle whose ranges differ
  by more than :data:`WEAK_RATIO` of the nearest is *weak* (edge-on from its
  frame: far road, or a skin from an edge to the background); rings farther apart in elevation
  than :data:`~slr_ray.sequence.ring_mesh.RATIO_STEP_DEG` may span ratios wider in proportion (:func:`ratio_widening`);
* **one Embree scene a frame** (:class:`MeshFrames`, world coordinates), built
  once and reused by every target whose window holds the frame, whatever the
  model (a raw mesh keeps its vertices' lasers; or, given a model, each vertex
  moved back along its laser's ray by that laser's range bias);
* **the model** (:func:`fit_embree_model`): the lasers' lines and the sweep's
  skew as ``rays`` fits them, on the other frames, and each laser's range
  bias against the other frames' raw meshes (:func:`mesh_range_bias`: each
  frame's every ``stride``-th point cast along its own laser's ray);
* **the cast** (:func:`cast_embree_rays`): every laser through every column's
  centre from its firing origin (:func:`rays_of_model`, the same rays as
  ``rays``), each ray into each frame's scene
  (:meth:`~slr_ray.raycast.RayScene.intersect_each`: one origin a ray); a hit
  on a weak triangle is taken only where no frame's mesh has a strong one for
  the ray; a raw mesh's hit moved back by the mean bias of its triangle's
  corners' lasers; the first surface is the nearest hit over the frames and
  the return the mean of the frames' hits within ``gap`` of it (the
  first-peak average's rule over the frames' surfaces), moved by the laser's
  range bias, binned into the target's image nearest per pulse as a real
  point is; a ray no mesh meets cast again tilted by the fit's residual (an open edge it grazes).

Measured against ``rays`` on the KITTI frames in
``benchmarks/sequence_embree_rays.py`` (docs/sequences.md).
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
from numba import njit

from ..errors import InputValueError, SlrWarning
from ..raycast import RayScene
from .estimators import FPA_GAP, PulseReturns, fpa_returns
from .rays import (PHASE_COHERENCE, RayModel, fit_ray_model, frame_motion, pattern_ray_model,
                   sweep_offsets)
from . import ring_mesh
from .porous import pass_porous
from .ring_mesh import (MAX_RATIO, MAX_STEP_COLUMNS, MAX_STEP_DEG, WEAK_RATIO, frame_mesh_spread,
                        frame_mesh, open_edge_skirts, ratio_widening, skirt_vertices)
from .sources import known_beams
from .union import Keep, rotate

__all__ = ["frame_mesh", "MeshFrames", "rays_of_model", "cast_embree_rays", "mesh_range_bias", "union_meshes",
           "frame_beams", "fit_embree_model", "pooled_lines", "fill_missing", "frame_surface", "frame_points_beams", "frame_ray_model",
           "mesh_problem",
           "combined_model", "with_azimuth_phases", "table_unfitted", "ratio_widening", "elevation_rows", "MAX_RATIO", "MAX_STEP_DEG", "MAX_STEP_COLUMNS", "EMBREE_GAP", "WEAK_RATIO"]

#: every this many points of a frame fitted for its own lasers' lines (frame_ray_model)
FIT_STRIDE = 8
#: every this many points of the frames fitted together for the lasers' lines (pooled_lines)
POOL_STRIDE = FIT_STRIDE
#: every this many points of a frame cast for the range biases (mesh_range_bias)
BIAS_STRIDE = 16
#: rounds of the range biases' fit against meshes that hold the same lasers' points (mesh_range_bias)
BIAS_ROUNDS = 1
#: the first-peak gap over the frames' surfaces (m): the frames' meshes of one surface lie within it
EMBREE_GAP = 0.2
#: rays start this far from their firing origin (m): nothing of a frame is nearer its sensor
TNEAR = 1.0
#: a ray no mesh meets is cast again tilted up and down by this many of its lasers' fit residuals (the
#: median angle of their points off their lines: a mesh's edge is known to within it). 3 (rays' line fit
#: keeps its points within 3) met more of a Pandar64's pulses (drop accuracy 0.948 to 0.954) but cost the
#: KITTI frames 0.0006 F@5cm and 0.03 m depth RMSE (1: 0.0002, 0.005 m; docs/sequences.md). 0: off, since the
#: meshes' open edges have skirts (ring_mesh.open_edge_skirts: the Pandar64's pulses the same without it, the
#: KITTI frames' F@5cm, RMSE, drop accuracy and Chamfer distance better)
EDGE_RESIDUALS = 0.0
#: a frame's mesh is built by Embree's quick (Morton) builder: the same hits; on the KITTI frames a mesh is
#: cast a few times (its targets' casts, the range biases'), so its build (~0.09 CPU s against ~0.03 quick)
#: costs more than the quick BVH's slower casts (~+30 %)
QUICK_BUILD = True


def _unbiased(points, beams, model: RayModel | None):
    """The frame's points moved back along their laser's ray by its range bias (from the laser's
    firing point on the spin axis; the sweep's offset is a few decimetres against ranges of metres)."""
    p = np.asarray(points, np.float64)
    if model is None or model.range_bias is None:
        return p
    b = np.asarray(beams, np.int64)
    ok = (b >= 0) & (b < len(model.range_bias))
    bias = np.where(ok, model.range_bias[np.clip(b, 0, len(model.range_bias) - 1)], 0.0)
    d = p.copy()
    d[:, 2] -= np.where(ok, model.height[np.clip(b, 0, len(model.height) - 1)], 0.0)
    d /= np.maximum(np.linalg.norm(d, axis=1), 1e-9)[:, None]
    return p - bias[:, None] * d


def _step_deg(columns) -> float:
    """A triangle's azimuth reach (degrees) for a sensor of ``columns`` a turn (:data:`MAX_STEP_COLUMNS`;
    :data:`MAX_STEP_DEG` where not given)."""
    return MAX_STEP_DEG if not columns else MAX_STEP_COLUMNS * 360.0 / columns


def _mesh(points, beams, pose, rows, model, step_deg, max_ratio, weak_ratio):
    """One frame's ``(scene, faces, raw, weak)`` (:meth:`MeshFrames.add`); ``rows`` each point's ring in
    elevation order (None: ``beams`` are)."""
    ring = np.asarray(beams if rows is None else rows, np.int64)
    faces, spread = frame_mesh_spread(points, ring, int(ring.max()) + 1 if len(ring) else 0, max_ratio, step_deg)
    P = np.asarray(pose, np.float64)
    local = _unbiased(points, beams, model)
    verts, faces, spread, cast = _skirted(points, ring, faces, spread, local, max_ratio, step_deg)
    world = rotate(verts, P[:3, :3]) + P[:3, 3]
    scene = RayScene.triangles(world, cast, quick=QUICK_BUILD) if len(faces) else None
    # a raw mesh keeps its vertices' lasers: the cast takes their biases out of its hits
    raw = np.asarray(beams, np.int64) if model is None or model.range_bias is None else None
    weak = None
    if weak_ratio is not None and len(faces):
        weak = spread > weak_ratio
    return scene, faces, raw, weak


def _skirted(points, ring, faces, spread, local, max_ratio, step_deg):
    """The mesh's open edges closed (:func:`~slr_ray.sequence.ring_mesh.open_edge_skirts`, of ``SKIRT_SHARE``
    then): ``(vertices, faces, spread, cast)``, ``cast`` the triangles Embree holds (into ``vertices``: the
    points ``local``, then the skirts'), ``faces`` the same with each skirt vertex its point's (the hits' debias
    and nearest corners read the points)."""
    share = ring_mesh.SKIRT_SHARE
    n_rows = int(ring.max()) + 1 if len(ring) else 0
    parents, shifts, tri, sp = open_edge_skirts(points, ring, n_rows, faces, max_ratio, step_deg, share)
    if not len(tri):
        return local, faces, spread, faces
    of = np.concatenate([np.arange(len(local)), parents])
    return (np.concatenate([local, skirt_vertices(local, parents, shifts)]), np.concatenate([faces, of[tri]]),
            np.concatenate([spread, sp]), np.concatenate([faces, tri]))


class MeshFrames:
    """The Embree scenes of frames' meshes in the world frame, one a frame, built once each
    (:meth:`add`) and cast into by every target that holds them (:func:`cast_embree_rays`)."""

    def __init__(self, max_ratio: float = MAX_RATIO, max_step_deg: float | None = None,
                 weak_ratio: float | None = WEAK_RATIO, on_cache: bool = False):
        self.max_ratio, self.max_step_deg, self.weak_ratio = max_ratio, max_step_deg, weak_ratio
        #: raw meshes held on the frames cache instead (:func:`union_meshes`, :func:`frame_surface`)
        self.on_cache = on_cache
        self._scenes: dict = {}

    def add(self, key, points, beams, pose, n_beams: int, model: RayModel | None = None, offset: int = 0,
            columns: int | None = None, rows=None):
        """Frame ``key``'s mesh: ``points`` in its own axes, ``beams`` its rings (lasers, by id), ``pose`` its
        pose; ``model``: its lasers' range biases taken out; ``offset``: the union index of its first point;
        ``columns``: its sensor's columns a turn (a triangle's azimuth reach: :data:`MAX_STEP_COLUMNS`;
        without, ``max_step_deg`` or :data:`MAX_STEP_DEG`); ``rows``: each point's ring in elevation order
        (default :func:`elevation_rows`: rings joined to the rings next to them in elevation, as
        :func:`frame_surface`'s, whatever their ids: a VLP-16's ids interleave, id order zips rings 15 deg apart)."""
        if key not in self._scenes:
            step = self.max_step_deg if self.max_step_deg is not None else _step_deg(columns)
            b = np.asarray(beams, np.int64)
            b = np.where(b < n_beams, b, -1)
            self._scenes[key] = _mesh(points, b, pose, elevation_rows(points, b) if rows is None else rows, model,
                                      step, self.max_ratio, self.weak_ratio)
        scene, faces, raw, weak = self._scenes[key]
        return scene, faces, offset, raw, weak

    def drop(self, key):
        self._scenes.pop(key, None)

    def __contains__(self, key):
        return key in self._scenes


def rays_of_model(pattern, model: RayModel, motion=(0.0, 0.0, 0.0)):
    """Every laser of ``model`` through every column's centre of ``pattern``: ``(origins, directions,
    lasers)`` in the target's frame (the firing point: the laser's height on the spin axis and the
    sweep's offset at the column's azimuth, as ``rays`` casts them)."""
    C = pattern.columns
    D = 2 * math.pi / C
    L = len(model.elevation)
    las = np.repeat(np.arange(L), C)
    col = np.tile(np.arange(C), L)
    th = model.azimuth_offset[las] + (col + 0.5) * D
    ce = np.cos(model.elevation[las])
    d = np.column_stack([ce * np.cos(th), ce * np.sin(th), np.sin(model.elevation[las])])
    phi = np.mod(th, 2 * math.pi)
    phi = np.where(phi > math.pi, phi - 2 * math.pi, phi)
    origin = (model.skew * ((phi + math.pi) / (2 * math.pi) - 0.5))[:, None] * np.asarray(motion, np.float64)[None, :]
    origin[:, 2] += model.height[las]
    return origin, d, las


def _strong(scene, weak, ow, dw, t, prims, layers: int = 4):
    """Where a ray's first hit is on a weak triangle, its first strong one behind (``layers`` casts at
    most; in place; inf where none)."""
    todo = np.flatnonzero((prims >= 0) & weak[np.maximum(prims, 0)])
    for _ in range(layers):
        if not len(todo):
            return
        step = t[todo] + 1e-3
        h = scene.intersect_each(ow[todo] + step[:, None] * dw[todo], dw[todo])
        t[todo], prims[todo] = step + h.distances, h.primitives
        todo = todo[(h.primitives >= 0) & weak[np.maximum(h.primitives, 0)]]
    t[todo], prims[todo] = np.inf, -1


def _edge_hits(live, model, ow, dw, P, hits):
    """Where no frame's mesh meets a ray, the ray tilted up and down in elevation by
    :data:`EDGE_RESIDUALS` of ``model``'s fit residual (its lasers' points lie that near their lines),
    cast again; the nearest hit of each frame's taken along the ray (in place; ``hits``: ``(t, prims, ts,
    ps)``, each frame's hits and its first strong ones). A ray cast along a ring of a frame seen from
    where it was fired runs along the ring's vertices: where the ring is the mesh's edge (its lowest,
    or no strip joins it on one side: a Pandar64's two lowest lasers missed 66 and 88 % of their
    pulses) the ray grazes the edge and meets it or not by rounding."""
    t, prims, ts, ps = hits
    delta = math.radians(EDGE_RESIDUALS * model.residual_deg) if np.isfinite(model.residual_deg) else 0.0
    none = np.flatnonzero(~np.isfinite(t).any(axis=1))
    if not delta > 0 or not len(none):
        return
    d = rotate(dw[none], P[:3, :3].T)  # the target's frame: elevation about its z
    el = np.arcsin(np.clip(d[:, 2], -1, 1))
    az = np.arctan2(d[:, 1], d[:, 0])
    tilted = [rotate(np.column_stack([np.cos(e) * np.cos(az), np.cos(e) * np.sin(az), np.sin(e)]), P[:3, :3])
              for e in (el + delta, el - delta)]
    for k, (scene, faces, _, raw, _) in enumerate(live):
        best, prim = np.full(len(none), np.inf), np.full(len(none), -1, np.int64)
        for dt in tilted:
            h = scene.intersect_each(ow[none], dt, tnear=TNEAR)
            tk, pk = h.distances.copy(), h.primitives.copy()
            if raw is not None and model.range_bias is not None:
                _debias(tk, pk, faces, raw, model.range_bias)
            near = tk < best
            best[near], prim[near] = tk[near], pk[near]
        t[none, k], prims[none, k], ts[none, k], ps[none, k] = best, prim, best, prim


def _debias(t, prims, faces, beams, bias):
    """Hits ``t`` on a raw mesh moved back by the mean range bias of their triangle's corners' lasers
    (in place): each corner was read that much long along its own ray, which from a nearby origin is
    nearly the cast ray."""
    _debias_kernel(t, np.asarray(prims, np.int64), faces, beams, np.asarray(bias, np.float64))


@njit(cache=True)
def _debias_kernel(t, prims, faces, beams, bias):
    L = len(bias)
    for i in range(len(t)):
        p = prims[i]
        if p < 0:
            continue
        s = 0.0
        for c in range(3):
            b = beams[faces[p, c]]
            if 0 <= b < L:
                s += bias[b]
        t[i] -= s / 3.0


def _first_peak(t, gap):
    """Per ray (rows), the nearest of the frames' hits (columns; inf: none) and the mean of those within
    ``gap`` of it; the frame of the nearest."""
    first = np.argmin(t, axis=1)
    t0 = t[np.arange(len(t)), first]
    near = t <= (t0 + gap)[:, None]
    n = near.sum(axis=1)
    mean = np.where(near, t, 0.0).sum(axis=1) / np.maximum(n, 1)
    return np.where(np.isfinite(t0), mean, np.inf), first


def cast_embree_rays(points, pattern, model: RayModel | None = None, motion=(0.0, 0.0, 0.0), gap: float = EMBREE_GAP,
                     *, surfaces, pose, porosity=None) -> PulseReturns:
    """One return per pulse of ``pattern``: ``model``'s rays (default the pattern's own) from the target at
    ``pose`` (world) cast into ``surfaces`` (``(scene, faces, offset)`` of :meth:`MeshFrames.add`, one a
    frame of the window); ``points`` the union (float64, the target's frame; the return's ``index`` is the
    union point nearest it among its triangle's corners). ``cast_rays``' arguments (module docstring).
    ``porosity`` (:class:`~slr_ray.sequence.porous.Porosity`): a first surface other frames went through
    is passed (:func:`~slr_ray.sequence.porous.pass_porous`)."""
    if not gap > 0:
        raise InputValueError(f"the fpa gap must be > 0 m, got {gap}")
    model = model or pattern_ray_model(pattern)
    pts = np.asarray(points, np.float64)
    origin, d, las = rays_of_model(pattern, model, motion)
    P = np.asarray(pose, np.float64)
    ow = rotate(origin, P[:3, :3]) + P[:3, 3]
    dw = rotate(d, P[:3, :3])
    live = [s for s in surfaces if s[0] is not None]
    shape = (len(d), max(len(live), 1))
    if live:  # every column written below (ts, ps: the first strong hit)
        t, prims, ts, ps = np.empty(shape), np.empty(shape, np.int64), np.empty(shape), np.empty(shape, np.int64)
    else:
        t, prims = np.full(shape, np.inf), np.full(shape, -1, np.int64)
        ts, ps = t.copy(), prims.copy()  # the first strong hit
    for k, (scene, faces, _, raw, weak) in enumerate(live):
        h = scene.intersect_each(ow, dw, tnear=TNEAR)
        tk, pk = h.distances, h.primitives
        sk, qk = tk.copy(), pk.copy()
        if weak is not None:
            _strong(scene, weak, ow, dw, sk, qk)
        if raw is not None and model.range_bias is not None:
            moved = np.flatnonzero(qk != pk)  # the strong hit differs from the first: debiased on its own
            sm = sk[moved]
            _debias(sm, qk[moved], faces, raw, model.range_bias)
            _debias(tk, pk, faces, raw, model.range_bias)
            sk = tk.copy()
            sk[moved] = sm
        t[:, k], prims[:, k], ts[:, k], ps[:, k] = tk, pk, sk, qk
    if live:  # rays along a mesh's open edge (its lowest ring, a ring with no strip on one side)
        _edge_hits(live, model, ow, dw, P, (t, prims, ts, ps))
    strong = np.isfinite(ts).any(axis=1)[:, None]
    np.copyto(t, ts, where=strong)
    np.copyto(prims, ps, where=strong)
    if porosity is not None and live:
        pass_porous(porosity, live, (ow, dw), (t, prims), gap, _first_peak, _live_debias(live, model))
    tt, first = _first_peak(t, gap)
    hitm = np.flatnonzero(np.isfinite(tt))
    tt = tt[hitm]
    L = las[hitm]
    if model.range_bias is not None:
        tt = tt + model.range_bias[L]
    hit = origin[hitm] + tt[:, None] * d[hitm]
    # the union point each return stands for: the nearest corner of the first surface's triangle
    index = _nearest_corners(pts, hit, hitm, first, prims, live)
    keys, ranges = pattern.pulse_ids(hit, np.zeros(3))
    win = _pulse_winners(keys, ranges)
    return PulseReturns(keys[win].astype(np.int64), ranges[win], hit[win], index[win])


def _live_debias(live, model):
    """``debias(t, prims, k)`` of frame ``k`` of ``live`` (its raw mesh's hits, as the cast's), or None."""
    if model.range_bias is None:
        return None

    def debias(t, prims, k):
        _, faces, _, raw, _ = live[k]
        if raw is not None:
            _debias(t, prims, faces, raw, model.range_bias)
    return debias


def _nearest_corners(pts, hit, hitm, first, prims, live) -> np.ndarray:
    """Each return's union point (``hit`` the returns of rays ``hitm``, ``first`` each ray's frame of the
    first surface, ``prims`` its triangle in each frame of ``live``): the corner of its triangle nearest it
    (the first corner where ``pts`` is empty), its frame's ``offset`` added."""
    index = np.zeros(len(hitm), np.int64)
    fk = first[hitm]
    for k, (_, faces, offset, _, _) in enumerate(live):
        m = np.flatnonzero(fk == k)
        if len(m):
            _corners_kernel(pts, hit, m, prims[hitm[m], k], np.asarray(faces, np.int64), int(offset), index)
    return index


@njit(cache=True)
def _corners_kernel(pts, hit, m, prims, faces, offset, index):
    for j in range(len(m)):
        i = m[j]
        best, bd = faces[prims[j], 0] + offset, np.inf
        if len(pts):
            for c in range(3):
                v = faces[prims[j], c] + offset
                dx, dy, dz = pts[v, 0] - hit[i, 0], pts[v, 1] - hit[i, 1], pts[v, 2] - hit[i, 2]
                d = math.sqrt((dx * dx + dy * dy) + dz * dz)  # numpy's norm: the same sum, the same order
                if c == 0 or d < bd:  # the first of equals (argmin's)
                    best, bd = v, d
        index[i] = best


def _pulse_winners(keys, ranges) -> np.ndarray:
    """The returns kept, one a pulse (``keys`` each return's, -1 none): its nearest (``ranges``), the first
    in order of equals; in order of pulse."""
    keys = np.asarray(keys)
    best = np.full(int(keys.max()) + 1 if len(keys) else 0, -1, np.int64)
    _winners_kernel(keys, np.asarray(ranges), best)
    return best[best >= 0]


@njit(cache=True)
def _winners_kernel(keys, ranges, best):
    for i in range(len(keys)):
        k = keys[i]
        if k < 0:
            continue
        b = best[k]
        if b < 0 or ranges[i] < ranges[b]:
            best[k] = i


def fill_missing(ret: PulseReturns, points, pattern, least: int = 1, gap: float = FPA_GAP) -> PulseReturns:
    """``ret`` with the pulses it misses (no mesh met) that hold at least ``least`` of the union's
    ``points`` (the target's frame) given their first-peak average
    (:func:`~slr_ray.sequence.estimators.fpa_returns`): the gaps of the meshes (depth jumps, rings
    too far apart) filled from the union. On the KITTI frames it trades depth and drop accuracy for
    coverage (the real frame's side of the Chamfer distance; docs/sequences.md)."""
    if least < 1 or not len(points):
        return ret
    f = fpa_returns(points, pattern, gap)
    keys, _ = pattern.pulse_ids(points, np.zeros(3))
    keys = keys[keys >= 0]
    held = np.searchsorted(np.sort(keys), f.keys, side="right") - np.searchsorted(np.sort(keys), f.keys)
    add = np.flatnonzero((held >= least) & ~np.isin(f.keys, ret.keys))
    k = np.concatenate([ret.keys, f.keys[add]])
    o = np.argsort(k, kind="stable")
    return PulseReturns(k[o], np.concatenate([ret.ranges, f.ranges[add]])[o],
                        np.concatenate([ret.points, f.points[add]])[o], np.concatenate([ret.index, f.index[add]])[o])


def mesh_range_bias(model: RayModel, frames, surfaces, stride: int = 8, reach: float = 0.2,
                    rounds: int = BIAS_ROUNDS) -> RayModel:
    """``model`` with each laser's range bias measured against meshes: ``frames`` ``(points, beams, pose,
    motion)`` (own axes), ``surfaces`` the same frames' raw meshes (:meth:`MeshFrames.add` without a
    model); each frame's every ``stride``-th point cast along its laser's ray from its firing point onto
    the other frames' meshes (the first-peak rule of :func:`cast_embree_rays`, the biases found so far
    taken out of the hits); a laser's bias the median of how far beyond them its points lie (within
    ``reach``). The meshes hold the same lasers' points of the other frames: one round sees a part of
    a laser's bias, the next rounds (``rounds`` in all, the hits cast once) the rest. One frame: no
    bias."""
    if len(frames) < 2:
        return model
    casts = []
    for j, (p, beams, pose, motion) in enumerate(frames):
        rest = [s for i, s in enumerate(surfaces) if i != j and s[0] is not None]
        lasers, r, ow, dw = _bias_rays(model, p, beams, pose, motion, stride)
        hits = []
        for scene, faces, _, raw, _ in rest:
            h = scene.intersect_each(ow, dw, tnear=TNEAR)
            hits.append((h.distances, h.primitives, faces, raw))
        casts.append((lasers, r, hits))
    return dataclasses.replace(model, range_bias=_biases(casts, len(model.elevation), reach, rounds))


def _bias_rays(model: RayModel, points, beams, pose, motion, stride: int):
    """A frame's every ``stride``-th point as a ray along its laser from its firing point (world): its
    lasers, ranges, origins and directions."""
    p = np.asarray(points, np.float64)[::stride]
    lasers = np.asarray(beams, np.int64)[::stride]
    origin = sweep_offsets(p, motion, model.skew)
    origin[:, 2] += model.height[lasers]
    dv = p - origin
    r = np.linalg.norm(dv, axis=1)
    dv /= np.maximum(r, 1e-9)[:, None]
    P = np.asarray(pose, np.float64)
    return lasers, r, rotate(origin, P[:3, :3]) + P[:3, 3], rotate(dv, P[:3, :3])


def _biases(casts, L: int, reach: float, rounds: int) -> np.ndarray:
    """Each laser's range bias from ``casts`` (``(lasers, ranges, hits)`` a frame, ``hits`` its rays'
    ``(distances, primitives, faces, raw)`` on each other frame's mesh): :func:`mesh_range_bias`."""
    bias = np.zeros(L)
    for _ in range(max(1, int(rounds))):
        along_all, laser_all = [], []
        for lasers, r, hits in casts:
            t = np.full((len(r), max(len(hits), 1)), np.inf)
            for k, (dist, prims, faces, raw) in enumerate(hits):
                t[:, k] = dist
                if raw is not None:
                    _debias(t[:, k], prims, faces, raw, bias)
            along = r - _first_peak(t, FPA_GAP)[0]
            ok = np.isfinite(along) & (np.abs(along) < reach)
            along_all.append(along[ok])
            laser_all.append(lasers[ok])
        along, lasers = np.concatenate(along_all), np.concatenate(laser_all)
        o = np.lexsort((along, lasers))
        along, lasers = along[o], lasers[o]
        starts = np.searchsorted(lasers, np.arange(L + 1))
        n = np.diff(starts)
        lo, hi = starts[:-1] + (n - 1) // 2, starts[:-1] + n // 2  # each laser's median
        bias = np.where(n >= 50, 0.5 * (along[np.minimum(lo, len(along) - 1)] + along[np.minimum(hi, len(along) - 1)]),
                        0.0)
    return bias


def frame_beams(frame, base, seq=None):
    """A frame's beams: its ``ring`` field (checked against ``base``, naming the frame and, given its
    sequence ``seq``, its file), else its scan order (KITTI's ``.bin``), else, for a card whose beams are its
    elevation bands (fitted from frames without rings), the band each point falls in (``rays``' beams:
    :func:`~slr_ray.sequence.sources.known_beams`), else None."""
    where = f" ({seq.paths[frame.index]})" if seq is not None and frame.attributes.get("ring") is not None else ""
    return known_beams(frame.points, frame.attributes, base, f"frame {frame.name}{where}")


def _base_key(base) -> tuple:
    return base.name, base.shape, tuple(np.round(np.asarray(base.elevation_deg, np.float64), 9).tolist())


def frame_points_beams(cache, i: int, base) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """Frame ``i``'s points in its own axes, their rings (``base``'s beam ids) and whether they are known
    (its ``ring`` field, its scan order: :func:`frame_beams`); not known: the beams of the rows of
    ``base``'s table its points fall in (None where it has no point). Held on ``cache`` while it holds
    the frame."""
    def make():
        f, _ = cache.get(int(i))
        pts = cache.own_points(int(i))
        beams = frame_beams(f, base, cache.seq)  # a ring field checked against base, naming the file
        if beams is not None:
            return pts, beams, True
        if not len(pts):
            return pts, None, False
        keys, _ = base.pulse_ids(pts, np.zeros(3))  # the band's beam id, as known frames' (one rule a sequence)
        return pts, np.where(keys >= 0, np.asarray(base.beam_of_row)[np.maximum(keys, 0) // base.columns], -1), False

    return cache.state(int(i), ("embree-rays beams", _base_key(base)), make)


def mesh_problem(points, attributes, base, max_ratio: float = MAX_RATIO) -> str | None:
    """Why a frame (``points`` in its own axes, its ``attributes``) gives no ring mesh with ``base``'s table
    (None where it gives one): the beams :func:`frame_points_beams` finds (a ``ring`` field, the scan order,
    else the rows of ``base``'s elevation bands its points fall in) meshed as :func:`frame_surface` meshes
    them, with no triangle. A terrestrial scan's points fill the bands a few degrees apart in azimuth, over
    a triangle's reach (:data:`MAX_STEP_COLUMNS`): no triangle, and no pulse returns; a spinning unit's
    frame, in scan order or not, meshes. One frame's mesh, without its Embree scene: a cheap up-front check."""
    pts = np.asarray(points, np.float64)
    beams = known_beams(pts, attributes, base)
    known = beams is not None
    if not known and len(pts):
        keys, _ = base.pulse_ids(pts, np.zeros(3))
        beams = np.where(keys >= 0, keys // base.columns, -1)
    if beams is None or not (beams >= 0).any():
        return f"none of its points lies in {base.name}'s elevation bands (no ring field, not in its scan order)"
    rows = elevation_rows(pts, beams) if known else beams
    faces, _ = frame_mesh_spread(pts, rows, int(rows.max()) + 1, max_ratio, _step_deg(base.columns))
    if len(faces):
        return None
    how = "its rings" if known else f"{base.name}'s elevation bands (no ring field, not in its scan order)"
    return (f"its points, by {how}, make no triangle of a ring mesh (points of a ring over "
            f"{_step_deg(base.columns):.2g} deg apart in azimuth: a terrestrial scan's?)")


def elevation_rows(points, beams) -> np.ndarray:
    """Each point's ring ranked by its ring's mean elevation in the frame, highest 0 (-1 stays -1): a
    ring's mesh joins the rings next to it in elevation, whatever their ids (a unit's ring ids need
    not be in elevation order)."""
    p = np.asarray(points, np.float64)
    b = np.asarray(beams, np.int64)
    ok = b >= 0
    if not ok.any():
        return b
    n = int(b[ok].max()) + 1
    el = np.arctan2(p[ok, 2], np.hypot(p[ok, 0], p[ok, 1]))
    cnt = np.bincount(b[ok], minlength=n)
    mean = np.where(cnt > 0, np.bincount(b[ok], el, n) / np.maximum(cnt, 1), -np.inf)
    rank = np.empty(n, np.int64)
    rank[np.argsort(-mean, kind="stable")] = np.arange(n)
    return np.where(ok, rank[np.maximum(b, 0)], -1)


def frame_surface(cache, i: int, base, drop_moving: bool = True, see_through=None, exclude=(),
                  max_ratio: float = MAX_RATIO, weak_ratio: float | None = WEAK_RATIO) -> tuple:
    """Frame ``i``'s raw mesh (:meth:`MeshFrames.add` without a model: its kept points, its rings):
    ``(scene, faces, raw, weak, points)``, ``points`` how many it kept (None scene: no ring known or
    no triangle). Built once while ``cache`` holds the frame, for every target and model."""
    i = int(i)
    keep, _ = cache.selection(i, drop_moving, see_through, exclude)
    key = ("embree-rays mesh", _base_key(base), Keep.of(drop_moving, see_through, exclude).key(i), max_ratio,
           weak_ratio)

    def make():
        f, _ = cache.get(i)
        pts, beams, known = frame_points_beams(cache, i, base)
        if keep is not None:
            pts, beams = pts[keep], None if beams is None else beams[keep]
        if beams is None:
            return None, np.zeros((0, 3), np.int64), None, None, len(pts)
        rows = elevation_rows(pts, beams) if known else base.rows_of_beams(beams)
        return _mesh(pts, beams, f.pose, rows, None, _step_deg(base.columns), max_ratio,
                     weak_ratio) + (len(pts),)

    return cache.state(i, key, make)


def union_meshes(cache, frames, base, model: RayModel | None = None, drop_moving: bool = True, see_through=None,
                 exclude=(), meshes: MeshFrames | None = None) -> list:
    """The surfaces of ``frames`` (sequence indices, in the union's order: ``offset`` of each frame's
    first point in :func:`~slr_ray.sequence.union.accumulate`'s union of them) for
    :func:`cast_embree_rays`: each frame's kept points meshed by its rings (``base``'s beam count), its
    lasers' range biases (``model``) taken out. Without a model the raw meshes (the same for every
    model; the cast takes the biases out of the hits) are held on ``cache`` (:func:`frame_surface`:
    built once while it holds the frame; ``meshes`` of ``on_cache`` gives their settings); ``meshes``
    keeps them instead (and those of a model). A
    frame whose rings are not known (no ``ring`` field, not in scan order) is meshed by the rows of
    ``base``'s table its points fall in."""
    out, offset = [], 0
    for i in frames:
        i = int(i)
        if model is None and (meshes is None or meshes.on_cache):
            held = meshes or MeshFrames()
            scene, faces, raw, weak, n = frame_surface(cache, i, base, drop_moving, see_through, exclude,
                                                       held.max_ratio, held.weak_ratio)
            out.append((scene, faces, offset, raw, weak))
            offset += n
            continue
        meshes = meshes if meshes is not None and not meshes.on_cache else MeshFrames()
        f, _ = cache.get(i)
        keep, _ = cache.selection(i, drop_moving, see_through, exclude)
        pts, beams, known = frame_points_beams(cache, i, base)
        if keep is not None:
            pts = pts[keep]
            beams = None if beams is None else beams[keep]
        if beams is None:
            out.append((None, np.zeros((0, 3), np.int64), offset, None, None))
        else:
            bias = None if model is None or model.range_bias is None else model.range_bias.tobytes()
            key = (i, bias, len(pts), model.height.tobytes() if bias else None)
            out.append(meshes.add(key, pts, beams, f.pose, base.n_beams, model, offset, base.columns,
                                  None if known else base.rows_of_beams(beams)))  # frame_surface's rings
        offset += len(pts)
    return out


#: a laser's line is fitted on at least this many points farther than 2 m from the spin axis (rays' fit)
FIT_LEAST = 20


def table_unfitted(model: RayModel, points, beams, base, rows: bool = False) -> RayModel:
    """``model`` (fitted on ``points``, their lasers ``beams``) with each laser whose line had too few
    points to fit (:data:`FIT_LEAST`; ``fit_ray_model`` gives it the others' mean elevation, the
    middle of the fan) at its elevation in ``base``'s table: a Pandar64's 5 deg laser, 8 points a frame
    under the sky, cast at -3.7 deg beside its -3.71 deg one took that laser's pulses on the road.
    ``rows``: ``beams`` are the table's rows, not its ids (a frame's beams are its ids whichever gave
    them, its scan order too: :func:`frame_points_beams`): the table read by row."""
    p = np.asarray(points, np.float64)
    b = np.asarray(beams, np.int64)
    far = np.hypot(p[:, 0], p[:, 1]) > 2.0
    few = np.bincount(b[far & (b >= 0)], minlength=len(model.elevation))[:len(model.elevation)] < FIT_LEAST
    table = np.radians(np.asarray(base.elevation_deg, np.float64))
    if rows:
        table = table[np.asarray(base.beam_of_row)]
    if not few.any() or len(table) != len(model.elevation):
        return model
    return dataclasses.replace(model, elevation=np.where(few, table, model.elevation))


def frame_ray_model(cache, seq, i: int, base) -> RayModel | None:
    """Frame ``i``'s own lasers' lines and sweep skew (:func:`~slr_ray.sequence.rays.fit_ray_model` on its
    points alone), None where its rings are not known; held on ``cache`` while it holds the frame."""
    def make():
        pts, beams, known = frame_points_beams(cache, i, base)
        if not known or not len(pts):
            return None
        ok = beams >= 0
        try:
            model = fit_ray_model([(pts[ok], beams[ok], frame_motion(seq.poses, int(i)))], base.n_beams,
                                  stride=FIT_STRIDE)
        except InputValueError:  # too few points on its lasers
            return None
        return table_unfitted(model, pts[ok][::FIT_STRIDE], beams[ok][::FIT_STRIDE], base)

    return cache.state(int(i), ("embree-rays model", _base_key(base)), make)


def with_azimuth_phases(model: RayModel, cache, frames, base, columns: int) -> RayModel:
    """``model`` with where in its column each laser fires (``columns`` a turn) from the frames' own
    points (:func:`~slr_ray.sequence.rays.fit_azimuth_phases`; each frame's phasor sums held on
    ``cache``); frames whose beams are not known left out; none: ``model`` as it is."""
    acc, cnt = np.zeros(base.n_beams, complex), np.zeros(base.n_beams)
    D = 2 * math.pi / int(columns)
    for i in frames:
        pts, beams, known = frame_points_beams(cache, int(i), base)
        if not known or not len(pts):
            continue

        def make(pts=pts, beams=beams):  # fit_azimuth_phases' sums, a frame's
            ok = beams >= 0
            b = beams[ok]
            ph = np.exp(1j * int(columns) * (np.arctan2(pts[ok, 1], pts[ok, 0]) - 0.5 * D))
            return (np.bincount(b, ph.real, base.n_beams)[:base.n_beams]
                    + 1j * np.bincount(b, ph.imag, base.n_beams)[:base.n_beams],
                    np.bincount(b, minlength=base.n_beams)[:base.n_beams].astype(np.float64))

        a, c = cache.state(int(i), ("embree-rays phasors", _base_key(base), int(columns)), make)
        acc, cnt = acc + a, cnt + c
    if not cnt.any():
        return model
    coherence = np.abs(acc) / np.maximum(cnt, 1)
    offset = np.where((coherence >= PHASE_COHERENCE) & (cnt >= 20), np.angle(acc) * D / (2 * math.pi), 0.0)
    return dataclasses.replace(model, azimuth_offset=offset)


def combined_model(models) -> RayModel:
    """One sensor from frames' own fits: each laser's elevation and height, the skew, the median over
    the frames."""
    if len(models) == 1:
        return models[0]
    med = [np.median(np.stack([getattr(m, n) for m in models]), axis=0)
           for n in ("elevation", "height", "azimuth_offset")]
    return RayModel(*med, float(np.median([m.skew for m in models])) + 0.0, "fitted",
                    round(float(np.median([m.residual_deg for m in models])), 5))


def pooled_lines(model: RayModel, cache, seq, frames, base) -> RayModel:
    """``model`` (:func:`combined_model`'s) with its lasers' lines fitted on the points of ``frames`` together
    at its skew (``rays``' fit, one skew: the median of the frames' own; every :data:`FIT_STRIDE`-th point;
    a laser too sparse to fit at its table's elevation, :func:`table_unfitted`). The median of each frame's
    own height and elevation is not a line of their points: on the BALM unit (rings 1.4 deg apart, deskewed
    frames) the two differ by 0.2-0.3 deg a laser, and the pooled lines cast its held-out frames' pulses
    2 mm nearer their real depths (MedAE; docs/sequences.md)."""
    parts = []
    for i in frames:
        pts, beams, _ = frame_points_beams(cache, int(i), base)
        ok = beams >= 0
        parts.append((pts[ok], beams[ok], frame_motion(seq.poses, int(i))))
    try:
        lines = fit_ray_model(parts, base.n_beams, skews=[model.skew], stride=POOL_STRIDE)
    except InputValueError:  # too few points on its lasers
        return model
    lines = table_unfitted(lines, np.concatenate([p[::POOL_STRIDE] for p, _, _ in parts]),
                           np.concatenate([b[::POOL_STRIDE] for _, b, _ in parts]), base)
    return dataclasses.replace(model, elevation=lines.elevation, height=lines.height)  # the frames' own residual


def _frame_bias_casts(cache, seq, j: int, model: RayModel, base, targets, surfaces, sel):
    """Frame ``j``'s every :data:`BIAS_STRIDE`-th point cast along its laser (``model``, its own fit) onto each
    frame of ``targets``' raw mesh (``surfaces``); each frame pair's hits held on ``cache`` with ``j``."""
    def rays():
        pts, beams, _ = frame_points_beams(cache, j, base)
        ok = beams >= 0
        f, _ = cache.get(j)
        return _bias_rays(model, pts[ok], beams[ok], f.pose, frame_motion(seq.poses, j), BIAS_STRIDE)

    lasers, r, ow, dw = cache.state(j, ("embree-rays bias rays", _base_key(base)), rays)
    hits = []
    for k, (scene, faces, _, raw, _) in zip(targets, surfaces):
        if k == j or scene is None:
            continue

        def cast(scene=scene):
            h = scene.intersect_each(ow, dw, tnear=TNEAR)
            return h.distances, h.primitives

        dist, prims = cache.state(j, ("embree-rays bias cast", int(k), _base_key(base), sel), cast)
        hits.append((dist, prims, faces, raw))
    return lasers, r, hits


def fit_embree_model(seq, others, base, cache, drop_moving: bool = True, see_through=None, exclude=(),
                     joint: bool = False) -> tuple[RayModel, list]:
    """``rays``' sensor fitted on the frames ``others`` (never a held-out one) and their raw meshes
    (:func:`union_meshes`, the union's order), which :func:`cast_embree_rays` casts into. Each frame's
    lasers' lines and sweep skew fitted on its own points (:func:`frame_ray_model`), the median over
    ``others``, the lines then fitted on their points together at that skew (:func:`pooled_lines`); each
    laser's range bias against the other frames' raw meshes (:func:`mesh_range_bias`,
    each frame's points cast along its own fit's rays). Each frame's fit, mesh and casts are held on
    ``cache`` (:meth:`~slr_ray.sequence.union.FrameCache.state`): a sequence's held-out frames and a conversion's targets fit and mesh
    each frame once. ``joint``: the lines fitted on all of ``others``' points together (``rays``'
    fit, a laser too sparse to fit at its table's elevation as here: :func:`table_unfitted`; nothing held
    but the meshes). Frames whose beams are not known are left out of the fit;
    none known: ``base``'s ideal rays."""
    surfaces = union_meshes(cache, others, base, None, drop_moving, see_through, exclude)
    known, unknown = [], []
    for i, surface in zip(others, surfaces):
        _, b, ok = frame_points_beams(cache, int(i), base)
        model = None if joint or not ok else frame_ray_model(cache, seq, int(i), base)
        if not ok or (not joint and model is None):
            unknown.append(seq.names[int(i)])
            continue
        known.append((int(i), surface, model))
    if unknown:
        warnings.warn(f"frame(s) {', '.join(unknown)}: beams not known (no ring field, not in {base.name}'s scan "
                      f"order of {base.n_beams} rings): left out of the rays' fit, meshed by the table's rows"
                      + ("" if known else "; the table's ideal rays cast"), SlrWarning, stacklevel=2)
    if not known:
        return pattern_ray_model(base), surfaces
    if joint:
        frames = []
        for i, _, _ in known:
            pts, b, _ = frame_points_beams(cache, i, base)
            ok = b >= 0
            frames.append((pts[ok], b[ok], cache.get(i)[0].pose, frame_motion(seq.poses, i)))
        model = fit_ray_model([(p, b, v) for p, b, _, v in frames], base.n_beams)  # stride 2, as table_unfitted's
        model = table_unfitted(model, np.concatenate([p[::2] for p, _, _, _ in frames]),
                               np.concatenate([b[::2] for _, b, _, _ in frames]), base)
        return mesh_range_bias(model, frames, [s for _, s, _ in known], BIAS_STRIDE), surfaces
    model = combined_model([m for _, _, m in known])
    if len(known) < 2:
        return model, surfaces
    model = pooled_lines(model, cache, seq, [i for i, _, _ in known], base)
    sel = Keep.of(drop_moving, see_through, exclude).key(-1)
    idx, surf = [i for i, _, _ in known], [s for _, s, _ in known]
    casts = [_frame_bias_casts(cache, seq, j, m, base, idx, surf, sel) for j, _, m in known]
    return dataclasses.replace(model, range_bias=_biases(casts, base.n_beams, 0.2, BIAS_ROUNDS)), surfaces
