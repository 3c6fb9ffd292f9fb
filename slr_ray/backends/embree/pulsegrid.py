"""Neighbours from the primary scan's own pulse grid (``neighbours='pulse-grid'``).

A point's neighbours are the points of the 8 pulses adjacent to its own in
the primary's pattern (the exact pulse keys of :mod:`slr_ray.core`),
range-gated; one sort and one linear pass, no kd-tree
(:func:`grid_neighbourhoods`), or spacing and normals fused into that pass
with no neighbour arrays (:func:`pulse_grid_spacing_normals`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ...arrays import as_origin
from ...errors import InputValueError
from ...pattern import as_pattern
from ...raycast import padded_rows, silhouette_bit
from ...threads import default_threads
from .discs import fallback_directions, pca_normal, primary_steps, turned
from .options import GRID_SPACINGS

__all__ = ["grid_neighbourhoods", "pulse_grid_spacing_normals", "grid_gate", "sorted_pulse_grid"]


def grid_neighbourhoods(points, primary_origin, primary_resolution, gate: float | None = None, chunk: int = 1 << 20,
                        layout: str = "auto", beams=None):
    """Neighbours of every point of a primary scan from its own pulse grid.

    The points are binned into the pulses of a ``primary_resolution`` pattern
    (degrees, or the primary's own pattern: anything
    :func:`~slr_ray.pattern.as_pattern` takes, a beam table included) at
    ``primary_origin`` (the binning backend's exact bins); a point's
    neighbours are the points of the 8 adjacent pulses (azimuth wrapping)
    whose primary range is within ``gate`` times its own (default
    :func:`grid_gate`), at most one per
    pulse (the nearest to the scanner, then the lowest index). No kd-tree: one
    sort of the pulse keys, then a linear walk along each zenith row with a
    pointer into the rows above and below (O(n) after the sort); for a cloud
    stored column by column (as TLS scanners record), along each azimuth
    column instead (``layout``: ``"auto"``, ``"rows"``, ``"columns"``; the
    neighbours do not depend on it). ``beams`` (optional, a beam table's
    primary): the beam that fired each point (-1 unknown), which sets its row
    instead of its elevation.

    Yields ``(members (c,), distances (c, 8), indices (c, 8), counts (c,))``
    chunk by chunk: ``members`` are the indices of the chunk's points (whole
    rows or columns, about ``chunk`` points, in pulse order; points outside
    the pattern come first, with no neighbours). Missing neighbours are the point
    itself at distance 0 (``counts`` says how many are real). Memory: three
    ``(n,)`` arrays and one chunk's ``(c, 8)`` arrays.
    """
    pts = np.ascontiguousarray(points)  # one layout: _grid_rows compiles once
    n = len(pts)
    if n == 0:
        return
    ranges, sorted_keys, order, row_start, line_len, transposed = sorted_pulse_grid(
        pts, as_origin(primary_origin, "primary_origin"), primary_resolution, layout, beams)
    nv = len(row_start) - 1  # lines: zenith rows, or azimuth columns for a column-ordered cloud
    unseen = int(row_start[0])
    if unseen:
        members = order[:unseen]
        yield (members, np.zeros((unseen, 8)), np.repeat(members[:, None], 8, axis=1),
               np.zeros(unseen, np.int64))
    v0 = 0
    while v0 < nv:
        # whole rows, at least one, about `chunk` points
        v1 = max(v0 + 1, int(np.searchsorted(row_start, row_start[v0] + chunk, side="right")) - 1)
        v1 = min(v1, nv)
        a, b = int(row_start[v0]), int(row_start[v1])
        if b > a:
            idx = np.empty((b - a, 8), np.int64)
            dist = np.empty((b - a, 8))
            counts = np.empty(b - a, np.int64)
            _grid_rows(pts, ranges, sorted_keys, order, row_start, _row_tasks(row_start, v0, v1), line_len,
                       transposed, grid_gate(primary_resolution, gate), idx, dist, counts)
            yield order[a:b], dist, idx, counts
        v0 = v1


#: incidence beyond which a surface's range steps count as an edge (the default range gate)
_GATE_INCIDENCE_DEG = 89.0


def grid_gate(primary, gate: float | None = None) -> float:
    """The pulse grid's range gate: ``gate`` if given, else the relative range
    step between adjacent pulses of a surface seen at 89 deg incidence
    (``tan(89 deg)`` times the primary's larger pulse step, radians), at most
    0.1. ``primary``: degrees or a pattern."""
    if gate is not None:
        return float(gate)
    return min(0.1, math.tan(math.radians(_GATE_INCIDENCE_DEG)) * max(primary_steps(primary)))


def sorted_pulse_grid(pts, origin, primary_resolution, layout: str = "auto", beams=None):
    """The pulse keys of a primary's points, sorted line by line.

    Lines are zenith rows (key ``v * n_azimuth + h``), or azimuth columns
    (key ``h * n_zenith + v``) when the cloud is stored column by column, as
    a TLS scanner records it: the sort is then nearly free and the walk reads
    memory in order (``layout``: ``"auto"`` picks the order in which more
    consecutive points have non-decreasing keys; ``"rows"``, ``"columns"``).
    Returns ``(ranges, sorted_keys, order, line_start (lines + 1,),
    line_len, transposed)``; points outside the pattern sort first.

    A beam table's columns are taken in absolute azimuth (its per-beam
    azimuth offsets set to 0): a beam fires ``offset`` degrees off the
    column's azimuth, so column ``h`` of two adjacent beams can lie degrees
    apart (up to 8 deg between an HDL-64E's beams), and the pulses adjacent
    in space are the ones adjacent in absolute azimuth. ``beams`` (a beam
    table's primary only): each point's beam, which then sets its row
    (:meth:`~slr_ray.sensors.BeamPattern.pulse_ids`).
    """
    pattern = _grid_pattern(primary_resolution)
    if beams is None:
        keys, ranges = pattern.pulse_ids(pts, origin)
    elif not pattern.has_beams:
        raise InputValueError("beams (a point's beam id) need a beam-table primary (primary_pattern), "
                              "not degrees")
    else:
        keys, ranges = pattern.pulse_ids(pts, origin, beams)
    nv, nh = pattern.n_zenith, pattern.n_azimuth
    if layout == "auto":
        rows_up, cols_up = _runs(keys, nv, nh)
        transposed = cols_up > rows_up
    elif layout in ("rows", "columns"):
        transposed = layout == "columns"
    else:
        raise InputValueError(f"layout must be 'auto', 'rows' or 'columns', got {layout!r}")
    if transposed:
        _transpose_keys(keys, nv, nh)
    lines, line_len = (nh, nv) if transposed else (nv, nh)
    # a counting sort by line, then each line sorted on its own (in parallel): the order
    # of a stable argsort of the keys, 3-4x faster on a 58 M-point primary
    order, sorted_keys, line_start = _line_sort(keys, line_len, lines)
    del keys
    _require_a_scan(sorted_keys, int(line_start[0]), origin, primary_resolution)
    return ranges, sorted_keys, order, line_start, line_len, transposed


#: A primary holds about one point a pulse of its own pattern (real frames and scans: 1.09-1.37 points
#: an occupied pulse, a KITTI frame in its HDL-64E table, the forest scan in its fitted grid); more than
#: this many a pulse (on average, over :data:`MIN_POINTS_CHECKED` points and more) is no scan from the
#: primary's origin with its pattern, and is refused: a far origin puts a whole cloud in a few pulses
#: and the discs, sized from pulses metres wide, grow to tens of metres (8,000 points seen from 1 km:
#: 667 a pulse, radii 40-80 m, and each ray met thousands of discs: a cast of minutes)
MAX_POINTS_PER_PULSE = 8.0
#: clouds with fewer points in the pattern than this are not checked (their cast is short whatever the discs)
MIN_POINTS_CHECKED = 1000


@njit(cache=True)
def _occupied(sorted_keys, start):
    """How many distinct keys ``sorted_keys[start:]`` holds (sorted within each line, lines apart)."""
    count = 0
    for i in range(start, sorted_keys.shape[0]):
        if i == start or sorted_keys[i] != sorted_keys[i - 1]:
            count += 1
    return count


def _require_a_scan(sorted_keys, unseen: int, origin, primary) -> None:
    """Refuse a primary whose points crowd its pulses (:data:`MAX_POINTS_PER_PULSE`)."""
    seen = len(sorted_keys) - unseen
    if seen < MIN_POINTS_CHECKED:
        return
    occupied = _occupied(sorted_keys, unseen)
    if seen > MAX_POINTS_PER_PULSE * occupied:
        o = ", ".join(f"{v:g}" for v in np.asarray(origin, np.float64))
        raise InputValueError(
            f"primary_origin ({o}): the cloud is no scan from there with the primary's pattern: its {seen:,} points "
            f"in the pattern fall in {occupied:,} pulses, {seen / occupied:.0f} a pulse (a scan holds about one; more "
            f"than {MAX_POINTS_PER_PULSE:g} is refused: discs sized from those pulses would span metres and the cast "
            "would grow with the square of the points); give the primary scanner's own position and pattern, or "
            "leave them out (kNN discs)", flags={"primary_origin": "--primary-origin"})


def require_a_scan_from(points, origin, primary) -> None:
    """Refuse ``points`` as a scan from ``origin`` with ``primary`` (degrees or a pattern) when they crowd
    its pulses (:data:`MAX_POINTS_PER_PULSE`): the check of the pulse-grid path, for the paths that size
    discs from the primary without its grid (``radius='footprint'``: a disc as wide as its pulse at its
    range, a whole pulse of points under each)."""
    pts = np.ascontiguousarray(points, np.float64)
    if len(pts) < MIN_POINTS_CHECKED:
        return
    keys, _ = _grid_pattern(primary).pulse_ids(pts, origin)
    keys = np.sort(keys[keys >= 0])
    _require_a_scan(keys, 0, origin, primary)


def _grid_pattern(primary):
    """The pattern whose pulses make the pulse grid: ``primary`` (degrees or a
    pattern) as a pattern, a beam table's per-beam azimuth offsets set to 0."""
    return as_pattern(primary).aligned()


@njit(cache=True)
def _line_counting_sort(keys, line_len, lines, order, bucket):
    """Indices of ``keys`` grouped by line (``key // line_len``; negative keys first),
    each group in index order; returns ``line_start`` (lines + 1,) past the unseen."""
    counts = np.zeros(lines + 2, np.int64)
    for i in range(keys.shape[0]):
        k = keys[i]
        b = 0 if k < 0 else k // line_len + 1
        bucket[i] = b
        counts[b + 1] += 1
    for b in range(lines + 1):
        counts[b + 1] += counts[b]
    start = counts[1:].copy()  # line_start: where line 0 begins is after the unseen points
    fill = counts[:-1].copy()
    for i in range(keys.shape[0]):
        b = bucket[i]
        order[fill[b]] = i
        fill[b] += 1
    return start


@njit(cache=True, parallel=True)
def _sort_lines(keys, order, line_start, sorted_keys):
    """Within each line, order by key (stable: equal keys keep index order)."""
    n0 = line_start[0]
    for j in range(n0):
        sorted_keys[j] = keys[order[j]]
    for v in prange(line_start.shape[0] - 1):
        a, b = line_start[v], line_start[v + 1]
        if b - a == 0:
            continue
        seg = np.empty(b - a, np.int64)
        ordered = True
        for j in range(a, b):
            seg[j - a] = keys[order[j]]
            if j > a and seg[j - a] < seg[j - a - 1]:
                ordered = False
        if not ordered:
            perm = np.argsort(seg, kind="mergesort")
            idx = order[a:b].copy()
            for j in range(b - a):
                order[a + j] = idx[perm[j]]
                sorted_keys[a + j] = seg[perm[j]]
        else:
            for j in range(b - a):
                sorted_keys[a + j] = seg[j]


def _line_sort(keys, line_len, lines):
    n = len(keys)
    order = np.empty(n, np.int64)
    bucket = np.empty(n, np.int32 if lines < 2**31 - 2 else np.int64)
    line_start = _line_counting_sort(keys, line_len, lines, order, bucket)
    del bucket
    sorted_keys = np.empty(n, np.int64)
    _sort_lines(keys, order, line_start, sorted_keys)
    return order, sorted_keys, line_start


@njit(cache=True)
def _runs(keys, nv, nh):
    """How many consecutive pairs of seen points have non-decreasing row-major
    keys, and how many non-decreasing column-major keys."""
    rows = cols = 0
    prev = -1
    for i in range(keys.shape[0]):
        k = keys[i]
        if k < 0:
            continue
        if prev >= 0:
            rows += k >= prev
            cols += (k % nh) * nv + k // nh >= (prev % nh) * nv + prev // nh
        prev = k
    return rows, cols


@njit(cache=True, parallel=True)
def _transpose_keys(keys, nv, nh):
    for i in prange(keys.shape[0]):
        k = keys[i]
        if k >= 0:
            keys[i] = (k % nh) * nv + k // nh


@njit(cache=True, inline="always")
def _offer(slot, q, ranges, ri, gate, best, near):
    """Keep ``q`` in ``best[slot]`` if within the range gate and nearer the scanner
    (candidates come in index order within a pulse: ties keep the lowest index);
    ``near[slot]``: the least range of any point of the pulse, gated or not."""
    if ranges[q] < near[slot]:
        near[slot] = ranges[q]
    if abs(ranges[q] - ri) <= gate * ri and (best[slot] < 0 or ranges[q] < ranges[best[slot]]):
        best[slot] = q


@njit(cache=True, inline="always")
def _line(row_start, line, off, transposed):
    """Line ``line + off``, or -1 where there is none (columns wrap in azimuth)."""
    n = row_start.shape[0] - 1
    rr = line + off
    if transposed and n >= 3:
        return (rr + n) % n
    return rr if 0 <= rr < n else -1


@njit(cache=True, inline="always")
def _pulse_neighbours(sk, order, ranges, row_start, ptr, line, pos, ri, gate, line_len, transposed, best, near):
    """Fill ``best[slot]`` (-1: none) with the neighbour in each of the 8 pulses
    around the pulse at ``pos`` of line ``line``; slot ``(dv + 1) * 3 + dh + 1``
    (4 is the pulse itself), the output order of a (dv, dh) double loop,
    whichever way the lines run. Lines are zenith rows (azimuth wraps within
    a line) or, ``transposed``, azimuth columns (the lines wrap). ``ptr[t]``:
    a position in line ``line + t - 1`` at or before ``pos - 1``; called with
    non-decreasing ``pos`` along a line, the pointers only move forward."""
    best[:] = -1
    near[:] = np.inf
    for t in range(3):
        rr = _line(row_start, line, t - 1, transposed)
        if rr < 0:
            continue
        end = row_start[rr + 1]
        row0 = rr * line_len
        while ptr[t] < end and sk[ptr[t]] < row0 + pos - 1:
            ptr[t] += 1
        q = ptr[t]
        while q < end and sk[q] <= row0 + pos + 1:
            dw = sk[q] - row0 - pos
            if not (t == 1 and dw == 0):
                _offer((dw + 1) * 3 + t if transposed else t * 3 + dw + 1, order[q], ranges, ri, gate, best, near)
            q += 1
        if not transposed and line_len >= 3 and pos == 0:  # azimuth wrap: the row's last pulse is h - 1
            q = end - 1
            while q >= row_start[rr] and sk[q] == row0 + line_len - 1:
                q -= 1
            for q2 in range(q + 1, end):  # forward, so ties keep the lowest index
                _offer(t * 3, order[q2], ranges, ri, gate, best, near)
        if not transposed and line_len >= 3 and pos == line_len - 1:  # and its first pulse is h + 1
            q = row_start[rr]
            while q < end and sk[q] == row0:
                _offer(t * 3 + 2, order[q], ranges, ri, gate, best, near)
                q += 1


def _row_tasks(row_start, v0, v1, tasks_per_thread: int = 8):
    """Split rows ``v0 .. v1`` into runs of about equal point counts, a few per
    thread (a prange over the rows themselves would give one thread every
    occupied row when the cloud covers part of the zenith range)."""
    a, b = int(row_start[v0]), int(row_start[v1])
    k = max(1, min(v1 - v0, default_threads() * tasks_per_thread))
    cuts = np.searchsorted(row_start[v0:v1 + 1], np.linspace(a, b, k + 1)[1:-1]) + v0
    return np.unique(np.concatenate([[v0], cuts, [v1]])).astype(np.int64)


@njit(cache=True, inline="always")
def _row_pointers(row_start, line, transposed):
    ptr = np.empty(3, np.int64)
    for t in range(3):
        rr = _line(row_start, line, t - 1, transposed)
        ptr[t] = row_start[rr] if rr >= 0 else 0
    return ptr


@njit(cache=True, inline="always")
def _point_neighbours(pts, sk, order, ranges, row_start, ptr, v, j, gate, line_len, transposed, best, nbr, dist,
                      near):
    """The neighbours of the point at sorted position ``j`` of line ``v``:
    their indices and distances in ``nbr[:m]``, ``dist[:m]`` (slot order),
    the rest of the 8 padded with the point itself at distance 0; returns ``m``."""
    i = order[j]
    _pulse_neighbours(sk, order, ranges, row_start, ptr, v, sk[j] - v * line_len, ranges[i], gate, line_len,
                      transposed, best, near)
    m = 0
    for slot in range(9):
        q = best[slot]
        if q >= 0:
            nbr[m] = q
            dx = pts[q, 0] - pts[i, 0]
            dy = pts[q, 1] - pts[i, 1]
            dz = pts[q, 2] - pts[i, 2]
            dist[m] = math.sqrt(dx * dx + dy * dy + dz * dz)
            m += 1
    for t in range(m, 8):
        nbr[t] = i
        dist[t] = 0.0
    return m


@njit(cache=True, parallel=True)
def _grid_rows(pts, ranges, sk, order, row_start, tasks, line_len, transposed, gate, idx, dist, counts):
    """Pulse-grid neighbours of the points of rows ``tasks[0] .. tasks[-1]``
    (see :func:`grid_neighbourhoods`): each task walks its rows linearly."""
    base = row_start[tasks[0]]
    for task in prange(len(tasks) - 1):
        best = np.empty(9, np.int64)
        near = np.empty(9)
        for v in range(tasks[task], tasks[task + 1]):
            ptr = _row_pointers(row_start, v, transposed)
            for j in range(row_start[v], row_start[v + 1]):
                c = j - base
                counts[c] = _point_neighbours(pts, sk, order, ranges, row_start, ptr, v, j, gate, line_len,
                                              transposed, best, idx[c], dist[c], near)


def pulse_grid_spacing_normals(points, primary_origin, primary_resolution, gate: float | None = None,
                               spacing: bool = True, normals: bool = True, dtype=np.float64,
                               layout: str = "auto", max_incidence: float = 90.0, beams=None, spacing_kind: str = "mean",
                               silhouette=None):
    """Mean neighbour spacing ``(n,)`` and PCA normals ``(n, 3)`` of a primary
    scan from its pulse grid, in one pass and without neighbour arrays.

    The same neighbours as :func:`grid_neighbourhoods` and the same normals as
    :func:`estimate_normals` would compute from them (missing neighbours count
    as the point itself); memory is the outputs and three ``(n,)`` arrays.
    Points outside the pattern, or with no neighbour, get spacing 0 (the disc
    radius floor applies) and the direction to the primary scanner.
    ``primary_resolution``: degrees, or the primary's own pattern (as in
    :func:`grid_neighbourhoods`). Either
    output is ``None`` when not asked for; ``dtype`` is the normals' (float32
    for Embree halves their memory); ``layout``: see :func:`sorted_pulse_grid`
    (the answer does not depend on it, only the speed); ``max_incidence``
    (degrees): normals turned as they are made to meet the line of sight to
    the primary at no more than this (:class:`EmbreeOptions`; 90: not turned);
    ``beams``: each point's beam, as in :func:`grid_neighbourhoods`;
    ``spacing_kind``: ``"mean"`` (the mean distance to the neighbours) or
    ``"step"`` (twice the smaller of the distances to the nearer neighbour
    along the grid's two axes: the nearer of the points of the pulses above
    and below, the nearer of those left and right; grazing ground is spaced
    by its small azimuth step, not its long range step; and at least 1.5
    times the range times the coarser of the pattern's two angular steps, so
    that a pattern of oblong pulses, 0.048 x 0.622 deg, is spaced by its
    long side, not twice its short one (no change on square pulses: twice
    the step seen head-on is more); :class:`EmbreeOptions` ``grid_spacing``).
    ``silhouette``: an ``(n,)`` uint8 array filled with each point's
    silhouette bits (:func:`silhouette_bit`): bit ``b`` set where the adjacent
    pulse ``b`` of the primary holds returns, none within the range gate and
    none nearer (its return lies behind: the point is at a silhouette there);
    empty pulses (lost pulses, sky, cells narrower than the noise near the
    poles) and pulses beyond the pattern's rows set none. Not computed with
    ``beams`` (the bits are read against elevation bands; left 0).
    """
    pts = np.ascontiguousarray(points, np.float64)
    n = len(pts)
    o = as_origin(primary_origin, "primary_origin")
    code = _spacing_code(spacing_kind)
    clip = np.zeros(0, np.uint8) if silhouette is None or beams is not None else silhouette
    if silhouette is not None:
        silhouette[:] = 0
    sp = np.zeros(n) if spacing else np.empty(0)
    # spare rows after the normals: Embree shares float32 ones instead of copying them
    nr = padded_rows(n, dtype) if normals else np.empty((0, 3), dtype)
    if n:
        ranges, sorted_keys, order, line_start, line_len, transposed = sorted_pulse_grid(
            pts, o, primary_resolution, layout, beams)
        if normals and line_start[0]:  # points outside the pattern: the direction to the scanner
            unseen = order[:line_start[0]]
            nr[unseen] = fallback_directions(pts[unseen], o, dtype)
        _grid_fused(pts, ranges, sorted_keys, order, line_start, _row_tasks(line_start, 0, len(line_start) - 1),
                    line_len, transposed, grid_gate(primary_resolution, gate), o, spacing, normals, sp, nr,
                    math.cos(math.radians(max_incidence)) if max_incidence < 90 else 0.0, code, clip,
                    _grid_pattern(primary_resolution).shape[0], *primary_steps(primary_resolution))
    return (sp if spacing else None), (nr if normals else None)


@njit(cache=True, parallel=True)
def _grid_fused(pts, ranges, sk, order, row_start, tasks, line_len, transposed, gate, po, want_spacing, want_normals,
                sp, nr, cos_min, step, clip, n_rows, d_theta, d_phi):
    sin_min = math.sqrt(max(0.0, 1.0 - cos_min * cos_min))
    want_clip = clip.shape[0] > 0
    for task in prange(len(tasks) - 1):
        best = np.empty(9, np.int64)
        near = np.empty(9)
        nbr = np.empty(8, np.int64)
        dist = np.empty(8)
        for v in range(tasks[task], tasks[task + 1]):
            ptr = _row_pointers(row_start, v, transposed)
            for j in range(row_start[v], row_start[v + 1]):
                i = order[j]
                m = _point_neighbours(pts, sk, order, ranges, row_start, ptr, v, j, gate, line_len, transposed,
                                      best, nbr, dist, near)
                if want_clip:
                    row = sk[j] - v * line_len if transposed else v
                    bits = 0
                    for slot in range(9):
                        rr = row + slot // 3 - 1
                        if slot != 4 and 0 <= rr < n_rows and best[slot] < 0 and ranges[i] < near[slot] < np.inf:
                            bits |= 1 << silhouette_bit(slot)
                    clip[i] = bits
                if want_spacing and m:
                    if step == 0:
                        sp[i] = dist[:m].sum() / m
                    else:
                        # the pulse's longer side seen head-on: R times the coarser angular step
                        dx, dy = pts[i, 0] - po[0], pts[i, 1] - po[1]
                        rho = math.sqrt(dx * dx + dy * dy)
                        coarse = 1.5 * max(d_theta * ranges[i], d_phi * rho)
                        sp[i] = max(_grid_step(pts, i, best, dist[:m].sum() / m), coarse)
                if want_normals:
                    nx, ny, nz = pca_normal(pts, i, nbr, 8, True, po)
                    if cos_min > 0.0:
                        nx, ny, nz = turned(pts[i, 0], pts[i, 1], pts[i, 2], nx, ny, nz, po, cos_min, sin_min)
                    nr[i, 0], nr[i, 1], nr[i, 2] = nx, ny, nz



def _spacing_code(kind: str) -> int:
    if kind not in GRID_SPACINGS:
        raise InputValueError(f"grid_spacing must be one of {GRID_SPACINGS}, got {kind!r}")
    return GRID_SPACINGS.index(kind)


@njit(cache=True, inline="always")
def _axis_step(pts, i, a, b):
    """Distance from point ``i`` to the nearer of the points ``a``, ``b`` (-1: none); 0 when neither."""
    out = 0.0
    for q in (a, b):
        if q >= 0:
            dx = pts[q, 0] - pts[i, 0]
            dy = pts[q, 1] - pts[i, 1]
            dz = pts[q, 2] - pts[i, 2]
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            if out == 0.0 or d < out:
                out = d
    return out


@njit(cache=True, inline="always")
def _grid_step(pts, i, best, mean):
    """``grid_spacing='step'``: twice the smaller of the point's two axis steps
    (the distance to the nearer neighbour in the adjacent pulses of its own
    column, slots 1 and 7 of ``best``, and of its own row, slots 3 and 5);
    the one axis that has neighbours when the other has none, and ``mean``
    (the mean-distance spacing) when only diagonal pulses have one."""
    sv = _axis_step(pts, i, best[1], best[7])
    sh = _axis_step(pts, i, best[3], best[5])
    if sv == 0.0 and sh == 0.0:
        return mean
    if sv == 0.0 or sh == 0.0:
        return 2.0 * max(sv, sh)
    return 2.0 * min(sv, sh)
