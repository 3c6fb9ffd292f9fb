"""A frame's rings meshed: the surface its own pulses sampled, seen from where they were fired.

Two rings adjacent in elevation are joined by a zipper of triangles (each two
points of one ring and one of the other, in azimuth order), kept where the
triangle spans at most ``max_step`` of azimuth and its ranges from the frame's
origin differ by at most ``max_ratio`` of the nearest; rings farther apart in
elevation than :data:`RATIO_STEP_DEG` may span ratios wider in proportion
(:func:`ratio_widening`). The ``embree-rays`` estimator
(:mod:`slr_ray.sequence.embree_rays`) casts its fitted sensor onto these meshes.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..errors import InputValueError

__all__ = ["frame_mesh", "frame_mesh_spread", "ratio_widening", "open_edge_skirts", "skirt_vertices", "MAX_RATIO", "MAX_STEP_DEG",
           "MAX_STEP_COLUMNS", "WEAK_RATIO", "RATIO_STEP_DEG", "SKIRT_SHARE"]

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
#: rings up to this far apart in elevation (deg) keep MAX_RATIO and WEAK_RATIO; farther, the ratios grow with
#: the step (ratio_widening): every ring pair of the HDL-64E (0.33-0.74 deg, where the ratios were chosen)
#: and the OS1-128 keeps them
RATIO_STEP_DEG = 1.0
#: an open edge of a ring's mesh (a stretch of ring with no strip on one side) is extended this share of the
#: way to the ring next to it in elevation, and a cap this share of a column either side about its points
#: (open_edge_skirts): a ray fired along the ring meets it. On a standing Pandar64 0.05, 0.15 and 0.5 met the
#: same pulses (its rays pass within 0.003 deg of the rings' points); on the KITTI frames 0.5 cost 0.004
#: F@5cm and 0.14 m depth RMSE (the foreground's edges grown into the background), 0.05 nothing
SKIRT_SHARE = 0.1


@njit(cache=True)
def _zipper(order, starts, az, rng, max_step, max_ratio, out, spread, widen):
    """Triangles joining each ring (``order[starts[b]:starts[b+1]]``, by azimuth) to the next;
    returns how many were written into ``out`` (each one's range spread over its nearest in ``spread``:
    the weak rule's measure, made here rather than by a second pass over the faces; both over
    ``widen[b]``, the ring pair's :func:`ratio_widening`)."""
    n = 0
    for b in range(len(starts) - 2):
        w = widen[b]
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
            if rhi - rlo > max_ratio * w * rlo:
                continue
            out[n, 0], out[n, 1], out[n, 2] = p, q, r
            spread[n] = (rhi - rlo) / rlo / w if rlo > 0 else 0.0
            n += 1
    return n


def frame_mesh(points, beams, n_beams: int, max_ratio: float = MAX_RATIO,
               max_step_deg: float = MAX_STEP_DEG) -> np.ndarray:
    """``(f, 3) int64``: the triangles of one frame's rings (module docstring); ``points`` in the
    frame's own axes, ``beams`` each point's ring (0 the highest, rings adjacent in elevation
    adjacent in number; -1: not known, left out)."""
    return frame_mesh_spread(points, beams, n_beams, max_ratio, max_step_deg)[0]


def frame_mesh_spread(points, beams, n_beams, max_ratio, max_step_deg):
    """:func:`frame_mesh`'s faces and each one's range spread over its nearest range."""
    p = np.asarray(points, np.float64)
    b = np.asarray(beams, np.int64)
    if b.shape != (len(p),):
        raise InputValueError(f"beams must be one a point ({len(p)}), got shape {b.shape}")
    az = np.arctan2(p[:, 1], p[:, 0])
    rng = np.sqrt(p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1] + p[:, 2] * p[:, 2])  # np.linalg.norm's sum, 3x faster
    keep = np.flatnonzero((b >= 0) & (b < n_beams))
    order, starts = _ring_order(keep, b, az, n_beams)
    out = np.empty((2 * len(order) + 4, 3), np.int64)
    spread = np.empty(len(out))
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    n = _zipper(order, starts, az, rng, math.radians(max_step_deg), float(max_ratio), out, spread,
                _widening(el, order, starts, n_beams))
    return out[:n], spread[:n]


