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

__all__ = ["frame_mesh", "frame_mesh_spread", "ratio_widening", "MAX_RATIO", "MAX_STEP_DEG", "MAX_STEP_COLUMNS",
           "WEAK_RATIO", "RATIO_STEP_DEG"]

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


def _widening(el, order, starts, n_rows: int) -> np.ndarray:
    """:func:`ratio_widening` of the points' elevations ``el`` (deg) grouped by ring (``order[starts[b]:
    starts[b+1]]`` ring ``b``'s, in any order): each ring's median is its sorted elevations' middle
    element (``n // 2``), found by a partial sort of the ring alone."""
    out = np.ones(max(int(n_rows), 1))
    if n_rows < 2:
        return out
    med = np.full(n_rows, np.nan)
    for k in range(n_rows):
        lo, hi = starts[k], starts[k + 1]
        if hi > lo:
            ring = el[order[lo:hi]]
            med[k] = np.partition(ring, (hi - lo) // 2)[(hi - lo) // 2]
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
