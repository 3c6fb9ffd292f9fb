"""The embree backend: points splatted as discs, one ray per pulse.

Every point becomes a disc; all discs go into one Embree BVH, built once when
the cloud is prepared (:class:`DiscScanner`), and each :meth:`~DiscScanner.scan`
casts one ray through the centre of every pulse. The point whose disc is hit
is returned. Where the binning backend answers "the closest point in the
pulse's pyramid", this answers "the first surface along the pulse's centre
ray", with the surface reconstructed from the points: it exposes binning
artefacts (a point far behind a surface, returned only because no point of the
surface fell in that pulse).

Options (:class:`EmbreeOptions`; defaults measured by
``benchmarks/bench_tradeoff.py``, README "Speed and accuracy"):

radius
    a fixed value in metres, an ``(n,)`` array, ``"spacing"`` (``radius_scale``
    times the mean distance to the ``k`` nearest neighbours: adapts to any
    cloud) or ``"footprint"`` (``radius_scale`` times the primary pulse
    footprint ``R_primary * tan(primary_resolution)``: needs
    ``primary_origin`` and ``primary_resolution``, or ``primary_pattern`` for a
    beam table). Computed radii never fall
    below ``min_radius`` (default a tenth of the cloud's median spacing), so
    duplicate points get a disc too; a cloud with no spacing at all (one
    point, identical points) gets ``fallback_radius``.
orientation
    ``"normal"`` (default): discs lie across normals estimated from the ``k``
    nearest neighbours (PCA; a collinear or degenerate neighbourhood takes the
    direction to the primary scanner, or +z, made orthogonal to its line);
    ``"billboard"``: every disc faces the ray that meets it (Embree's
    ``DISC_POINT``); ``"primary"``: discs face the primary scanner
    (``primary_origin``). All three use one BVH for every position.
engine
    ``"embree"`` (default): Embree's own disc primitives, exact discs;
    ``"fan"``: each disc as a polygon of ``segments`` vertices circumscribing
    it (``segments - 2`` triangles) in the same Embree module; ``"open3d"``:
    the same polygons in Open3D's ``RaycastingScene`` (another Embree front
    end; no tie rule). The polygon engines are kept to cross-check the exact
    discs (tests measure how far they agree).
neighbours
    where 'spacing' radii and normals take neighbours from: ``"knn"`` (the
    ``k`` nearest, one kd-tree queried in chunks; the default when the
    primary is unknown) or ``"pulse-grid"`` (the default when
    ``primary_origin`` and ``primary_resolution`` are given, or
    ``primary_pattern``, such as a KITTI frame's beam table: the points of
    the 8 adjacent pulses of the primary's own pulse grid, range-gated by
    ``grid_gate``; one sort and one linear pass computing spacing and normals
    together, no kd-tree and no neighbour arrays, 3.6x faster on 5 M points).
ties
    Tie window in disc radii (default 1; 3 for a beam-table primary, a real
    sensor frame, whose discs are not coplanar): among discs hit within ``ties``
    times the first disc's radius beyond the first hit, the one whose centre
    lies nearest the ray wins, then the lowest index
    (:mod:`slr_ray.raycast`). Results no longer depend on float32 rounding,
    and on a sampled surface each ray returns the point of its own pulse
    rather than a larger neighbouring disc. 0 keeps Embree's first hit.
max_incidence
    With pulse-grid normals (default 80 degrees): a disc seen edge-on from the
    primary scanner (a noisy normal on grazing ground) is turned towards it,
    so that the ray of its own pulse still meets it.

Embree works in float32: coordinates are recentred in float64 on the cloud's
centre before conversion; the tie rule and returned ranges are computed in
float64 from the input points. A scanner standing among the points needs no
rebuild: discs whose reach holds the scanner are skipped by the ray query.
Points the pattern cannot see themselves (range limits, field of view) are
not returned.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from ..arrays import as_origin, as_points, bounds
from ..core import ranges_of
from ..errors import InputValueError, MissingDependencyError
from ..pattern import as_pattern, pulse_rays
from ..raycast import RayScene, padded_rows
from ..scan import Scan
from ..threads import default_threads
from .base import BackendOptions, Scanner

__all__ = ["EmbreeOptions", "DiscScanner", "disc_radii", "estimate_normals", "neighbourhoods",
           "grid_neighbourhoods", "pulse_grid_spacing_normals", "grid_gate", "RADIUS_MODES", "ORIENTATIONS", "ENGINES", "NEIGHBOURS"]

RADIUS_MODES = ("spacing", "footprint")
ORIENTATIONS = ("normal", "billboard", "primary")
ENGINES = ("embree", "fan", "open3d")
NEIGHBOURS = ("knn", "pulse-grid")
#: estimated disc normals are turned to meet the primary's line of sight at no more than this (degrees)
DEFAULT_MAX_INCIDENCE = 80.0


@dataclass(frozen=True)
class EmbreeOptions(BackendOptions):
    """Options of the embree backend (module docstring).

    Attributes
    ----------
    radius : float, (n,) float or {'spacing', 'footprint'}
        Disc radius in metres, or 'spacing' (mean distance to the k nearest
        neighbours) or 'footprint' (the primary pulse's width at the point).
    radius_scale : float
        Multiplies every radius.
    k : int
        Neighbours for ``'spacing'`` radii and for normals.
    orientation : {'normal', 'billboard', 'primary'}
        Discs along the surface normal, facing each ray, or facing the
        primary scanner.
    engine : {'embree', 'fan', 'open3d'}
        Embree's exact discs, or polygon fans in Embree or Open3D (cross-checks).
    segments : int
        Rim vertices of a disc's polygon (fan engines only; >= 3).
    ties : float, optional
        Tie window in disc radii; 0 turns the tie rule off. Default 1, and 3
        when the primary is a beam table (``primary_pattern`` a sensor: real
        frames, whose discs are not coplanar: per-beam range offsets, beams
        not where the table says; a KITTI frame re-scanned with its own
        table, a VLP-16 or 0.4 deg, from its own origin or 1 m aside: 91-98 %
        of binning's points against 89-96 % with 1).
    primary_origin : (3,) float, optional
        The primary scanner (``radius='footprint'``, ``orientation='primary'``,
        and the fallback direction of degenerate normals).
    primary_resolution : float, optional
        Degrees: the primary was scanned with a uniform pattern of this
        resolution (``radius='footprint'``, ``neighbours='pulse-grid'``).
    primary_pattern : str, ScanPattern or BeamPattern, optional
        The primary's own pattern instead of ``primary_resolution`` when it
        is not uniform: a shipped sensor name (a KITTI frame:
        ``velodyne_hdl64e_s2``), a preset, or a pattern object. The pulse
        grid is then its rows (beams) and columns, and the footprint angle
        the root mean square of its row gap and column step.
    primary_beams : (n,) int, optional
        With ``primary_pattern`` a beam table: the beam (table position) that
        fired each point, -1 where unknown, as a frame's ``ring`` field or
        its scan order records it. The pulse grid then puts each point in its
        beam's row instead of the band its elevation falls in: a real unit's
        beams depart from any table, and a beam's vertical offset moves near
        points' elevation by degrees (KITTI frame: README "Where the KITTI
        frame's VLP-16 re-scan loses its points").
    normals : (n, 3) float, optional
        Normals to use instead of estimating them (``orientation='normal'``).
    min_radius : float, optional
        Floor of computed radii (default: 0.1 x the median spacing).
    fallback_radius : float
        Radius when the cloud has no spacing (one point, identical points).
    chunk : int
        Points per neighbour query (bounds memory: about 100 bytes a point).
    n_threads : int, optional
        Threads casting rays (default: all cores).
    neighbours : {'knn', 'pulse-grid'}, optional
        Where 'spacing' radii and normals take neighbours from: the k nearest
        (kd-tree), or the 8 adjacent pulses of the primary's own pulse grid
        (needs primary_origin and primary_resolution or primary_pattern; no
        kd-tree). Default: 'pulse-grid' when the primary's origin and pattern
        are given (3.6x faster to prepare on 5 M
        points, and no holes between rings when re-scanned coarser: 100 % of
        binning's points against 85 % with kNN; but larger discs on grazing
        ground: precision 70 % against kNN's 97 % on bare ground, 92 against
        96.5 % on rect-1000, README "Speed and accuracy"), else 'knn'.
    max_incidence : float, optional
        Degrees. With estimated normals (``orientation='normal'``) and a known
        ``primary_origin``: a disc whose normal makes more than this angle
        with the line of sight to the primary scanner is turned towards the
        scanner until it makes exactly this angle. The primary recorded the
        point, so its pulse met a surface that faced it; a disc edge-on to the
        primary comes from a noisy normal (range noise and beam-to-beam range
        offsets of real sensors, on grazing ground), and a ray passing its
        centre misses it. Default 80 with pulse-grid neighbours (the KITTI
        re-scans of ``ties``, with ``ties=3``: 91-98 % of binning's points
        against 89-97 % without; the same precision on the synthetic
        scenes), 90 (off) otherwise: kNN normals of noiseless
        ground are exact, and turned they stand up in the way of other
        positions' rays (precision 96.9 -> 76.7 % on bare ground). Normals
        given by the user are never turned. README "Returned points on
        sparse clouds".
    grid_gate : float, optional
        With 'pulse-grid': an adjacent pulse's point is a neighbour only when
        its primary range is within this fraction of the point's (a jump in
        range is an edge, not the same surface). Default: the range step of
        a surface seen at 89 deg incidence, ``tan(89 deg)`` times the
        primary's pulse step, at most 0.1 (0.1 for pulses of 0.1 deg and
        coarser; 0.014 at 0.0144 deg, where 0.1 let discs at object edges take
        neighbours metres behind them and grow to 7 m).
    """

    radius: object = "spacing"
    radius_scale: float = 1.0
    k: int = 6
    orientation: str = "normal"
    engine: str = "embree"
    segments: int = 3
    ties: float | None = None
    primary_origin: object = None
    primary_resolution: float | None = None
    primary_pattern: object = None
    primary_beams: object = None
    normals: object = None
    min_radius: float | None = None
    fallback_radius: float = 0.01
    chunk: int = 1 << 20
    n_threads: int | None = None
    neighbours: str | None = None
    grid_gate: float | None = None
    max_incidence: float | None = None

    @classmethod
    def choices(cls) -> dict:
        return {"orientation": ORIENTATIONS, "engine": ENGINES, "neighbours": NEIGHBOURS}

    def __post_init__(self):
        if isinstance(self.radius, str) and self.radius not in RADIUS_MODES:
            raise InputValueError(f"radius must be a number, an array or one of {RADIUS_MODES}, "
                                  f"got {self.radius!r}")
        if self.orientation not in ORIENTATIONS:
            raise InputValueError(f"orientation must be one of {ORIENTATIONS}, got {self.orientation!r}")
        if self.engine not in ENGINES:
            raise InputValueError(f"engine must be one of {ENGINES}, got {self.engine!r}")
        if int(self.segments) != self.segments or self.segments < 3:
            raise InputValueError(f"segments must be an integer >= 3, got {self.segments!r}")
        if int(self.k) != self.k or self.k < 1:
            raise InputValueError(f"k must be an integer >= 1, got {self.k!r}")
        for name in ("radius_scale", "fallback_radius"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputValueError(f"{name} must be a finite number > 0, got {v!r}")
        if self.ties is None:  # frozen: set through object.__setattr__
            beams = self.primary_pattern is not None and as_pattern(self.primary_pattern).has_beams
            object.__setattr__(self, "ties", 3.0 if beams else 1.0)
        if not (isinstance(self.ties, (int, float)) and math.isfinite(self.ties) and self.ties >= 0):
            raise InputValueError(f"ties must be a finite number >= 0, got {self.ties!r}")
        if self.min_radius is not None and not (math.isfinite(self.min_radius) and self.min_radius > 0):
            raise InputValueError(f"min_radius must be a finite number > 0, got {self.min_radius!r}")
        if self.orientation == "billboard" and self.engine != "embree":
            raise InputValueError("orientation='billboard' needs engine='embree' (ray-facing discs)")
        if self.primary_pattern is not None:
            if self.primary_resolution is not None:
                raise InputValueError("give primary_resolution or primary_pattern, not both")
            as_pattern(self.primary_pattern)  # an unknown name or type fails here, not in prepare
        if self.primary_beams is not None and not getattr(self.primary_grid, "has_beams", False):
            raise InputValueError("primary_beams (each point's beam) needs primary_pattern, the primary's "
                                  "beam table")
        if self.neighbours is None:  # frozen: set through object.__setattr__
            known = self.primary_origin is not None and self.primary_grid is not None
            object.__setattr__(self, "neighbours", "pulse-grid" if known else "knn")
        if self.neighbours not in NEIGHBOURS:
            raise InputValueError(f"neighbours must be one of {NEIGHBOURS}, got {self.neighbours!r}")
        if self.neighbours == "pulse-grid" and (self.primary_origin is None or self.primary_grid is None):
            raise InputValueError("neighbours='pulse-grid' needs primary_origin and primary_resolution "
                                  "(or primary_pattern)")
        if self.max_incidence is None:  # frozen: set through object.__setattr__
            grid_normals = self.neighbours == "pulse-grid" and self.orientation == "normal"
            object.__setattr__(self, "max_incidence", DEFAULT_MAX_INCIDENCE if grid_normals else 90.0)
        if not (isinstance(self.max_incidence, (int, float)) and 0 < self.max_incidence <= 90):
            raise InputValueError(f"max_incidence must be degrees in (0, 90], got {self.max_incidence!r}")
        if self.max_incidence < 90 and self.primary_origin is None:
            raise InputValueError("max_incidence needs primary_origin (the scanner the discs turn towards)")
        if self.grid_gate is not None and not (isinstance(self.grid_gate, (int, float)) and self.grid_gate > 0):
            raise InputValueError(f"grid_gate must be a number > 0, got {self.grid_gate!r}")
        if self.orientation == "primary" and self.primary_origin is None:
            raise InputValueError("orientation='primary' needs primary_origin")
        if isinstance(self.radius, str) and self.radius == "footprint" and (
                self.primary_origin is None or self.primary_grid is None):
            raise InputValueError("radius='footprint' needs primary_origin and primary_resolution "
                                  "(or primary_pattern)")
        if int(self.chunk) != self.chunk or self.chunk < 1:
            raise InputValueError(f"chunk must be an integer >= 1, got {self.chunk!r}")

    @property
    def primary_grid(self):
        """The primary's pattern: ``primary_pattern`` as a pattern object, or
        ``primary_resolution`` degrees (a float), or None when neither is given."""
        if self.primary_pattern is not None:
            return as_pattern(self.primary_pattern)
        return None if self.primary_resolution is None else float(self.primary_resolution)

    def to_dict(self) -> dict:
        out = super().to_dict()
        if self.primary_pattern is not None and not isinstance(self.primary_pattern, str):
            out["primary_pattern"] = as_pattern(self.primary_pattern).to_dict()
        return out

    @property
    def reach(self) -> float:
        """How far a disc's stand-in reaches, in radii (polygons circumscribe the disc)."""
        return 1.0 if self.engine == "embree" else 1.0 / math.cos(math.pi / self.segments)


