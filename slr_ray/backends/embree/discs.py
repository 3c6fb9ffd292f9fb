"""Disc geometry of a cloud, no Embree in it: k-nearest neighbours, PCA normals
(turned towards the primary scanner where they are edge-on to it), radii, and
the polygon fans that stand in for discs in the polygon engines.

Everything here works on float64 points and is testable without the Embree
library; the pulse-grid neighbours are :mod:`slr_ray.backends.embree.pulsegrid`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ... import lazy
from ...arrays import as_origin, bounds
from ...errors import InputValueError
from ...pattern import as_pattern
from ...raycast import padded_rows
from .options import RADIUS_MODES

#: scipy.spatial, loaded on first use (slr_ray.lazy: the command line starts without it)
scipy_spatial = lazy.module("scipy.spatial")

__all__ = ["neighbourhoods", "disc_radii", "estimate_normals", "chunk_normals", "fallback_directions",
           "limit_incidence", "turned", "pca_normal", "fan_polygons", "primary_steps", "footprint_angle",
           "pulse_centre_reach", "PULSE_REACH_MARGIN", "PULSE_REACH_CAP"]


#: Bytes of one chunk's neighbour arrays (float64 distances, int64 indices) in :func:`neighbourhoods`.
_NEIGHBOUR_BYTES = 1 << 30


def neighbourhoods(points, k: int, chunk: int = 1 << 20):
    """The ``k`` nearest neighbours of every point, chunk by chunk.

    Yields ``(start, distances (c, k), indices (c, k))`` for consecutive
    chunks of ``chunk`` points (the point itself excluded; duplicates of it
    count as neighbours at distance 0). One kd-tree, queried on all cores;
    memory is the tree plus one chunk's arrays (at most about 1 GiB: fewer
    points a chunk for a larger ``k``), never ``(n, k)`` for all.
    """
    pts = np.asarray(points)
    n = len(pts)
    k = min(k, n - 1)
    if k < 1:
        return
    chunk = max(1, min(chunk, _NEIGHBOUR_BYTES // (16 * (k + 1))))  # a chunk's distances and indices
    c = 0.5 * np.add(*bounds(pts))
    tree = scipy_spatial.cKDTree(pts - c, balanced_tree=False, compact_nodes=False)
    for s in range(0, n, chunk):
        q = pts[s:s + chunk] - c
        d, i = tree.query(q, k=k + 1, workers=-1)
        # the first answer is at distance 0: the point itself or a duplicate of it
        # (same coordinates, so radii and normals do not depend on which)
        yield s, d[:, 1:], i[:, 1:]


def fallback_directions(points, primary_origin, dtype=np.float64):
    """Direction used where a normal is undefined: to the primary scanner, or +z."""
    if primary_origin is None:
        return np.broadcast_to(np.array([0.0, 0.0, 1.0], dtype), points.shape)
    out = padded_rows(len(points), dtype)  # shared with Embree as they are
    _towards(np.ascontiguousarray(points, np.float64), as_origin(primary_origin, "primary_origin"), out)
    return out


@njit(cache=True, inline="always")
def turned(px, py, pz, nx, ny, nz, o, cos_min, sin_min):
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
def limit_incidence(points, normals, o, cos_min):
    """:func:`turned` applied to every normal in place (normals not computed by
    the pulse-grid pass, which turns its own as it makes them)."""
    sin_min = math.sqrt(max(0.0, 1.0 - cos_min * cos_min))
    for i in prange(points.shape[0]):
        normals[i, 0], normals[i, 1], normals[i, 2] = turned(
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
            r *= math.tan(footprint_angle(primary_resolution)) * radius_scale
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
    pts = np.ascontiguousarray(points, np.float64)  # one layout: _pca_normals compiles once (3.5 s a layout)
    if len(pts) < 2:  # no neighbours: the fallback direction
        return np.array(fallback_directions(pts, primary_origin))
    out = np.empty((len(pts), 3))
    for s, _, idx in neighbourhoods(pts, k, chunk):
        out[s:s + len(idx)] = chunk_normals(pts, np.arange(s, s + len(idx)), idx, primary_origin)
    return out


def chunk_normals(pts, members, idx, primary_origin):
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
def pca_normal(pts, p, nbr, k, has_primary, po):
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
    # in coordinates relative to the point itself: the offsets, their mean and so the
    # covariance do not depend on where the cloud lies (translation invariance; at 1e7 m
    # an absolute mean would round to 2e-9 m and a threshold scaled by |x| called 1 cm
    # neighbourhoods "identical points")
    px, py, pz = pts[p, 0], pts[p, 1], pts[p, 2]
    mx = my = mz = 0.0
    for j in range(k):
        q = nbr[j]
        mx += pts[q, 0] - px
        my += pts[q, 1] - py
        mz += pts[q, 2] - pz
    mx /= k + 1
    my /= k + 1
    mz /= k + 1
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    for j in range(-1, k):
        q = p if j < 0 else nbr[j]
        dx, dy, dz = (pts[q, 0] - px) - mx, (pts[q, 1] - py) - my, (pts[q, 2] - pz) - mz
        a00 += dx * dx
        a01 += dx * dy
        a02 += dx * dz
        a11 += dy * dy
        a12 += dy * dz
        a22 += dz * dz
    tiny = 0.0  # identical points: every offset is exactly 0
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
    """:func:`pca_normal` of every point ``members[i]`` with neighbours ``idx[i]``."""
    k = idx.shape[1]
    for i in prange(idx.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = pca_normal(pts, members[i], idx[i], k, has_primary, po)


def _frames(normals):
    """Two unit vectors spanning the plane orthogonal to each normal."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, [2]]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(n, u)


