"""The ``rays`` estimator: each beam of the target cast along its own modelled ray onto the union's surface.

A real spinning unit's pulse is not the centre of its range-image pixel. Each
laser of an HDL-64E has its own elevation *and* sits above or below the
origin (its ray crosses the spin axis at its own height ``z0``: seen from the
origin its elevation changes with range, by degrees at a few metres), and a
KITTI frame's points were moved after the fact as if measured at the frame's
time (motion-compensated: a point fired at azimuth ``a`` from the back of the
sweep was fired from where the sensor was then, up to half a frame's motion,
~0.35 m, from the frame's origin). Where on the road a pulse lands depends on
both by decimetres at grazing incidence.

:class:`RayModel` is that sensor: per laser ``z = z0 + rho tan(e)`` in the
frame the laser fired from, the firing origin displaced by
``skew (phi - 1/2) v`` (``phi`` the share of the sweep from the back,
counter-clockwise; ``v`` the frame's motion per frame from its poses). It is
fitted by :func:`fit_ray_model` from frames' *own* points and beams (rings),
never the target's: in :mod:`~slr_ray.sequence.holdout` from the other frames
of the window. The skew is the value on a grid that makes the frames' rings
fit their lines best. :func:`fit_range_bias` adds each laser's range bias (a
real unit's lasers read their ranges centimetres long or short), measured
against the planes of the other frames. :func:`pattern_ray_model` is the ideal
sensor of a beam table (each beam from the origin at its table elevation, no
motion, no bias), for a simulated target.

:func:`cast_rays` then, for each laser and column: the union's points in the
laser's band (seen from its firing origin, nearest laser in elevation) and
column, their first cluster by range (the first-peak average's rule: the
first surface), the laser's ray through the column's centre azimuth, and
where that ray meets the plane of the union's ``neighbours`` points nearest to
the cluster, then to that hit (when they are flat and near, the hit lies
within them and not more than ``max_shift`` before the cluster; else the
cluster's centroid projected onto the ray), moved by the laser's range bias.
Each hit is binned into the target's range image as a real point is (its
direction from the origin), nearest per pulse.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .. import lazy
from ..errors import InputValueError
from ..pattern import pulse_directions
from .estimators import FPA_GAP, PulseReturns

#: scipy.spatial, loaded on first use (slr_ray.lazy: the command line starts without it)
scipy_spatial = lazy.module("scipy.spatial")

__all__ = ["RayModel", "fit_ray_model", "fit_range_bias", "pattern_ray_model", "frame_motion", "sweep_offsets", "cast_rays",
           "cast_grid_rays", "RAY_NEIGHBOURS", "fit_azimuth_phases", "PHASE_COHERENCE"]

#: the plane's points (the union's nearest to the first cluster); chosen on the KITTI frames
#: (benchmarks/sequence_rays.py)
RAY_NEIGHBOURS = 64
#: the plane is not used where it meets the ray more than this before the first cluster's start (m)
MAX_SHIFT = 0.3
#: a laser's ray crosses the spin axis within this of the origin (m); a fit beyond it (one range only)
#: takes the height of the lasers fitted before it and its elevation from its points
MAX_HEIGHT = 0.5
#: a plane's points lie within this of where it is asked (m), or this share of the range if more (the
#: union is sparse far off); chosen on the KITTI frames (benchmarks/sequence_rays.py)
PLANE_RADIUS, PLANE_RADIUS_PER_M = 0.5, 0.1
#: a plane's points are flat: their least variance under this share of the next
FLAT = 0.1
#: rays a block (bounds the memory of the plane fits: ~ 64 neighbours x 3 x 8 bytes a ray)
_BLOCK = 32_768


@dataclass(frozen=True)
class RayModel:
    """Each laser's ray (arrays by laser) and the sweep's skew (module docstring).

    The lasers are the table's beam ids (laser ``i`` the table's beam ``i``, as a ``ring`` field numbers
    them), whatever gave them: a frame's ring field, its file's scan order (rows taken to ids), a table's
    ideal rays (:func:`pattern_ray_model`). :meth:`to_dict` writes the per-laser lists in that order and
    :meth:`from_dict` reads them back."""

    elevation: np.ndarray       # (L,) radians
    height: np.ndarray          # (L,) m: where the laser's ray crosses the spin axis
    azimuth_offset: np.ndarray  # (L,) radians: a column's centre is offset + (h + 1/2) 2 pi / columns
    skew: float = 0.0           # the firing origin's displacement over a sweep, in frames' motion
    source: str = "pattern"     # "fitted" (from frames' own points) or "pattern" (a beam table's ideal rays)
    residual_deg: float = math.nan  # median |angle| of the fitting frames' points off their laser's line
    range_bias: np.ndarray | None = None  # (L,) m: what each laser's ranges add to the union's surface

    def to_dict(self) -> dict:
        return {"source": self.source, "skew": self.skew, "lasers": int(len(self.elevation)),
                "median_residual_deg": self.residual_deg,
                "height_m": [round(float(x), 4) for x in self.height],
                "elevation_deg": [round(math.degrees(x), 4) for x in self.elevation],
                "azimuth_offset_deg": [round(math.degrees(x), 4) for x in self.azimuth_offset],
                "range_bias_m": None if self.range_bias is None else [round(float(x), 4) for x in self.range_bias]}

    @classmethod
    def from_dict(cls, d: dict) -> "RayModel":
        """The model :meth:`to_dict` wrote (its values as rounded there), lasers by beam id."""
        try:
            n = int(d["lasers"])
            lists = [np.asarray(d[k], np.float64) for k in ("elevation_deg", "height_m", "azimuth_offset_deg")]
            bias = d.get("range_bias_m")
            bias = None if bias is None else np.asarray(bias, np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputValueError(f"not a ray model's dict ({type(exc).__name__}: {exc})") from None
        if any(v.shape != (n,) for v in lists + ([] if bias is None else [bias])):
            raise InputValueError(f"a ray model's per-laser lists must hold {n} values each (its 'lasers')")
        el, height, az = lists
        return cls(np.radians(el), height, np.radians(az), float(d.get("skew", 0.0)), str(d.get("source", "pattern")),
                   float(d.get("median_residual_deg", math.nan)), bias)


def frame_motion(poses, i: int) -> np.ndarray:
    """Frame ``i``'s motion per frame in its own axes, from the poses of its neighbours (the central
    difference; one-sided at the ends; zeros for a sequence of one frame)."""
    P = np.asarray(poses, np.float64)
    a, b = max(i - 1, 0), min(i + 1, len(P) - 1)
    if a == b:
        return np.zeros(3)
    t = (P[b][:3, 3] - P[a][:3, 3]) / (b - a)  # world
    return P[i][:3, :3].T @ t


def sweep_offsets(points, motion, skew: float) -> np.ndarray:
    """``(n, 3)``: where the sensor was, in the frame, when it fired at each point's azimuth:
    ``skew (phi - 1/2) motion``, ``phi`` the share of the sweep from the back (counter-clockwise)."""
    p = np.asarray(points, np.float64)
    phi = (np.arctan2(p[:, 1], p[:, 0]) + math.pi) / (2 * math.pi)
    return (skew * (phi - 0.5))[:, None] * np.asarray(motion, np.float64)[None, :]


def _lines(P, R, n_lasers, ordered: bool = False):
    """Per laser the robust line ``z = z0 + rho tan(e)``; the median |angular residual| (degrees).
    ``ordered``: ``R`` is sorted already (``P`` C-contiguous, its points in that order)."""
    # each laser's points a slice of one stable sort (the points in the order a mask would give them)
    order = None if ordered else np.argsort(R, kind="stable")
    starts = np.searchsorted(R if ordered else R[order], np.arange(n_lasers + 1))
    Ps = P if ordered else np.ascontiguousarray(P[order])
    z0, el = np.full(n_lasers, np.nan), np.full(n_lasers, np.nan)
    res = np.empty(len(Ps))
    n = _lines_kernel(Ps, starts, MAX_HEIGHT, z0, el, res)
    return z0, el, float(np.median(res[:n])) if n else math.inf


@njit(cache=True)
def _line(rho, z):
    """The least-squares line ``z = c0 + c1 rho`` (numpy's lstsq's: the least-norm one when every
    ``rho`` is the same)."""
    mr, mz = rho.mean(), z.mean()
    sxx = ((rho - mr) ** 2).sum()
    if sxx == 0.0:
        s = mz / (1.0 + mr * mr)
        return s, s * mr
    c1 = ((rho - mr) * (z - mz)).sum() / sxx
    return mz - c1 * mr, c1


@njit(cache=True)
def _lines_kernel(Ps, starts, max_height, z0, el, res_out):
    """:func:`_lines` of points sorted by laser (laser ``l``'s: ``starts[l]:starts[l + 1]``); each
    fitted point's angular residual (degrees) into ``res_out``; returns how many."""
    n_out = 0
    for laser in range(len(starts) - 1):
        a, b = starts[laser], starts[laser + 1]
        rho_all = np.sqrt(Ps[a:b, 0] ** 2 + Ps[a:b, 1] ** 2)
        m = rho_all > 2.0
        if m.sum() < 20:
            continue
        rho = rho_all[m]
        z = Ps[a:b, 2][m]
        c0, c1 = _line(rho, z)
        for _ in range(3):  # drop what is not on the laser's line (mixed pixels, another laser's)
            r = np.abs(z - (c0 + c1 * rho))
            keep = r < 3 * np.median(r) + 1e-3
            c0, c1 = _line(rho[keep], z[keep])
        if abs(c0) > max_height:  # one range only (a laser that sees only the road): no height in it
            c0 = 0.0
            if laser > 0:
                prior = z0[:laser]
                prior = prior[np.isfinite(prior)]
                if len(prior):
                    c0 = np.median(prior)
            c1 = np.median((z - c0) / rho)
        z0[laser], el[laser] = c0, math.atan(c1)
        zz = z - c0
        res_out[n_out:n_out + len(z)] = np.degrees(np.abs(zz - c1 * rho) / np.sqrt(rho * rho + zz * zz))
        n_out += len(z)
    return n_out


#: per laser the robust line ``z = z0 + rho tan(e)`` of points and their lasers: ``(z0, e, median residual deg)``
#: (the sensor cards' fit, :mod:`slr_ray.sensorfit`, uses it too)
beam_lines = _lines


def fit_ray_model(frames, n_lasers: int, skews=None, stride: int = 2) -> RayModel:
    """The sensor's rays from frames' own points: ``frames`` a list of ``(points, beams, motion)``
    (each frame's points in its own frame, each point's laser, the frame's motion per frame by
    :func:`frame_motion`). The skew is the one of ``skews`` (default: -2 to 1 by 0.25, then the
    best's neighbourhood by 0.05) whose undone offsets let the lasers' lines fit best; every
    ``stride``-th point is used. Lasers with too few points take the mean line of the others'."""
    if not frames:
        raise InputValueError("no frame to fit the sensor's rays on")
    pts = [np.asarray(p, np.float64)[::stride] for p, _, _ in frames]
    rings = [np.asarray(r, np.int64)[::stride] for _, r, _ in frames]
    motions = [np.asarray(v, np.float64) for _, _, v in frames]
    R = np.concatenate(rings)
    # what every skew shares, made once: each point's share of the sweep (sweep_offsets' phi - 1/2) and
    # the points in their lasers' (stable) order, which _lines then finds already sorted
    halves = [(np.arctan2(p[:, 1], p[:, 0]) + math.pi) / (2 * math.pi) - 0.5 for p in pts]
    order = np.argsort(R, kind="stable")
    R = R[order]
    pts_o, half_o = np.concatenate(pts)[order], np.concatenate(halves)[order]
    motion_o = np.concatenate([np.broadcast_to(v, p.shape) for p, v in zip(pts, motions)])[order]

    def fit(k):
        return _lines(pts_o - (k * half_o)[:, None] * motion_o, R, n_lasers, ordered=True)

    def best_of(grid):
        fits = {float(k): fit(k) for k in grid}
        k = min(fits, key=lambda s: (fits[s][2], abs(s)))  # a tie (no motion: every skew alike): the least
        return k, fits[k]

    if skews is None and not any(np.any(v != 0) for v in motions):
        skews = [0.0]  # frames that never moved: no skew in them to fit
    if skews is None:
        k, _ = best_of(np.arange(-2.0, 1.01, 0.25))
        k, (z0, el, res) = best_of(np.round(np.arange(k - 0.2, k + 0.21, 0.05), 2))
    else:
        k, (z0, el, res) = best_of(skews)
    if not np.isfinite(el).any():
        raise InputValueError("the frames' lasers have too few points to fit their rays")
    z0 = np.where(np.isfinite(z0), z0, np.nanmean(z0))
    el = np.where(np.isfinite(el), el, np.nanmean(el))  # an empty laser: somewhere (it returns little)
    return RayModel(el, z0, np.zeros(n_lasers), float(k) + 0.0, "fitted", round(res, 5))  # + 0.0: no -0.0


def fit_range_bias(model: RayModel, frames, k: int = 32, stride: int = 8) -> RayModel:
    """``model`` with each laser's range bias: how far, along its own rays, a laser's points lie beyond
    the plane of the *other* frames' points (median over every ``stride``-th point, where the plane of
    its ``k`` nearest is flat). ``frames``: ``(world points, beams, pose, motion)`` of two or more
    frames; one frame: no bias. A real unit's lasers each read their ranges a few centimetres long or
    short (KITTI's: -4 to +7 cm), and a union's planes mix its lasers: the bias is measured
    against such planes (its own laser's points in other frames included), as :func:`cast_rays` uses
    them."""
    L = len(model.elevation)
    if len(frames) < 2:
        return model
    found = [[] for _ in range(L)]
    for j, (w, beams, pose, motion) in enumerate(frames):
        rest = np.concatenate([f[0] for i, f in enumerate(frames) if i != j])
        tree = scipy_spatial.cKDTree(rest)
        P = np.asarray(pose, np.float64)
        pw = np.asarray(w[::stride], np.float64)
        local = (pw - P[:3, 3]) @ P[:3, :3]  # into frame j
        lasers = np.asarray(beams, np.int64)[::stride]
        origin = sweep_offsets(local, motion, model.skew)
        origin[:, 2] += model.height[lasers]
        d = local - origin
        dw = (d / np.linalg.norm(d, axis=1)[:, None]) @ P[:3, :3].T
        dist, c, ev, nrm = _local_planes(rest, tree, pw, k)
        nd = np.einsum("mi,mi->m", nrm, dw)
        along = np.einsum("mi,mi->m", nrm, pw - c) / np.where(np.abs(nd) > 0.2, nd, np.nan)  # + : beyond
        ok = (ev[:, 0] < FLAT * ev[:, 1]) & (dist[:, -1] < PLANE_RADIUS) & np.isfinite(along) & \
            (np.abs(along) < 0.2)
        for laser in range(L):
            found[laser].append(along[ok & (lasers == laser)])
    bias = np.array([float(np.median(np.concatenate(a))) if sum(map(len, a)) >= 50 else 0.0 for a in found])
    return dataclasses.replace(model, range_bias=bias)


#: a laser's azimuth phase is fitted where its points' phasors agree this well (1: every point at one
#: phase of its column; a motion-compensated frame's azimuths, as KITTI's, spread and keep phase 0)
PHASE_COHERENCE = 0.9


def fit_azimuth_phases(frames, n_lasers: int, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """Where within a column each laser fires, from frames' own points: ``frames`` a list of ``(points,
    beams)`` (each in its own frame). A laser's offset (radians: its column's centre is ``offset + (h +
    1/2) 2 pi / columns``) is the mean phase of its points' azimuths in the column, taken where their
    phasors agree (:data:`PHASE_COHERENCE`), else 0 (the column's centre). An Ouster's beams fire at
    the column's edge (its beam azimuth angles), a Hesai's at its centre. Returns the offsets and each
    laser's coherence."""
    D = 2 * math.pi / int(columns)
    acc = np.zeros(n_lasers, complex)
    cnt = np.zeros(n_lasers)
    for p, b in frames:
        p = np.asarray(p, np.float64)
        b = np.asarray(b, np.int64)
        ph = np.exp(1j * (2 * math.pi / D) * (np.arctan2(p[:, 1], p[:, 0]) - 0.5 * D))
        acc += np.bincount(b, weights=ph.real, minlength=n_lasers)[:n_lasers] + \
            1j * np.bincount(b, weights=ph.imag, minlength=n_lasers)[:n_lasers]
        cnt += np.bincount(b, minlength=n_lasers)[:n_lasers]
    coherence = np.abs(acc) / np.maximum(cnt, 1)
    offset = np.where((coherence >= PHASE_COHERENCE) & (cnt >= 20), np.angle(acc) * D / (2 * math.pi), 0.0)
    return offset, coherence


def pattern_ray_model(pattern) -> RayModel:
    """A beam table's ideal rays: each beam from the origin at its elevation, its azimuth offset, no
    motion; lasers by beam id (:class:`RayModel`), as a fitted model's."""
    row = pattern.rows_of_beams(np.arange(pattern.n_beams))  # each beam's row
    return RayModel((math.pi / 2 - np.asarray(pattern.row_zenith, np.float64))[row], np.zeros(pattern.n_beams),
                    np.asarray(pattern.row_offsets, np.float64)[row], 0.0, "pattern")


def _first_clusters(key, r, gap):
    new = np.r_[True, key[1:] != key[:-1]]
    cl = np.cumsum(new | np.r_[False, np.diff(r) > gap]) - 1
    pno = np.cumsum(new) - 1
    first = np.flatnonzero(new)
    return cl == cl[first][pno], pno, first


def _bands(points, model, motion):
    """Each point's laser (nearest in elevation seen from the laser's firing origin; -1: outside
    every band) and its position in the laser's firing frame."""
    q = points - sweep_offsets(points, motion, model.skew)
    rho = np.hypot(q[:, 0], q[:, 1])
    el = model.elevation
    best = np.full(len(q), np.inf)
    laser = np.full(len(q), -1, np.int64)
    signed = np.zeros(len(q))
    for j in range(len(el)):
        g = np.arctan2(q[:, 2] - model.height[j], rho) - el[j]
        b = np.abs(g) < best
        best[b], laser[b], signed[b] = np.abs(g[b]), j, g[b]
    order = np.argsort(el)
    gaps = np.diff(el[order])
    up = np.empty(len(el))
    down = np.empty(len(el))
    if len(el) > 1:
        up[order[:-1]], up[order[-1]] = gaps, gaps[-1]
        down[order[1:]], down[order[0]] = gaps, gaps[0]
    else:
        up[:] = down[:] = math.radians(1.0)
    half = 0.5 * np.where(signed > 0, up[laser], down[laser])
    laser[best > half] = -1
    return laser, q


def cast_rays(points, pattern, model: RayModel | None = None, motion=(0.0, 0.0, 0.0), gap: float = FPA_GAP,
              neighbours: int = RAY_NEIGHBOURS, max_shift: float = MAX_SHIFT) -> PulseReturns:
    """One return per pulse of ``pattern`` from ``points`` (float64, the target's frame) along
    ``model``'s rays (default: the pattern's own, :func:`pattern_ray_model`); ``motion`` the
    target's motion per frame (:func:`frame_motion`). Module docstring."""
    pts = np.ascontiguousarray(points, np.float64)
    model = model or pattern_ray_model(pattern)
    if not gap > 0:
        raise InputValueError(f"the fpa gap must be > 0 m, got {gap}")
    if int(neighbours) < 3:
        raise InputValueError(f"a plane takes 3 or more neighbours, got {neighbours}")
    motion = np.asarray(motion, np.float64)
    C = pattern.columns
    D = 2 * math.pi / C
    laser, q = _bands(pts, model, motion)
    sel = np.flatnonzero(laser >= 0)
    las = laser[sel]
    az = np.mod(np.arctan2(q[sel, 1], q[sel, 0]) - model.azimuth_offset[las], 2 * math.pi)
    col = np.minimum((az / D).astype(np.int64), C - 1)
    key = las * C + col
    r = np.hypot(np.hypot(q[sel, 0], q[sel, 1]), q[sel, 2] - model.height[las])
    o = np.lexsort((sel, r, key))
    key, r, sel, las, col = key[o], r[o], sel[o], las[o], col[o]
    if not len(key):
        return PulseReturns(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64))
    member, pno, first = _first_clusters(key, r, gap)
    n = np.bincount(pno[member]).astype(np.float64)
    cen = np.column_stack([np.bincount(pno[member], weights=pts[sel[member], j]) for j in range(3)]) / n[:, None]
    L, H = las[first], col[first]
    th = model.azimuth_offset[L] + (H + 0.5) * D  # the column's centre: where in it the beam fired is not known
    ce = np.cos(model.elevation[L])
    d = np.column_stack([ce * np.cos(th), ce * np.sin(th), np.sin(model.elevation[L])])
    phi = np.mod(th, 2 * math.pi)
    phi = np.where(phi > math.pi, phi - 2 * math.pi, phi)
    origin = (model.skew * ((phi + math.pi) / (2 * math.pi) - 0.5))[:, None] * motion[None, :]
    origin[:, 2] += model.height[L]
    t = np.einsum("mi,mi->m", cen - origin, d)  # the cluster's centroid projected onto the ray
    lo = r[first] - max_shift  # the plane is taken where it meets the ray past the cluster's start
    if len(pts) >= neighbours:
        tree = scipy_spatial.cKDTree(pts)
        for s in range(0, len(t), _BLOCK):
            b = slice(s, s + _BLOCK)
            t[b] = _onto_plane(pts, tree, origin[b], d[b], t[b], lo[b], int(neighbours))
    if model.range_bias is not None:
        t = t + model.range_bias[L]
    hit = origin + t[:, None] * d
    keys, ranges = pattern.pulse_ids(hit, np.zeros(3))
    ok = np.flatnonzero(keys >= 0)
    o = np.lexsort((ok, ranges[ok], keys[ok]))
    kk = keys[ok][o]
    win = ok[o][np.r_[True, kk[1:] != kk[:-1]]] if len(kk) else ok[:0]
    return PulseReturns(keys[win].astype(np.int64), ranges[win], hit[win], sel[first][win].astype(np.int64))


def cast_grid_rays(points, pattern, gap: float = FPA_GAP, neighbours: int = RAY_NEIGHBOURS,
                   max_shift: float = MAX_SHIFT) -> PulseReturns:
    """:func:`cast_rays` for a uniform grid (a terrestrial scanner's :class:`~slr_ray.ScanPattern`: no lasers,
    no sweep, no range bias): each pulse's ray from the origin through its centre, the first cluster of
    ``points`` (float64, the scanner's frame) in the pulse, and where the ray meets the plane of the
    ``neighbours`` points nearest it (as :func:`cast_rays`; else the cluster's centroid projected onto the
    ray), binned nearest per pulse."""
    pts = np.ascontiguousarray(points, np.float64)
    if not gap > 0:
        raise InputValueError(f"the fpa gap must be > 0 m, got {gap}")
    if int(neighbours) < 3:
        raise InputValueError(f"a plane takes 3 or more neighbours, got {neighbours}")
    keys, ranges = pattern.pulse_ids(pts, np.zeros(3))
    sel = np.flatnonzero(keys >= 0)
    o = np.lexsort((sel, ranges[sel], keys[sel]))
    key, r, sel = keys[sel][o], ranges[sel][o], sel[o]
    if not len(key):
        return PulseReturns(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64))
    member, pno, first = _first_clusters(key, r, gap)
    n = np.bincount(pno[member]).astype(np.float64)
    cen = np.column_stack([np.bincount(pno[member], weights=pts[sel[member], j]) for j in range(3)]) / n[:, None]
    d = pulse_directions(pattern.unravel(key[first]), pattern)
    origin = np.zeros_like(d)
    t = np.einsum("mi,mi->m", cen, d)
    lo = r[first] - max_shift
    if len(pts) >= neighbours:
        tree = scipy_spatial.cKDTree(pts)
        for s in range(0, len(t), _BLOCK):
            b = slice(s, s + _BLOCK)
            t[b] = _onto_plane(pts, tree, origin[b], d[b], t[b], lo[b], int(neighbours))
    hit = t[:, None] * d
    keys, ranges = pattern.pulse_ids(hit, np.zeros(3))
    ok = np.flatnonzero(keys >= 0)
    o = np.lexsort((ok, ranges[ok], keys[ok]))
    kk = keys[ok][o]
    win = ok[o][np.r_[True, kk[1:] != kk[:-1]]] if len(kk) else ok[:0]
    return PulseReturns(keys[win].astype(np.int64), ranges[win], hit[win], sel[first][win].astype(np.int64))