def neighbourhoods(points, k: int, chunk: int = 1 << 20):
    """The ``k`` nearest neighbours of every point, chunk by chunk.

    Yields ``(start, distances (c, k), indices (c, k))`` for consecutive
    chunks of ``chunk`` points (the point itself excluded; duplicates of it
    count as neighbours at distance 0). One kd-tree, queried on all cores;
    memory is the tree plus one chunk's arrays, never ``(n, k)`` for all.
    """
    pts = np.asarray(points)
    n = len(pts)
    k = min(k, n - 1)
    if k < 1:
        return
    c = 0.5 * np.add(*bounds(pts))
    tree = cKDTree(pts - c, balanced_tree=False, compact_nodes=False)
    for s in range(0, n, chunk):
        q = pts[s:s + chunk] - c
        d, i = tree.query(q, k=k + 1, workers=-1)
        # the first answer is at distance 0: the point itself or a duplicate of it
        # (same coordinates, so radii and normals do not depend on which)
        yield s, d[:, 1:], i[:, 1:]


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
    pts = np.asarray(points)
    n = len(pts)
    if n == 0:
        return
    ranges, sorted_keys, order, row_start, line_len, transposed = _sorted_pulse_grid(
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
    return min(0.1, math.tan(math.radians(_GATE_INCIDENCE_DEG)) * max(_primary_steps(primary)))


def _sorted_pulse_grid(pts, origin, primary_resolution, layout: str = "auto", beams=None):
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
    (:meth:`~slr_ray.sensors.BeamPattern.keys`).
    """
    pattern = _grid_pattern(primary_resolution)
    if beams is None:
        keys, ranges = pattern.keys(pts, origin)
    elif not pattern.has_beams:
        raise InputValueError("beams (a point's beam id) need a beam-table primary (primary_pattern), "
                              "not degrees")
    else:
        keys, ranges = pattern.keys(pts, origin, beams)
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
    return ranges, sorted_keys, order, line_start, line_len, transposed


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
def _offer(slot, q, ranges, ri, gate, best):
    """Keep ``q`` in ``best[slot]`` if within the range gate and nearer the scanner
    (candidates come in index order within a pulse: ties keep the lowest index)."""
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
def _pulse_neighbours(sk, order, ranges, row_start, ptr, line, pos, ri, gate, line_len, transposed, best):
    """Fill ``best[slot]`` (-1: none) with the neighbour in each of the 8 pulses
    around the pulse at ``pos`` of line ``line``; slot ``(dv + 1) * 3 + dh + 1``
    (4 is the pulse itself), the output order of a (dv, dh) double loop,
    whichever way the lines run. Lines are zenith rows (azimuth wraps within
    a line) or, ``transposed``, azimuth columns (the lines wrap). ``ptr[t]``:
    a position in line ``line + t - 1`` at or before ``pos - 1``; called with
    non-decreasing ``pos`` along a line, the pointers only move forward."""
    best[:] = -1
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
                _offer((dw + 1) * 3 + t if transposed else t * 3 + dw + 1, order[q], ranges, ri, gate, best)
            q += 1
        if not transposed and line_len >= 3 and pos == 0:  # azimuth wrap: the row's last pulse is h - 1
            q = end - 1
            while q >= row_start[rr] and sk[q] == row0 + line_len - 1:
                q -= 1
            for q2 in range(q + 1, end):  # forward, so ties keep the lowest index
                _offer(t * 3, order[q2], ranges, ri, gate, best)
        if not transposed and line_len >= 3 and pos == line_len - 1:  # and its first pulse is h + 1
            q = row_start[rr]
            while q < end and sk[q] == row0:
                _offer(t * 3 + 2, order[q], ranges, ri, gate, best)
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
def _point_neighbours(pts, sk, order, ranges, row_start, ptr, v, j, gate, line_len, transposed, best, nbr, dist):
    """The neighbours of the point at sorted position ``j`` of line ``v``:
    their indices and distances in ``nbr[:m]``, ``dist[:m]`` (slot order),
    the rest of the 8 padded with the point itself at distance 0; returns ``m``."""
    i = order[j]
    _pulse_neighbours(sk, order, ranges, row_start, ptr, v, sk[j] - v * line_len, ranges[i], gate, line_len,
                      transposed, best)
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
        for v in range(tasks[task], tasks[task + 1]):
            ptr = _row_pointers(row_start, v, transposed)
            for j in range(row_start[v], row_start[v + 1]):
                c = j - base
                counts[c] = _point_neighbours(pts, sk, order, ranges, row_start, ptr, v, j, gate, line_len,
                                              transposed, best, idx[c], dist[c])


def pulse_grid_spacing_normals(points, primary_origin, primary_resolution, gate: float | None = None,
                               spacing: bool = True, normals: bool = True, dtype=np.float64,
                               layout: str = "auto", max_incidence: float = 90.0, beams=None):
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
    for Embree halves their memory); ``layout``: see :func:`_sorted_pulse_grid`
    (the answer does not depend on it, only the speed); ``max_incidence``
    (degrees): normals turned as they are made to meet the line of sight to
    the primary at no more than this (:class:`EmbreeOptions`; 90: not turned);
    ``beams``: each point's beam, as in :func:`grid_neighbourhoods`.
    """
    pts = np.ascontiguousarray(points, np.float64)
    n = len(pts)
    o = as_origin(primary_origin, "primary_origin")
    sp = np.zeros(n) if spacing else np.empty(0)
    # spare rows after the normals: Embree shares float32 ones instead of copying them
    nr = padded_rows(n, dtype) if normals else np.empty((0, 3), dtype)
    if n:
        ranges, sorted_keys, order, line_start, line_len, transposed = _sorted_pulse_grid(
            pts, o, primary_resolution, layout, beams)
        if normals and line_start[0]:  # points outside the pattern: the direction to the scanner
            unseen = order[:line_start[0]]
            nr[unseen] = _fallback_directions(pts[unseen], o, dtype)
        _grid_fused(pts, ranges, sorted_keys, order, line_start, _row_tasks(line_start, 0, len(line_start) - 1),
                    line_len, transposed, grid_gate(primary_resolution, gate), o, spacing, normals, sp, nr,
                    math.cos(math.radians(max_incidence)) if max_incidence < 90 else 0.0)
    return (sp if spacing else None), (nr if normals else None)


@njit(cache=True, parallel=True)
def _grid_fused(pts, ranges, sk, order, row_start, tasks, line_len, transposed, gate, po, want_spacing, want_normals,
                sp, nr, cos_min):
    sin_min = math.sqrt(max(0.0, 1.0 - cos_min * cos_min))
    for task in prange(len(tasks) - 1):
        best = np.empty(9, np.int64)
        nbr = np.empty(8, np.int64)
        dist = np.empty(8)
        for v in range(tasks[task], tasks[task + 1]):
            ptr = _row_pointers(row_start, v, transposed)
            for j in range(row_start[v], row_start[v + 1]):
                i = order[j]
                m = _point_neighbours(pts, sk, order, ranges, row_start, ptr, v, j, gate, line_len, transposed,
                                      best, nbr, dist)
                if want_spacing and m:
                    sp[i] = dist[:m].sum() / m
                if want_normals:
                    nx, ny, nz = _pca_normal(pts, i, nbr, 8, True, po)
                    if cos_min > 0.0:
                        nx, ny, nz = _turned(pts[i, 0], pts[i, 1], pts[i, 2], nx, ny, nz, po, cos_min, sin_min)
                    nr[i, 0], nr[i, 1], nr[i, 2] = nx, ny, nz


def _fallback_directions(points, primary_origin, dtype=np.float64):
    """Direction used where a normal is undefined: to the primary scanner, or +z."""
    if primary_origin is None:
        return np.broadcast_to(np.array([0.0, 0.0, 1.0], dtype), points.shape)
    out = padded_rows(len(points), dtype)  # shared with Embree as they are
    _towards(np.ascontiguousarray(points, np.float64), as_origin(primary_origin, "primary_origin"), out)
    return out


@njit(cache=True, inline="always")
def _turned(px, py, pz, nx, ny, nz, o, cos_min, sin_min):
    """The unit normal ``n`` of a disc at ``p``, turned within the plane it spans
    with the line of sight to ``o`` until it meets that line at no more than
    ``acos(cos_min)`` (unchanged when it already does, or at ``o``)."""
    ux, uy, uz = o[0] - px, o[1] - py, o[2] - pz
    un = math.sqrt(ux * ux + uy * uy + uz * uz)
    if un == 0.0:
        return nx, ny, nz
    ux, uy, uz = ux / un, uy / un, uz / un
    c = nx * ux + ny * uy + nz * uz
    if abs(c) >= cos_min:
        return nx, ny, nz
    if c < 0.0:  # a disc has no back: turn the side that faces away
        nx, ny, nz, c = -nx, -ny, -nz, -c
    # v: the normal's part orthogonal to the line of sight; the turned normal is
    # cos_min along the line and sin_min along v (the same plane, the same side)
    vx, vy, vz = nx - c * ux, ny - c * uy, nz - c * uz
    vn = math.sqrt(vx * vx + vy * vy + vz * vz)
    if vn == 0.0:
        return nx, ny, nz
    return (cos_min * ux + sin_min * vx / vn, cos_min * uy + sin_min * vy / vn,
            cos_min * uz + sin_min * vz / vn)


@njit(cache=True, parallel=True)
def _limit_incidence(points, normals, o, cos_min):
    """:func:`_turned` applied to every normal in place (normals not computed by
    the pulse-grid pass, which turns its own as it makes them)."""
    sin_min = math.sqrt(max(0.0, 1.0 - cos_min * cos_min))
    for i in prange(points.shape[0]):
        normals[i, 0], normals[i, 1], normals[i, 2] = _turned(
            points[i, 0], points[i, 1], points[i, 2], np.float64(normals[i, 0]), np.float64(normals[i, 1]),
            np.float64(normals[i, 2]), o, cos_min, sin_min)


@njit(cache=True, parallel=True)
def _distances(points, o, out):
    for i in prange(points.shape[0]):
        hx, hy, hz = o[0] - points[i, 0], o[1] - points[i, 1], o[2] - points[i, 2]
        out[i] = math.sqrt(hx * hx + hy * hy + hz * hz)


@njit(cache=True, parallel=True)
def _towards(points, o, out):
    """Unit vectors from each point to ``o`` (+z for a point at ``o``)."""
    for i in prange(points.shape[0]):
        hx, hy, hz = o[0] - points[i, 0], o[1] - points[i, 1], o[2] - points[i, 2]
        n = math.sqrt(hx * hx + hy * hy + hz * hz)
        if n > 0:
            out[i, 0], out[i, 1], out[i, 2] = hx / n, hy / n, hz / n
        else:
            out[i, 0], out[i, 1], out[i, 2] = 0.0, 0.0, 1.0


def disc_radii(points, radius="spacing", *, k: int = 6, radius_scale: float = 1.0, primary_origin=None,
               primary_resolution=None, min_radius=None, fallback_radius: float = 0.01,
               spacing=None) -> np.ndarray:
    """Disc radius of every point, ``(n,) float64`` (module docstring).

    ``spacing``: the ``(n,)`` mean distance to the ``k`` nearest neighbours
    when already computed. Computed radii ('spacing', 'footprint') are floored
    at ``min_radius`` (default 0.1 x the median positive spacing or radius) and
    never fail on duplicate points; given radii must be finite and > 0.
    """
    pts = np.asarray(points)
    n = len(pts)
    if isinstance(radius, str):
        if radius == "spacing":
            if spacing is None:
                spacing = np.zeros(n)
                for s, d, _ in neighbourhoods(pts, k):
                    spacing[s:s + len(d)] = d.mean(axis=1)
            r = np.asarray(spacing, np.float64) * radius_scale
        elif radius == "footprint":
            if primary_origin is None or primary_resolution is None:
                raise InputValueError("radius='footprint' needs primary_origin and primary_resolution")
            r = np.empty(n)
            _distances(np.ascontiguousarray(pts, np.float64), as_origin(primary_origin, "primary_origin"), r)
            r *= math.tan(_footprint_angle(primary_resolution)) * radius_scale
        else:
            raise InputValueError(f"radius must be a number, an array or one of {RADIUS_MODES}, got {radius!r}")
        positive = r[r > 0]
        floor = min_radius if min_radius is not None else (
            0.1 * float(np.median(positive)) if len(positive) else fallback_radius)
        return np.maximum(r, floor)
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,)) * radius_scale
    if n and not (np.all(np.isfinite(r)) and r.min() > 0):
        raise InputValueError(f"disc radii must be finite and > 0 ({np.count_nonzero(~(r > 0))} are not)")
    return r.copy()