def fan_polygons(centres, normals, radii, segments):
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


def primary_steps(primary) -> tuple[float, float]:
    """Zenith and azimuth pulse steps of the primary, radians: ``primary``
    degrees (both), or those of a pattern (:attr:`~slr_ray.core.Pattern.pulse_steps`)."""
    if isinstance(primary, (int, float, np.integer, np.floating)):
        step = math.radians(float(primary))
        return step, step
    return as_pattern(primary).pulse_steps


def footprint_angle(primary) -> float:
    """The primary pulse's angular width, radians: the root mean square of its
    zenith and azimuth steps (a beam table's pulses are taller than wide; for
    degrees, exactly their radians)."""
    d_theta, d_phi = primary_steps(primary)
    return d_theta if d_theta == d_phi else math.sqrt(0.5 * (d_theta * d_theta + d_phi * d_phi))


#: :func:`pulse_centre_reach`'s radius: this times the distance to the pulse centre ray (float32 discs)
PULSE_REACH_MARGIN = 1.02
#: :func:`pulse_centre_reach` grows a disc to at most this times its radius (a disc nearly along its
#: pulse's ray would meet it metres away)
PULSE_REACH_CAP = 4.0


def pulse_centre_reach(points, normals, primary_origin, primary, chunk: int = 1 << 20,
                       corners: bool = False) -> np.ndarray:
    """``(n,) float64``: how far each point's disc must reach to hold its own pulse.

    Each point falls in a pulse of the primary's pattern ``primary`` (degrees or a pattern; a
    beam table's elevation bands, its azimuth offsets 0, as the pulse grid takes them) seen from
    ``primary_origin``; the pulse's centre ray and (``corners``) the rays through its four corners
    meet the point's disc plane (normal ``normals[i]``, None: the disc faces the ray) at some
    distance from the point: the largest, times :data:`PULSE_REACH_MARGIN`. A point recorded off
    its pulse's centre (a beam's point a band away from its beam's nominal elevation, a point near
    a cell's corner) has a disc of its neighbours' spacing that rays of its pulse can pass by. Rays
    along the plane count 0 (:data:`PULSE_REACH_CAP` bounds the growth where the caller applies
    it); points outside the pattern get 0.
    """
    pts = np.asarray(points, np.float64)
    o = as_origin(primary_origin, "primary_origin")
    grid = as_pattern(primary).aligned() if not isinstance(primary, (int, float, np.integer, np.floating)) \
        else as_pattern(float(primary))
    nv, nh = grid.shape
    beams = getattr(grid, "has_beams", False)
    if beams:
        edges = np.asarray(grid.band_edges, np.float64)
        zen_mid = np.asarray(grid.row_zenith, np.float64)
    else:
        d_theta, d_phi, th0, th1 = grid.radians
    d_az = 2 * math.pi / nh
    out = np.zeros(len(pts))
    offsets = ((0.5, 0.5), (0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0)) if corners else ((0.5, 0.5),)
    for s in range(0, len(pts), chunk):
        rel = pts[s:s + chunk] - o
        keys, _ = grid.pulse_ids(rel, np.zeros(3))
        ok = keys >= 0
        v, h = keys[ok] // nh, keys[ok] % nh
        p = rel[ok]
        n = None if normals is None else np.asarray(normals[s:s + len(rel)], np.float64)[ok]
        best = np.zeros(len(p))
        for fv, fh in offsets:
            if beams:
                zen = zen_mid[v] if fv == 0.5 else edges[v + int(fv)]
            else:
                zen = np.minimum(th0 + (v + fv) * d_theta, th1)
            az = (h + fh) * (d_az if beams else d_phi)
            st = np.sin(zen)
            d = np.column_stack([st * np.cos(az), st * np.sin(az), np.cos(zen)])
            if n is None:  # facing the ray: the distance from the ray
                t = np.einsum("ij,ij->i", p, d)
            else:
                dn = np.einsum("ij,ij->i", d, n)
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = np.einsum("ij,ij->i", p, n) / dn
                t = np.where(np.isfinite(t) & (t > 0), t, np.nan)
            r = np.linalg.norm(t[:, None] * d - p, axis=1)
            best = np.fmax(best, r)
        out[s:s + chunk][ok] = np.where(np.isfinite(best), best * PULSE_REACH_MARGIN, 0.0)
    return out
