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
  frame: far road, or a skin from an edge to the background);
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
  point is.

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
from ..evaluate import scan_order_beams
from ..raycast import RayScene
from .estimators import FPA_GAP, PulseReturns
from .rays import RayModel, fit_ray_model, frame_motion, pattern_ray_model, sweep_offsets
from .sources import ring_beams
from .union import rotate

__all__ = ["frame_mesh", "MeshFrames", "rays_of_model", "cast_embree_rays", "mesh_range_bias", "union_meshes",
           "frame_beams", "fit_embree_model", "MAX_RATIO", "MAX_STEP_DEG", "MAX_STEP_COLUMNS", "EMBREE_GAP", "WEAK_RATIO"]

#: a triangle's ranges (from its frame's origin) differ by at most this share of the nearest
MAX_RATIO = 0.3
#: a triangle spans at most this many of its sensor's columns of azimuth (no pulses lost between): 0.4 deg
#: of an HDL-64E's 2,083 columns (chosen on the KITTI frames: 0.8 and 2 deg lost 0.0005 and 0.003 drop accuracy)
MAX_STEP_COLUMNS = 0.4 * 2083 / 360
#: the same in degrees where the sensor's columns are not given
MAX_STEP_DEG = 0.4
#: a triangle whose ranges differ by more than this share of the nearest is *weak* (seen edge-on from its
#: frame: the road far off, or a skin from an edge to what lies behind it): a ray takes it only where
#: no frame's mesh gives it a strong one
WEAK_RATIO = 0.1
#: rounds of the range biases' fit against meshes that hold the same lasers' points (mesh_range_bias)
BIAS_ROUNDS = 1
#: the first-peak gap over the frames' surfaces (m): the frames' meshes of one surface lie within it
EMBREE_GAP = 0.2
#: rays start this far from their firing origin (m): nothing of a frame is nearer its sensor
TNEAR = 1.0


@njit(cache=True)
def _zipper(order, starts, az, rng, max_step, max_ratio, out):
    """Triangles joining each ring (``order[starts[b]:starts[b+1]]``, by azimuth) to the next;
    returns how many were written into ``out``."""
    n = 0
    for b in range(len(starts) - 2):
        a0, a1 = starts[b], starts[b + 1]
        b0, b1 = starts[b + 1], starts[b + 2]
        if a1 - a0 < 2 or b1 - b0 < 2:
            continue
        i, j = a0, b0
        while i < a1 - 1 or j < b1 - 1:
            if j == b1 - 1 or (i < a1 - 1 and az[order[i + 1]] < az[order[j + 1]]):
                p, q, r = order[i], order[i + 1], order[j]
                i += 1
            else:
                p, q, r = order[i], order[j], order[j + 1]
                j += 1
            lo = min(az[p], az[q], az[r])
            hi = max(az[p], az[q], az[r])
            if hi - lo > max_step:
                continue
            rlo = min(rng[p], rng[q], rng[r])
            rhi = max(rng[p], rng[q], rng[r])
            if rhi - rlo > max_ratio * rlo:
                continue
            out[n, 0], out[n, 1], out[n, 2] = p, q, r
            n += 1
    return n


def frame_mesh(points, beams, n_beams: int, max_ratio: float = MAX_RATIO,
               max_step_deg: float = MAX_STEP_DEG) -> np.ndarray:
    """``(f, 3) int64``: the triangles of one frame's rings (module docstring); ``points`` in the
    frame's own axes, ``beams`` each point's ring (0 the highest, rings adjacent in elevation
    adjacent in number; -1: not known, left out)."""
    p = np.asarray(points, np.float64)
    b = np.asarray(beams, np.int64)
    if b.shape != (len(p),):
        raise InputValueError(f"beams must be one a point ({len(p)}), got shape {b.shape}")
    az = np.arctan2(p[:, 1], p[:, 0])
    rng = np.linalg.norm(p, axis=1)
    keep = np.flatnonzero((b >= 0) & (b < n_beams))
    order = keep[np.lexsort((az[keep], b[keep]))]
    starts = np.searchsorted(b[order], np.arange(n_beams + 1))
    out = np.empty((2 * len(order) + 4, 3), np.int64)
    n = _zipper(order, starts, az, rng, math.radians(max_step_deg), float(max_ratio), out)
    return out[:n]


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