def estimate_normals(points, k: int = 10, primary_origin=None, chunk: int = 1 << 20) -> np.ndarray:
    """Unit normals ``(n, 3)`` by PCA of each point and its ``k`` nearest
    neighbours (smallest eigenvector); collinear or empty neighbourhoods take
    the direction to ``primary_origin`` (or +z) made orthogonal to the line."""
    pts = np.asarray(points, np.float64)
    if len(pts) < 2:  # no neighbours: the fallback direction
        return np.array(_fallback_directions(pts, primary_origin))
    out = np.empty((len(pts), 3))
    for s, _, idx in neighbourhoods(pts, k, chunk):
        out[s:s + len(idx)] = _chunk_normals(pts, np.arange(s, s + len(idx)), idx, primary_origin)
    return out


def _chunk_normals(pts, members, idx, primary_origin):
    """PCA normals of the points ``members`` with their neighbours ``idx``."""
    out = np.empty((len(idx), 3))
    has = primary_origin is not None
    po = as_origin(primary_origin, "primary_origin") if has else np.zeros(3)
    _pca_normals(pts, np.ascontiguousarray(members, np.int64), np.ascontiguousarray(idx, np.int64),
                 has, po, out)
    return out


@njit(cache=True, inline="always")
def _eigvec(a00, a01, a02, a11, a12, a22, lam):
    """Unit eigenvector of the symmetric 3x3 matrix for its eigenvalue ``lam``: the
    largest cross product of two rows of (A - lam I)."""
    r0 = (a00 - lam, a01, a02)
    r1 = (a01, a11 - lam, a12)
    r2 = (a02, a12, a22 - lam)
    best = -1.0
    vx = vy = vz = 0.0
    for ra, rb in ((r0, r1), (r0, r2), (r1, r2)):
        cx = ra[1] * rb[2] - ra[2] * rb[1]
        cy = ra[2] * rb[0] - ra[0] * rb[2]
        cz = ra[0] * rb[1] - ra[1] * rb[0]
        m = cx * cx + cy * cy + cz * cz
        if m > best:
            best, vx, vy, vz = m, cx, cy, cz
    n = math.sqrt(best)
    if n == 0.0:
        return 0.0, 0.0, 0.0, False
    return vx / n, vy / n, vz / n, True