def ratio_widening(points, rows, n_rows: int) -> np.ndarray:
    """``(n_rows,)``: how much wider the range ratio of a triangle between ring ``b`` and ring ``b + 1``
    may be (:data:`MAX_RATIO`, :data:`WEAK_RATIO` times it): the rings' elevation step (their points'
    median elevations from the frame's origin) over :data:`RATIO_STEP_DEG`, at least 1. A plane seen at
    a grazing angle ``a`` from rays ``s`` apart has ranges ``s / a`` apart, so the ratio a surface may
    span grows with the step: the road between a Pandar64's lowest lasers, 5-6 deg apart (ranges 5.1,
    6.6 and 9.0 m: ratios 0.29, 0.36), was left unmeshed and their pulses missed."""
    p = np.asarray(points, np.float64)
    r = np.asarray(rows, np.int64)
    out = np.ones(max(int(n_rows), 1))
    if not len(r) or n_rows < 2:
        return out
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    keep = np.flatnonzero((r >= 0) & (r < n_rows))
    o = keep[np.argsort(r[keep], kind="stable")]
    return _widening(el, o, np.searchsorted(r[o], np.arange(n_rows + 1)), n_rows)


def _ring_elevations(el, order, starts, n_rows: int) -> np.ndarray:
    """Each ring's median elevation (``el`` grouped by ``order[starts[b]:starts[b+1]]``; NaN: no point): its
    sorted elevations' middle element (``n // 2``), found by a partial sort of the ring alone."""
    med = np.full(max(int(n_rows), 0), np.nan)
    for k in range(n_rows):
        lo, hi = starts[k], starts[k + 1]
        if hi > lo:
            ring = el[order[lo:hi]]
            med[k] = np.partition(ring, (hi - lo) // 2)[(hi - lo) // 2]
    return med


def _widening(el, order, starts, n_rows: int) -> np.ndarray:
    """:func:`ratio_widening` of the points' elevations ``el`` (deg) grouped by ring (``order[starts[b]:
    starts[b+1]]`` ring ``b``'s, in any order): each ring's median elevation (:func:`_ring_elevations`)."""
    out = np.ones(max(int(n_rows), 1))
    if n_rows < 2:
        return out
    med = _ring_elevations(el, order, starts, n_rows)
    step = np.abs(med[:-1] - med[1:])
    out[:-1] = np.where(np.isfinite(step), np.maximum(step / RATIO_STEP_DEG, 1.0), 1.0)
    return out


def _ring_order(keep, b, az, n_beams):
    """The points ``keep`` by ring ``b``, then azimuth ``az`` (``np.lexsort((az, b))``'s order: equals in
    the order of ``keep``), and where each ring starts: a radix sort of the rings, then each ring's
    (a scan's ring is two runs of azimuth: the stable sort's merge finds them)."""
    if n_beams >= 1 << 15:
        order = keep[np.lexsort((az[keep], b[keep]))]
        return order, np.searchsorted(b[order], np.arange(n_beams + 1))
    order = keep[np.argsort(b[keep].astype(np.int16), kind="stable")]
    starts = np.searchsorted(b[order], np.arange(n_beams + 1))
    for lo, hi in zip(starts[:-1], starts[1:]):
        if hi - lo > 1:
            ring = order[lo:hi]
            order[lo:hi] = ring[np.argsort(az[ring], kind="stable")]
    return order, starts


def open_edge_skirts(points, rows, n_rows: int, faces, max_ratio: float = MAX_RATIO,
                     max_step_deg: float = MAX_STEP_DEG, share: float = SKIRT_SHARE):
    """The open edges of a frame's ring mesh (``faces`` of :func:`frame_mesh`, ``rows`` each point's ring
    in elevation order, 0 the highest) closed: each stretch of ring between two points next in azimuth
    (within ``max_step_deg``, ranges within ``max_ratio`` of the nearer) that no triangle joins to the ring
    above (below) gets a *skirt*, a quad turned up (down) about the frame's origin by ``share`` of the
    elevation step to that ring (the rings' median elevations; the outermost rings' the step to their one
    neighbour); each point of an open edge, and each where its ring's run ends in azimuth (a lone point, the
    end of a thin object), a *cap*, a quad about it ``share`` of a column either side (``max_step_deg`` over
    :data:`MAX_STEP_COLUMNS`) and ``share`` of the steps to the rings above and below high. Returns
    ``(parents, shifts, faces, spread)``: the new vertices each a point ``parents`` turned by ``shifts``
    (rad, elevation and azimuth: :func:`skirt_vertices`), the triangles (indexing the points, then the new
    vertices), and each one's range spread over its nearest (:func:`frame_mesh_spread`'s; a cap's 0).

    A ray fired along a ring, as a standing unit's next scan fires it, runs through the ring's points: where
    the ring is a mesh's edge (the far end of a surface, a thin object one ring met, the lowest ring) it
    grazes the edge and meets it or not by rounding (a Pandar64's rays pass within 0.001 deg of the ring's
    points and missed 2-4 % of its pulses, most of them 50-120 m off)."""
    p = np.asarray(points, np.float64)
    r_ = np.asarray(rows, np.int64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    if not share > 0 or n_rows < 1 or not len(p):
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros(0)
    az = np.arctan2(p[:, 1], p[:, 0])
    rng = np.sqrt(p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1] + p[:, 2] * p[:, 2])
    keep = np.flatnonzero((r_ >= 0) & (r_ < n_rows))
    order, starts = _ring_order(keep, r_, az, n_rows)
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    column = max_step_deg / MAX_STEP_COLUMNS
    half = _half_steps(_ring_elevations(el, order, starts, n_rows), share, column)  # (n_rows, 2): up, down (rad)
    # each stretch of ring: two points next in azimuth on one ring, close in azimuth and range
    a, b = order[:-1], order[1:]
    lo, hi = np.minimum(rng[a], rng[b]), np.maximum(rng[a], rng[b])
    seg = (r_[a] == r_[b]) & (az[b] - az[a] <= math.radians(max_step_deg)) & (hi - lo <= max_ratio * lo)
    a, b, spread = a[seg], b[seg], ((hi - lo) / np.maximum(lo, 1e-12))[seg]
    n, parts = len(p), []
    pos = np.full(n, -1, np.int64)
    pos[order] = np.arange(len(order))
    for side in (0, 1):  # 0: the ring above (a lower row), 1: below
        open_ = ~_covered_edges(f, r_, 2 * side - 1, pos)[a] & (half[r_[a], side] != 0)
        sa, sb, t = a[open_], b[open_], half[r_[a[open_]], side]
        parts.append(((sa, sb, sb, sa), (0 * t, 0 * t, t, t), (0 * t,) * 4, spread[open_], None))
    # a cap about each point on an open edge (a ray through the point meets its inside, not a corner) and
    # each where its ring's run ends (no stretch beyond it in azimuth: a lone point, a thin object's end)
    right, left, mark = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    right[a], left[b] = True, True
    mark[keep] = ~(right[keep] & left[keep])  # not joined on both sides: a run's end
    for q in parts:
        mark[q[0][0]] = mark[q[0][1]] = True
    end = np.flatnonzero(mark)
    up, dn = half[r_[end], 0], half[r_[end], 1]
    col = math.radians(share * column) + 0 * up
    parts.append(((end,) * 4, (up, dn, dn, up), (-col, -col, col, col), 0 * up, end))
    return _quads(parts, n)


def _half_steps(med, share: float, lone: float) -> np.ndarray:
    """``(n_rows, 2)``: ``share`` of each ring's elevation step (rad; ``med`` the rings' median elevations,
    deg, a ring with no point between the rings beside it) to the ring above (positive) and below
    (negative), the step to its one neighbour where it has one ring beside it only; ``lone`` (deg) where
    the frame has one ring."""
    have = np.flatnonzero(np.isfinite(med))
    if len(have) < 2:
        return np.radians(share * np.column_stack([np.full(len(med), lone), np.full(len(med), -lone)]))
    med = np.where(np.isfinite(med), med, np.interp(np.arange(len(med)), have, med[have]))
    up = np.concatenate([[np.nan], med[:-1] - med[1:]])
    dn = np.concatenate([med[1:] - med[:-1], [np.nan]])
    up, dn = np.where(np.isfinite(up), up, -dn), np.where(np.isfinite(dn), dn, -up)
    return np.radians(share * np.nan_to_num(np.column_stack([up, dn])))


def _quads(parts, n: int):
    """:func:`open_edge_skirts`' quads (``parts``: each ``(corners, elevation turns, azimuth turns, spread,
    centres)``, four corners of one quad a column, in order round it) as new vertices and two triangles
    each, or, given ``centres`` (points), four: a fan about the point (a flat quad about it would pass
    ``r (1 - cos a)`` in front of it)."""
    parents, shifts, tri, sp, m = [], [], [], [], n
    for corners, de, da, s, centre in parts:
        k = len(s)
        parents += list(corners)
        shifts += [np.column_stack([e, z]) for e, z in zip(de, da)]
        v = m + np.arange(4)[None, :] * k + np.arange(k)[:, None]  # the quad's four new vertices
        if centre is None:
            tri += [v[:, [0, 1, 2]], v[:, [0, 2, 3]]]
            sp += [s, s]
        else:
            tri += [np.column_stack([centre, v[:, i], v[:, (i + 1) % 4]]) for i in range(4)]
            sp += [s] * 4
        m += 4 * k
    return (np.concatenate(parents).astype(np.int64), np.concatenate(shifts), np.concatenate(tri).astype(np.int64),
            np.concatenate(sp).astype(np.float64))


def _covered_edges(faces, rows, side: int, pos) -> np.ndarray:
    """``(n,) bool``: whether the stretch of ring from each point to the next in its ring's azimuth order
    (``pos`` each point's place in that order) is joined by a triangle of ``faces`` to the ring ``side`` of
    theirs (-1 above, 1 below): a zipper's triangle holds two points next in one ring."""
    out = np.zeros(len(pos), bool)
    if not len(faces):
        return out
    fr = rows[faces]
    for i, j, k in ((0, 1, 2), (1, 2, 0), (0, 2, 1)):
        m = (fr[:, i] == fr[:, j]) & (np.sign(fr[:, k] - fr[:, i]) == side)
        u, v = faces[m, i], faces[m, j]
        out[np.where(pos[u] < pos[v], u, v)] = True
    return out


def skirt_vertices(points, parents, shifts) -> np.ndarray:
    """``(m, 3)``: the points ``parents`` of ``points`` turned ``shifts`` (rad: ``(m, 2)`` elevation and
    azimuth) about the origin, their ranges kept: :func:`open_edge_skirts`' new vertices."""
    p = np.asarray(points, np.float64)[np.asarray(parents, np.int64)]
    t = np.asarray(shifts, np.float64).reshape(-1, 2)
    h = np.hypot(p[:, 0], p[:, 1])
    r = np.sqrt(h * h + p[:, 2] * p[:, 2])
    e = np.arctan2(p[:, 2], h) + t[:, 0]
    az = np.arctan2(p[:, 1], p[:, 0]) + t[:, 1]
    return np.column_stack([r * np.cos(e) * np.cos(az), r * np.cos(e) * np.sin(az), r * np.sin(e)])