def _local_planes(pts, tree, queries, k):
    """The plane of the ``k`` points of ``pts`` (kd-tree ``tree``) nearest each query: the distances
    to them ``(m, k)``, their centroid, their scatter's eigenvalues (ascending) and
    the plane's normal (the eigenvector of the smallest)."""
    dist, nn = tree.query(queries, k=k)
    Q = pts[nn]
    c = Q.mean(axis=1)
    x = Q - c[:, None]
    w, v = np.linalg.eigh(np.matmul(x.transpose(0, 2, 1), x))
    return dist, c, w, v[:, :, 0]


def _plane_hit(pts, tree, origin, d, t, lo, k):
    """Where each ray meets the plane of the ``k`` points nearest ``origin + t d``; whether that plane
    is usable (flat, its points near: :data:`PLANE_RADIUS`, met no nearer than ``lo``) and the hit
    lies within them."""
    dist, c, w, nrm = _local_planes(pts, tree, origin + t[:, None] * d, k)
    nd = np.einsum("mi,mi->m", nrm, d)
    tt = np.einsum("mi,mi->m", nrm, c - origin) / np.where(np.abs(nd) > 0.05, nd, np.nan)
    ok = (w[:, 0] < FLAT * w[:, 1]) & (dist[:, -1] < np.maximum(PLANE_RADIUS, PLANE_RADIUS_PER_M * t)) & \
        np.isfinite(tt) & (tt >= lo)
    within = np.linalg.norm(origin + np.nan_to_num(tt)[:, None] * d - c, axis=1) <= dist[:, -1]
    return tt, ok, within


def _onto_plane(pts, tree, origin, d, t0, lo, k):
    """Where each ray meets the plane of the ``k`` points nearest its first guess (``t0`` along it),
    then of those nearest that hit: taken where both are usable and the second hit lies within its
    own neighbourhood; else ``t0``. (A ray whose first plane is not usable would ask the same
    neighbourhood again: it keeps ``t0`` without the second query.)"""
    tt, ok, _ = _plane_hit(pts, tree, origin, d, t0, lo, k)
    t = t0.copy()
    m = np.flatnonzero(ok)
    if len(m):
        tt2, ok2, within = _plane_hit(pts, tree, origin[m], d[m], tt[m], lo[m], k)
        take = ok2 & within
        t[m[take]] = tt2[take]
    return t