@njit(cache=True, inline="always")
def _pca_normal(pts, p, nbr, k, has_primary, po):
    """Normal of point ``p`` by PCA of it and its neighbours ``nbr[:k]``,
    eigenvalues in closed form (trigonometric solution of the symmetric 3x3
    characteristic polynomial)."""
    # fallback direction: to the primary scanner, or +z
    fx, fy, fz = 0.0, 0.0, 1.0
    if has_primary:
        hx, hy, hz = po[0] - pts[p, 0], po[1] - pts[p, 1], po[2] - pts[p, 2]
        hn = math.sqrt(hx * hx + hy * hy + hz * hz)
        if hn > 0:
            fx, fy, fz = hx / hn, hy / hn, hz / hn
    mx, my, mz = pts[p, 0], pts[p, 1], pts[p, 2]
    for j in range(k):
        q = nbr[j]
        mx += pts[q, 0]
        my += pts[q, 1]
        mz += pts[q, 2]
    mx /= k + 1
    my /= k + 1
    mz /= k + 1
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    for j in range(-1, k):
        q = p if j < 0 else nbr[j]
        dx, dy, dz = pts[q, 0] - mx, pts[q, 1] - my, pts[q, 2] - mz
        a00 += dx * dx
        a01 += dx * dy
        a02 += dx * dz
        a11 += dy * dy
        a12 += dy * dz
        a22 += dz * dz
    scale = 1e-9 * (1.0 + max(abs(pts[p, 0]), abs(pts[p, 1]), abs(pts[p, 2])))
    tiny = scale * scale * (k + 1)
    q3 = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q3, a11 - q3, a22 - q3
    p2 = (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0
    if a00 + a11 + a22 <= tiny:  # identical points: no direction
        return fx, fy, fz
    if p2 <= 0.0:  # isotropic: any direction is a normal
        return fx, fy, fz
    pp = math.sqrt(p2)
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
           + a02 * (a01 * a12 - b11 * a02)) / (pp * pp * pp)
    r = min(1.0, max(-1.0, det / 2.0))
    phi = math.acos(r) / 3.0
    lam2 = q3 + 2.0 * pp * math.cos(phi)  # largest
    lam0 = q3 + 2.0 * pp * math.cos(phi + 2.0 * math.pi / 3.0)  # smallest
    lam1 = 3.0 * q3 - lam0 - lam2
    if lam1 <= 1e-9 * lam2:
        # collinear: orthogonal to the line, towards the fallback direction
        ax, ay, az, ok = _eigvec(a00, a01, a02, a11, a12, a22, lam2)
        t = fx * ax + fy * ay + fz * az
        hx, hy, hz = fx - t * ax, fy - t * ay, fz - t * az
        hn = math.sqrt(hx * hx + hy * hy + hz * hz)
        if hn <= 1e-12:  # the fallback lies along the line: any orthogonal direction
            if abs(ax) < 0.9:
                hx, hy, hz = 0.0, az, -ay
            else:
                hx, hy, hz = -az, 0.0, ax
            hn = math.sqrt(hx * hx + hy * hy + hz * hz)
        return hx / hn, hy / hn, hz / hn
    vx, vy, vz, ok = _eigvec(a00, a01, a02, a11, a12, a22, lam0)
    if not ok:
        vx, vy, vz = fx, fy, fz
    return vx, vy, vz