class MeshFrames:
    """The Embree scenes of frames' meshes in the world frame, one a frame, built once each
    (:meth:`add`) and cast into by every target that holds them (:func:`cast_embree_rays`)."""

    def __init__(self, max_ratio: float = MAX_RATIO, max_step_deg: float | None = None,
                 weak_ratio: float | None = WEAK_RATIO):
        self.max_ratio, self.max_step_deg, self.weak_ratio = max_ratio, max_step_deg, weak_ratio
        self._scenes: dict = {}

    def add(self, key, points, beams, pose, n_beams: int, model: RayModel | None = None, offset: int = 0,
            columns: int | None = None):
        """Frame ``key``'s mesh: ``points`` in its own axes, ``beams`` its rings, ``pose`` its pose;
        ``model``: its lasers' range biases taken out; ``offset``: the union index of its first point;
        ``columns``: its sensor's columns a turn (a triangle's azimuth reach: :data:`MAX_STEP_COLUMNS`;
        without, ``max_step_deg`` or :data:`MAX_STEP_DEG`)."""
        if key not in self._scenes:
            step = self.max_step_deg if self.max_step_deg is not None else \
                MAX_STEP_DEG if not columns else MAX_STEP_COLUMNS * 360.0 / columns
            faces = frame_mesh(points, beams, n_beams, self.max_ratio, step)
            P = np.asarray(pose, np.float64)
            local = _unbiased(points, beams, model)
            world = rotate(local, P[:3, :3]) + P[:3, 3]
            scene = RayScene.triangles(world, faces) if len(faces) else None
            # a raw mesh keeps its vertices' lasers: the cast takes their biases out of its hits
            raw = np.asarray(beams, np.int64) if model is None or model.range_bias is None else None
            weak = None
            if self.weak_ratio is not None and len(faces):
                r = np.linalg.norm(np.asarray(points, np.float64), axis=1)[faces]
                weak = np.ptp(r, axis=1) > self.weak_ratio * r.min(axis=1)
            self._scenes[key] = (scene, faces, raw, weak)
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


def _debias(t, prims, faces, beams, bias):
    """Hits ``t`` on a raw mesh moved back by the mean range bias of their triangle's corners' lasers
    (in place): each corner was read that much long along its own ray, which from a nearby origin is
    nearly the cast ray."""
    hit = np.flatnonzero(prims >= 0)
    b = beams[faces[prims[hit]]]
    ok = (b >= 0) & (b < len(bias))
    t[hit] -= np.where(ok, bias[np.clip(b, 0, len(bias) - 1)], 0.0).mean(axis=1)


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
                     *, surfaces, pose) -> PulseReturns:
    """One return per pulse of ``pattern``: ``model``'s rays (default the pattern's own) from the target at
    ``pose`` (world) cast into ``surfaces`` (``(scene, faces, offset)`` of :meth:`MeshFrames.add`, one a
    frame of the window); ``points`` the union (float64, the target's frame; the return's ``index`` is the
    union point nearest it among its triangle's corners). ``cast_rays``' arguments (module docstring)."""
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
    t, prims = np.full(shape, np.inf), np.full(shape, -1, np.int64)
    ts, ps = np.full(shape, np.inf), np.full(shape, -1, np.int64)  # the first strong hit
    for k, (scene, faces, _, raw, weak) in enumerate(live):
        h = scene.intersect_each(ow, dw, tnear=TNEAR)
        t[:, k], prims[:, k] = h.distances, h.primitives
        ts[:, k], ps[:, k] = h.distances, h.primitives
        if weak is not None:
            _strong(scene, weak, ow, dw, ts[:, k], ps[:, k])
        if raw is not None and model.range_bias is not None:
            _debias(t[:, k], prims[:, k], faces, raw, model.range_bias)
            _debias(ts[:, k], ps[:, k], faces, raw, model.range_bias)
    strong = np.isfinite(ts).any(axis=1)
    t[strong], prims[strong] = ts[strong], ps[strong]
    tt, first = _first_peak(t, gap)
    hitm = np.flatnonzero(np.isfinite(tt))
    tt = tt[hitm]
    L = las[hitm]
    if model.range_bias is not None:
        tt = tt + model.range_bias[L]
    hit = origin[hitm] + tt[:, None] * d[hitm]
    # the union point each return stands for: the nearest corner of the first surface's triangle
    index = np.zeros(len(hitm), np.int64)
    for k, (_, faces, offset, _, _) in enumerate(live):
        m = np.flatnonzero(first[hitm] == k)
        if not len(m):
            continue
        corners = faces[prims[hitm[m], k]] + offset
        dist = np.linalg.norm(pts[corners] - hit[m][:, None, :], axis=2) if len(pts) else np.zeros(corners.shape)
        index[m] = corners[np.arange(len(m)), np.argmin(dist, axis=1)]
    keys, ranges = pattern.pulse_ids(hit, np.zeros(3))
    ok = np.flatnonzero(keys >= 0)
    o = np.lexsort((ok, ranges[ok], keys[ok]))
    kk = keys[ok][o]
    win = ok[o][np.r_[True, kk[1:] != kk[:-1]]] if len(kk) else ok[:0]
    return PulseReturns(keys[win].astype(np.int64), ranges[win], hit[win], index[win])


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
    L = len(model.elevation)
    if len(frames) < 2:
        return model
    casts = []
    for j, (p, beams, pose, motion) in enumerate(frames):
        p = np.asarray(p, np.float64)[::stride]
        lasers = np.asarray(beams, np.int64)[::stride]
        origin = sweep_offsets(p, motion, model.skew)
        origin[:, 2] += model.height[lasers]
        dv = p - origin
        r = np.linalg.norm(dv, axis=1)
        dv /= r[:, None]
        P = np.asarray(pose, np.float64)
        ow, dw = rotate(origin, P[:3, :3]) + P[:3, 3], rotate(dv, P[:3, :3])
        rest = [s for i, s in enumerate(surfaces) if i != j and s[0] is not None]
        hits = [(scene.intersect_each(ow, dw, tnear=TNEAR), faces, raw) for scene, faces, _, raw, _ in rest]
        casts.append((lasers, r, hits))
    bias = np.zeros(L)
    for _ in range(max(1, int(rounds))):
        along_all, laser_all = [], []
        for lasers, r, hits in casts:
            t = np.full((len(r), max(len(hits), 1)), np.inf)
            for k, (h, faces, raw) in enumerate(hits):
                t[:, k] = h.distances
                if raw is not None:
                    _debias(t[:, k], h.primitives, faces, raw, bias)
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
    return dataclasses.replace(model, range_bias=bias)