@njit(cache=True, parallel=True)
def _pca_normals(pts, members, idx, has_primary, po, out):
    """:func:`_pca_normal` of every point ``members[i]`` with neighbours ``idx[i]``."""
    k = idx.shape[1]
    for i in prange(idx.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _pca_normal(pts, members[i], idx[i], k, has_primary, po)


def _frames(normals):
    """Two unit vectors spanning the plane orthogonal to each normal."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, [2]]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(n, u)


def _fan(centres, normals, radii, segments):
    """Discs as polygons: vertices (n * segments, 3) float64, faces (n * (segments - 2), 3).

    Each disc is a regular polygon of ``segments`` rim vertices that
    circumscribes it, triangulated as a fan from its first rim vertex. There
    is no vertex at the disc centre: a ray through a point exactly (the common
    case when a scan is scanned again from its own origin) would meet several
    triangles at their shared vertex, which Embree's fast test can miss. With
    an odd ``segments`` no edge passes through the centre either.
    """
    n = len(centres)
    u, w = _frames(normals)
    ang = 2 * np.pi * (np.arange(segments) + 0.25) / segments
    rim = radii / np.cos(np.pi / segments)
    verts = np.empty((n, segments, 3))
    for j, a in enumerate(ang):
        verts[:, j] = centres + rim[:, None] * (np.cos(a) * u + np.sin(a) * w)
    base = (np.arange(n, dtype=np.int64) * segments)[:, None]
    j = np.arange(1, segments - 1)
    faces = np.empty((n, segments - 2, 3), dtype=np.int64)
    faces[:, :, 0] = base
    faces[:, :, 1] = base + j
    faces[:, :, 2] = base + j + 1
    return verts.reshape(-1, 3), faces.reshape(-1, 3)


class DiscScanner(Scanner):
    """A cloud as discs in one Embree BVH, ready to scan from many positions.

    Made by ``slr_ray.prepare(points, backend="embree", **options)``; options
    are those of :class:`EmbreeOptions`. Neighbours, radii, normals and the
    BVH are computed here, once; :meth:`scan` only casts rays.

    Attributes
    ----------
    radii : (n,) float32
        The disc radii as Embree uses them (for the ``embree`` engine, a
        read-only view of its vertex buffer).
    normals : (n, 3) float64 or None
        None for ray-facing discs (``orientation='billboard'``) and for discs
        facing the primary scanner (``orientation='primary'``: the direction
        to ``primary_origin``, not kept to save 24 bytes a point).
    build_seconds : float
        Time to build the BVH.
    neighbour_seconds : float
        Time for neighbours, radii and normals.
    nbytes : int
        Bytes of the arrays shared with the ray engine (the BVH comes on top).
    """

    backend = "embree"

    def __init__(self, points, options: EmbreeOptions | None = None):
        t0 = time.perf_counter()
        options = options or EmbreeOptions()
        pts = as_points(points).astype(np.float64, copy=False)
        super().__init__(pts, options)
        o = options
        n = len(pts)
        need_spacing = isinstance(o.radius, str) and o.radius == "spacing"
        need_normals = o.orientation == "normal" and o.normals is None
        spacing = np.zeros(n) if need_spacing else None
        normals = None
        # estimated normals in float32 for Embree (its precision; 12 B a point less at the peak)
        ndtype = np.float32 if o.engine == "embree" else np.float64
        grid = (need_spacing or need_normals) and o.neighbours == "pulse-grid"
        if o.primary_beams is not None:
            o.primary_grid.rows_of_beams(o.primary_beams, n)  # a bad length or beam id fails here, used or not
        if o.orientation == "normal":
            # kNN normals are filled chunk by chunk below, pulse-grid ones come whole; fewer than two
            # points have no neighbours and keep the fallback direction
            if not need_normals:
                normals = np.asarray(as_points(o.normals, "normals"), np.float64)
            elif n < 2:
                normals = np.array(_fallback_directions(pts, o.primary_origin, ndtype))
            elif not grid:
                normals = padded_rows(n, ndtype)  # shared with Embree, not copied
            if normals is not None and len(normals) != n:
                raise InputValueError(f"normals has {len(normals)} rows for {n} points")
        elif o.orientation == "primary":
            # float32: what Embree holds anyway (a float64 copy would be 24 B a point of peak memory)
            normals = _fallback_directions(pts, o.primary_origin, np.float32)
        if grid and n >= 2:
            # one fused pass: no neighbour arrays (spacing 0 where none: the floor applies)
            spacing, grid_normals = pulse_grid_spacing_normals(pts, o.primary_origin, o.primary_grid,
                                                               o.grid_gate, need_spacing, need_normals, ndtype,
                                                               max_incidence=o.max_incidence,
                                                               beams=o.primary_beams)
            if need_normals:
                normals = grid_normals
        elif need_spacing or need_normals:
            # one neighbour query per chunk serves radii and normals
            for s, d, idx in neighbourhoods(pts, o.k, o.chunk):
                if need_spacing:
                    spacing[s:s + len(d)] = d.mean(axis=1)
                if need_normals:
                    normals[s:s + len(idx)] = _chunk_normals(pts, np.arange(s, s + len(idx)), idx,
                                                             o.primary_origin)
        if need_normals and n >= 2 and o.max_incidence < 90 and not grid:  # the grid pass turns its own
            _limit_incidence(pts, normals, as_origin(o.primary_origin, "primary_origin"),
                             math.cos(math.radians(o.max_incidence)))
        # float32, Embree's precision (4 B a point instead of 8: 0.8 GB on a 209 M-point primary)
        self.radii = disc_radii(pts, o.radius, k=o.k, radius_scale=o.radius_scale,
                                primary_origin=o.primary_origin, primary_resolution=o.primary_grid,
                                min_radius=o.min_radius, fallback_radius=o.fallback_radius,
                                spacing=spacing).astype(np.float32)
        del spacing
        self.normals = normals
        self.neighbour_seconds = time.perf_counter() - t0
        t1 = time.perf_counter()
        self._centre = 0.5 * np.add(*bounds(pts)) if n else np.zeros(3)
        self._scene = None
        if o.engine == "embree":
            self._scene = RayScene.discs(pts, self.radii, normals, centre=self._centre)
            self.radii = self._scene.owner_radii  # a view of Embree's buffer: no second copy
            self._per_point = 1
        else:
            self._per_point = o.segments - 2
            verts, faces = _fan(pts, normals, self.radii, o.segments)
            if o.engine == "fan":
                self._scene = RayScene.triangles(verts, faces, centre=self._centre,
                                                 owners=(pts, self.radii, self._per_point, o.reach, normals))
            else:
                self._scene = _Open3DFans(verts - self._centre, faces)
            del verts, faces
        if o.engine == "embree" and normals is not None:
            # Embree and the tie rule hold their own float32 copy: the float64 one (24 B a point, 5 GB on
            # a 209 M-point primary) is not kept; ``normals`` is a read-only view of Embree's
            self.normals = normals = self._scene.owner_normals
        self._max_radius = float(self.radii.max(initial=0.0))  # read by every scan: computed once
        self.nbytes = self._scene.nbytes
        self.build_seconds = time.perf_counter() - t1
        self.prepare_seconds = time.perf_counter() - t0

    def _cast(self, origin, dirs, tfar, aspect=None):
        o = self.options
        if o.engine == "open3d":
            return self._scene.cast(origin - self._centre, dirs, tfar, self._per_point, self._open3d_start)
        hits = self._scene.intersect(origin, dirs, tfar=tfar, ties=o.ties, skip_containing=True,
                                     n_threads=o.n_threads, pulse_aspect=aspect)
        return hits.owners, hits.distances

    def _hits(self, origin, pattern, rays_per_batch=1 << 21):
        """Every ray that hits a disc: (point index, t, v, h) arrays."""
        rmin, rmax = pattern.range_limits
        reach = self._max_radius * self.options.reach
        tfar = min(rmax + 2 * reach, 3e37)
        if self.options.engine == "open3d":
            # Open3D has no filter: rays start beyond the discs that hold the scanner
            d = np.linalg.norm(self.points - origin, axis=1)
            inside = d <= self.radii * self.options.reach
            self._open3d_start = float((d + self.radii * self.options.reach)[inside].max(initial=0.0))
        nv, nh = pattern.shape
        aspect = _pulse_aspect(pattern)
        rows_per = max(1, rays_per_batch // nh)
        parts = []
        for r0 in range(0, nv, rows_per):
            dirs, vv, hh = pulse_rays(pattern, slice(r0, min(nv, r0 + rows_per)))
            pt, t = self._cast(origin, dirs, tfar, aspect)
            hit = pt >= 0
            parts.append((pt[hit], t[hit], vv[hit], hh[hit]))
        if not parts:
            return np.empty(0, np.int64), np.empty(0), np.empty(0, np.int64), np.empty(0, np.int64)
        return tuple(np.concatenate([p[j] for p in parts]) for j in range(4))

    def ray_hits(self, origin, pattern):
        """Per-ray answer: for every pulse whose centre ray hits a disc, the point.

        Returns
        -------
        pulses : (k, 2) int64
            ``(v, h)`` of each ray that hit.
        indices : (k,) intp
            The point whose disc it hit (a point may appear for several pulses).
        distances : (k,) float64
            Distance along the ray to the disc.
        """
        pt, t, v, h = self._hits(as_origin(origin), as_pattern(pattern))
        return np.column_stack([v, h]), pt.astype(np.intp), t

    def scan(self, origin, pattern, rays_per_batch: int = 1 << 21) -> Scan:
        """Scan the discs from ``origin`` with ``pattern``.

        A point hit by several rays appears once, with the pulse of its
        nearest ray. ``info`` of the result holds ``cast_seconds``, ``rays``
        and ``ray_hits`` (rays that hit a disc) and the options.
        """
        return self.scan_and_rays(origin, pattern, rays_per_batch)[0]

    def scan_and_rays(self, origin, pattern, rays_per_batch: int = 1 << 21):
        """:meth:`scan` and :meth:`ray_hits` from one cast: ``(scan, (pulses, indices, distances))``."""
        pattern = as_pattern(pattern)
        origin = as_origin(origin)
        t_start = time.perf_counter()
        pt, tt, v, h = self._hits(origin, pattern, rays_per_batch)
        cast = time.perf_counter() - t_start
        rays = (np.column_stack([v, h]), pt.astype(np.intp), tt)
        n_ray_hits = len(pt)
        # points the pattern itself would not see (range limits, field of view) are not returned
        uniq, inverse = np.unique(pt, return_inverse=True)
        keys, _ = pattern.keys(self.points[uniq], origin)
        nearest = _nearest_ray(inverse, tt, len(uniq))  # per point, its nearest ray (the first of equals)
        seen = keys >= 0
        idx = uniq[seen].astype(np.intp)
        nearest = nearest[seen]
        scan = Scan(indices=idx, ranges=ranges_of(self.points, idx, origin),
                    pulses=np.column_stack([v[nearest], h[nearest]]).astype(np.int64),
                    origin=origin, pattern=pattern, backend=self.backend, n_input=len(self.points),
                    seconds=time.perf_counter() - t_start,
                    info={"cast_seconds": round(cast, 6), "rays": int(pattern.n_pulses),
                          "ray_hits": int(n_ray_hits), **self.options.to_dict()})
        return scan, rays


@njit(cache=True)
def _nearest_ray(group, t, n_groups):
    """Per group (a point), the index of its ray of least ``t``, the first of equals."""
    best = np.full(n_groups, -1, np.int64)
    for i in range(len(group)):
        g = group[i]
        b = best[g]
        if b < 0 or t[i] < t[b]:
            best[g] = i
    return best


def _pulse_steps(pattern) -> tuple[float, float]:
    """Zenith and azimuth step of a pattern's pulses, radians (a beam table: its
    mean row gap)."""
    return pattern.pulse_steps


def _pulse_aspect(pattern) -> float:
    """Zenith step over azimuth step of a pattern's pulses, the scale of the
    tie rule's pulse units."""
    d_theta, d_phi = _pulse_steps(pattern)
    return d_theta / d_phi


def _primary_steps(primary) -> tuple[float, float]:
    """Zenith and azimuth pulse steps of the primary, radians: ``primary``
    degrees (both), or those of a pattern (:func:`_pulse_steps`)."""
    if isinstance(primary, (int, float, np.integer, np.floating)):
        step = math.radians(float(primary))
        return step, step
    return _pulse_steps(as_pattern(primary))


def _footprint_angle(primary) -> float:
    """The primary pulse's angular width, radians: the root mean square of its
    zenith and azimuth steps (a beam table's pulses are taller than wide; for
    degrees, exactly their radians)."""
    d_theta, d_phi = _primary_steps(primary)
    return d_theta if d_theta == d_phi else math.sqrt(0.5 * (d_theta * d_theta + d_phi * d_phi))


class _Open3DFans:
    """Polygon fans in Open3D's RaycastingScene (the ``engine='open3d'`` cross-check)."""

    def __init__(self, verts_local, faces):
        try:
            import open3d as o3d
        except ImportError as exc:
            raise MissingDependencyError(
                "engine='open3d' needs open3d (pip install 'slr_ray[open3d]'; apt-get install libusb-1.0-0)"
            ) from exc
        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        v32 = verts_local.astype(np.float32)
        f32 = faces.astype(np.uint32)
        if len(f32):
            self.scene.add_triangles(o3d.core.Tensor(v32), o3d.core.Tensor(f32))
        self.nbytes = v32.nbytes + f32.nbytes

    def cast(self, origin_local, dirs, tfar, per_point, start):
        o3d = self._o3d
        rays = np.empty((len(dirs), 6), np.float32)
        rays[:, :3] = origin_local + start * dirs
        rays[:, 3:] = dirs
        ans = self.scene.cast_rays(o3d.core.Tensor(rays), nthreads=default_threads())
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        t = ans["t_hit"].numpy().astype(np.float64) + start
        miss = (prim == o3d.t.geometry.RaycastingScene.INVALID_ID) | ~(t <= tfar)
        owner = np.where(miss, -1, prim // per_point)
        return owner, np.where(miss, np.inf, t)