def frame_beams(frame, base, seq=None):
    """A frame's beams: its ``ring`` field (checked against ``base``, naming the frame and, given its
    sequence ``seq``, its file), else its scan order (KITTI's ``.bin``), else None."""
    ring = frame.attributes.get("ring")
    if ring is not None:
        where = f" ({seq.paths[frame.index]})" if seq is not None else ""
        return ring_beams(ring, base, f"frame {frame.name}{where}")
    return scan_order_beams(frame.points, base.n_beams)


def union_meshes(cache, frames, base, model: RayModel | None = None, drop_moving: bool = True, see_through=None,
                 exclude=(), meshes: MeshFrames | None = None) -> list:
    # model None: raw meshes (the same for every model: reusable across targets), the biases taken out
    # of the hits by cast_embree_rays; a model: its biases taken out of the vertices
    """The surfaces of ``frames`` (sequence indices, in the union's order: ``offset`` of each frame's
    first point in :func:`~slr_ray.sequence.union.accumulate`'s union of them) for
    :func:`cast_embree_rays`: each frame's kept points meshed by its rings (``base``'s beam count), its
    lasers' range biases (``model``) taken out. ``meshes`` keeps them between targets (a frame's
    mesh is built once). A frame whose rings are not known (no ``ring`` field, not in scan order) is
    meshed by the rows of ``base``'s table its points fall in."""
    meshes = meshes if meshes is not None else MeshFrames()
    out, offset = [], 0
    for i in frames:
        f, _ = cache.get(int(i))
        keep, _ = cache.selection(int(i), drop_moving, see_through, exclude)
        pts = cache.own_points(int(i))
        beams = frame_beams(f, base, cache.seq)
        if beams is None and len(pts):  # rings not known: each point's row of the base table
            keys, _ = base.pulse_ids(pts, np.zeros(3))
            beams = np.where(keys >= 0, keys // base.columns, -1)
        if keep is not None:
            pts = pts[keep]
            beams = None if beams is None else beams[keep]
        if beams is None:
            out.append((None, np.zeros((0, 3), np.int64), offset, None, None))
        else:
            bias = None if model is None or model.range_bias is None else model.range_bias.tobytes()
            key = (int(i), bias, len(pts), model.height.tobytes() if bias else None)
            out.append(meshes.add(key, pts, beams, f.pose, base.n_beams, model, offset, base.columns))
        offset += len(pts)
    return out


def fit_embree_model(seq, others, base, cache, meshes: MeshFrames | None = None,
                     drop_moving: bool = True, see_through=None, exclude=()) -> tuple[RayModel, list]:
    """``rays``' sensor fitted on the frames ``others`` (never a held-out one): each laser's line and
    the sweep's skew (:func:`~slr_ray.sequence.rays.fit_ray_model`) on their own points, each laser's
    range bias against the other frames' raw meshes (:func:`mesh_range_bias`); and the frames' raw
    meshes (:func:`union_meshes`, the union's order), which :func:`cast_embree_rays` casts into.
    Frames whose beams are not known are left out of the fit; none known: ``base``'s ideal rays.
    ``meshes`` keeps the frames' meshes between targets (a sliding window builds each once)."""
    surfaces = union_meshes(cache, others, base, None, drop_moving, see_through, exclude, meshes)
    frames, known_surfaces, unknown = [], [], []
    for i, surface in zip(others, surfaces):
        f, _ = cache.get(int(i))
        b = frame_beams(f, base, cache.seq)
        if b is None or not len(f.points):
            unknown.append(seq.names[int(i)])
            continue
        known = b >= 0
        frames.append((f.points[known], b[known], f.pose, frame_motion(seq.poses, int(i))))
        known_surfaces.append(surface)
    if unknown:
        warnings.warn(f"frame(s) {', '.join(unknown)}: beams not known (no ring field, not in {base.name}'s scan "
                      f"order of {base.n_beams} rings): left out of the rays' fit, meshed by the table's rows"
                      + ("" if frames else "; the table's ideal rays cast"), SlrWarning, stacklevel=2)
    if not frames:
        return pattern_ray_model(base), surfaces
    model = fit_ray_model([(p, b, v) for p, b, _, v in frames], base.n_beams)
    return mesh_range_bias(model, frames, known_surfaces), surfaces
