"""The TSDF-mesh converter of lidar_transfer (Langer et al., IROS 2020), the published non-learned peer.

Langer, Milioto, Haag, Behley, Stachniss, *Domain Transfer for Semantic Segmentation of LiDAR Data
using Deep Neural Networks*, IROS 2020; code github.com/PRBonn/lidar_transfer (read at its HEAD).
Its default adaption (``config/lidar_transfer.yaml``: ``adaption: 'mergemesh'``, ``voxel_size:
0.05``, ``voxel_bounds: [-50, 50, -50, 50, -5, 5]``) does, in
``auxiliary/laserscan.py`` (``MultiSemLaserScan.open_multiple_scans`` and ``deform``, branch
``'mergemesh'``) and ``auxiliary/fusion_lidar.py`` (``TSDFVolume``, after Andy Zeng's
tsdf-fusion-python):

1. **Accumulate**: every source scan moved into the world by its pose, the moving classes dropped
   from all but the primary (``open_multiple_scans``), then all merged and moved into the *target's*
   frame (``merged.apply_inv_pose()``).
2. **One range image from the target's origin**: the merged cloud projected spherically
   (``do_range_projection_new``, ``method="depth"``: the nearest point per pixel), rows over the
   target's vertical field of view (points outside it removed), columns ``W`` uniform in azimuth
   (``proj_x = 0.5 * (yaw / pi + 1) * W``, ``yaw = -atan2(y, x)``); with ``beam_angles`` a point's
   elevation snapped to the nearest beam's.
3. **Fuse**: the image integrated *projectively* into a dense TSDF (``TSDFVolume.integrate``, CPU
   branch): every voxel centre projected into the image from the origin, ``depth_diff = D[pixel]
   - |voxel|``; voxels with no depth or more than the truncation behind it skipped (they keep the
   volume's initial value, 1), the others averaged with weight 1 to ``min(1, depth_diff / trunc)``.
   The truncation is ``voxel_size * 5`` (``_trunc_margin``); no normals, no point-to-plane distance.
   The volume spans ``voxel_bounds`` cut to the merged cloud's rounded bounds. The label rides on
   each voxel (the class-aware branch) from the pixel it projects to.
4. **Mesh**: ``skimage.measure.marching_cubes_lewiner(tsdf_vol, level=0)`` (``get_mesh``).
5. **Ray-cast the target**: the target's rays from the origin (``create_rays``) through a BVH of the
   mesh (``auxiliary/raytracer/RayTracer.cpp``: the first hit); a hit takes the label of its face's
   first vertex (``throw_rays_at_mesh``), the voxel nearest that vertex.

Here, in numpy and numba:

- steps 1 and 2 as theirs, on the union the sequence gives (in the target's frame, the moving
  classes already dropped by the union), the image's rows the target's own beams (a point's row is
  the beam nearest in elevation, their ``beam_angles`` snapping; a grid pattern's rows likewise),
  its columns the target's column count, uniform in azimuth as theirs;
- step 3 is not stored: with one image integrated once (weight 1 on an empty volume), every voxel's
  value is a function of the image alone, ``min(1, (D - r) / trunc)`` or the initial 1; the cast
  evaluates it at the voxel centres it needs, so a 100 m x 100 m x 10 m volume of 5 cm voxels
  (800 M voxels, their GPU's) costs no memory;
- steps 4 and 5 are one: **no mesh**. scikit-image (their marching cubes, and trimesh's
  ``matrix_to_marching_cubes``) is not a dependency, and Open3D's TSDF volumes
  (``ScalableTSDFVolume``, ``VoxelBlockGrid``) integrate pinhole depth images only, not a
  spherical range image. Each target ray instead marches through the volume to the zero crossing
  of the TSDF interpolated trilinearly between voxel centres, what a renderer of a TSDF does: the
  crossing lies on the same level set marching cubes triangulates (marching cubes interpolates
  linearly along the voxel edges, trilinear interpolation inside the cells; they agree on every
  edge and differ inside a cell by a fraction of a voxel). A voxel's value is below 1 only within
  the truncation of its pixel's depth, so a ray is marched only about the depths of the pixels near
  its own (two rows and four columns either side, wider where they are near, so that the window spans
  two voxels: up to 8 rows and 64 columns), nearest first, by steps of half the TSDF's distance (at
  least half a voxel); a surface seen through a pixel further off the ray is missed;
- the labels and every other attribute: a return carries the union point nearest its hit among
  the image's points (those the surface was fused from), where theirs takes the voxel of a face's
  first vertex, whose label is that of the image pixel the voxel projects to.

The volume's bounds are theirs (``voxel_bounds``: 50 m either side in x and y, 5 m in z, cut to
the union's rounded bounds): no return beyond them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..arrays import count_nonfinite_rows, refuse_nonfinite_rows
from ..errors import InputValueError
from ..metrics import nearest
from .estimators import PulseReturns

__all__ = ["TSDF_VOXEL", "TSDF_TRUNCATION", "TSDF_XY_BOUND", "TSDF_Z_BOUND", "RangeImage", "range_image",
           "tsdf_returns"]

#: lidar_transfer's ``voxel_size`` (m)
TSDF_VOXEL = 0.05
#: its truncation, five voxels (m)
TSDF_TRUNCATION = 5 * TSDF_VOXEL
#: its ``voxel_bounds``: half-widths in x, y and in z about the target's origin (m)
TSDF_XY_BOUND = 50.0
TSDF_Z_BOUND = 5.0
#: the window of image pixels whose depths bound a ray's march: rows and columns either side
_WINDOW_ROWS, _WINDOW_COLUMNS = 2, 4


class RangeImage:
    """The image the TSDF is fused from: the nearest union point per pixel, seen from the origin.

    ``depth`` (rows, columns; 0: no point), ``index`` (the union point; -1), ``edges`` (the rows'
    elevation edges, ascending, radians: row ``i`` of ``rows - 1 - searchsorted``; the first row
    the highest, as the patterns' are) and ``columns``.
    """

    def __init__(self, depth, index, edges):
        self.depth, self.index, self.edges = depth, index, edges
        self.columns = depth.shape[1]


def _row_edges(pattern) -> np.ndarray:
    """Elevation edges (ascending, radians) of ``pattern``'s rows: midway between neighbouring rows'
    elevations, the outer ones half a gap beyond (a beam table's rows need not be uniform)."""
    d, v, _ = pattern.rays()
    el = np.zeros(pattern.shape[0])
    np.add.at(el, v, np.arcsin(np.clip(d[:, 2], -1, 1)))
    el /= np.maximum(np.bincount(v, minlength=len(el)), 1)
    e = np.sort(el)
    if len(e) == 1:
        return np.array([e[0] - 1e-3, e[0] + 1e-3])
    mid = (e[1:] + e[:-1]) / 2
    return np.r_[e[0] - (mid[0] - e[0]), mid, e[-1] + (e[-1] - mid[-1])]


@njit(cache=True, inline="always", error_model="numpy")
def _pixel(x, y, z, edges, columns):
    """(row, column, range) of a point seen from the origin; row -1 outside the rows' elevations."""
    r = math.sqrt(x * x + y * y + z * z)
    if r == 0.0:
        return -1, -1, r
    el = math.asin(min(1.0, max(-1.0, z / r)))
    if el < edges[0] or el > edges[-1]:
        return -1, -1, r
    k = np.searchsorted(edges, el)  # edges[k-1] < el <= edges[k]
    rows = edges.shape[0] - 1
    row = rows - max(k, 1)
    yaw = -math.atan2(y, x)
    col = int(math.floor(0.5 * (yaw / math.pi + 1.0) * columns))
    col = min(columns - 1, max(0, col))
    return row, col, r


@njit(cache=True, error_model="numpy")
def _image(points, edges, columns, depth, index):
    rows = edges.shape[0] - 1
    for i in range(points.shape[0]):
        row, col, r = _pixel(points[i, 0], points[i, 1], points[i, 2], edges, columns)
        if row < 0 or row >= rows:
            continue
        if index[row, col] < 0 or r < depth[row, col]:
            depth[row, col] = r
            index[row, col] = i


def range_image(points, pattern) -> RangeImage:
    """The nearest point of ``points`` (the sensor's frame) per pixel of ``pattern``'s rows by its
    column count, from the origin (lidar_transfer's ``do_range_projection_new``, module docstring)."""
    edges = _row_edges(pattern)
    depth = np.zeros((len(edges) - 1, pattern.shape[1]))
    index = np.full(depth.shape, -1, np.int64)
    _image(np.ascontiguousarray(points, np.float64), edges, pattern.shape[1], depth, index)
    return RangeImage(depth, index, edges)


@njit(cache=True, inline="always", error_model="numpy")
def _tsdf(i, j, k, vox, trunc, lo, hi, depth, edges, columns):
    """The fused TSDF at voxel centre ``(i, j, k) * vox``: 1 outside the volume, with no depth or
    more than ``trunc`` behind it (the volume's initial value), else ``min(1, (D - r) / trunc)``."""
    x, y, z = i * vox, j * vox, k * vox
    if x < lo[0] or x > hi[0] or y < lo[1] or y > hi[1] or z < lo[2] or z > hi[2]:
        return 1.0
    row, col, r = _pixel(x, y, z, edges, columns)
    if row < 0:
        return 1.0
    d = depth[row, col]
    if d <= 0.0:
        return 1.0
    diff = d - r
    if diff < -trunc:
        return 1.0
    return min(1.0, diff / trunc)


@njit(cache=True, inline="always", error_model="numpy")
def _trilinear(px, py, pz, vox, trunc, lo, hi, depth, edges, columns):
    gx, gy, gz = px / vox, py / vox, pz / vox
    i0, j0, k0 = math.floor(gx), math.floor(gy), math.floor(gz)
    fx, fy, fz = gx - i0, gy - j0, gz - k0
    f = 0.0
    for a in range(2):
        wa = fx if a else 1.0 - fx
        for b in range(2):
            wb = fy if b else 1.0 - fy
            for c in range(2):
                wc = fz if c else 1.0 - fz
                f += wa * wb * wc * _tsdf(i0 + a, j0 + b, k0 + c, vox, trunc, lo, hi, depth, edges, columns)
    return f


@njit(cache=True, inline="always", error_model="numpy")
def _window(row, col, wr, wc, depth, buf):
    """The depths of the image within ``wr`` rows and ``wc`` columns of ``(row, col)`` (columns wrap) into
    ``buf``; returns how many."""
    rows, columns = depth.shape
    m = 0
    for rr in range(max(0, row - wr), min(rows, row + wr + 1)):
        for cc in range(col - wc, col + wc + 1):
            d = depth[rr, cc % columns]
            if d > 0.0:
                buf[m] = d
                m += 1
    return m


@njit(cache=True, parallel=True, error_model="numpy")
def _march(dirs, vox, trunc, lo, hi, rmin, rmax, depth, edges, row_step, out):
    """Each ray's range to the first zero crossing (positive to negative) of the trilinear TSDF (NaN:
    none). A voxel's value is below 1 only within the truncation of its pixel's depth, so a ray is
    marched only about the depths of the pixels near its own (two rows and four columns either side,
    more where they are near: the window spans two voxels at the nearest of them, up to 8 rows and 64
    columns), nearest first;
    each stretch by steps of half the TSDF's distance (at least half a voxel), the crossing
    interpolated linearly between the last two."""
    rows, columns = depth.shape
    col_step = 2.0 * math.pi / columns
    reach = trunc + 2.0 * vox
    for n in prange(dirs.shape[0]):
        dx, dy, dz = dirs[n, 0], dirs[n, 1], dirs[n, 2]
        out[n] = np.nan
        row, col, _ = _pixel(dx, dy, dz, edges, columns)
        if row < 0:  # beyond the image's rows: the window about the nearest row
            row = 0 if dz > 0 else rows - 1
            col = min(columns - 1, max(0, int(math.floor(0.5 * (-math.atan2(dy, dx) / math.pi + 1.0) * columns))))
        buf = np.empty((2 * _WINDOW_ROWS + 1) * (2 * _WINDOW_COLUMNS + 1))
        m = _window(row, col, _WINDOW_ROWS, _WINDOW_COLUMNS, depth, buf)
        if m == 0:
            continue
        near = max(buf[:m].min(), vox)
        wr = min(4 * _WINDOW_ROWS, max(_WINDOW_ROWS, int(math.ceil(2.0 * vox / (near * row_step)))))
        wc = min(columns // 2, 16 * _WINDOW_COLUMNS, max(_WINDOW_COLUMNS, int(math.ceil(2.0 * vox / (near * col_step)))))
        if wr > _WINDOW_ROWS or wc > _WINDOW_COLUMNS:
            buf = np.empty((2 * wr + 1) * (2 * wc + 1))
            m = _window(row, col, wr, wc, depth, buf)
        cand = np.sort(buf[:m])
        k = 0
        while k < m and np.isnan(out[n]):
            a, b = cand[k] - reach, cand[k] + reach
            while k + 1 < m and cand[k + 1] - reach <= b:  # the stretches that overlap, merged
                k += 1
                b = cand[k] + reach
            k += 1
            t = max(rmin, a)
            b = min(b, rmax)
            f_prev = _trilinear(t * dx, t * dy, t * dz, vox, trunc, lo, hi, depth, edges, columns)
            while t < b:
                t_prev = t
                t += max(0.5 * vox, 0.5 * f_prev * trunc)
                f = _trilinear(t * dx, t * dy, t * dz, vox, trunc, lo, hi, depth, edges, columns)
                if f <= 0.0 < f_prev:
                    out[n] = t_prev + (t - t_prev) * f_prev / (f_prev - f)
                    break
                f_prev = f


def _check(voxel, truncation, xy_bound, z_bound):
    if not (np.isfinite(voxel) and voxel > 0):
        raise InputValueError(f"the TSDF voxel must be > 0 m, got {voxel}")
    if not (np.isfinite(truncation) and truncation >= voxel):
        raise InputValueError(f"the TSDF truncation must be at least one voxel ({voxel} m): a thinner band has "
                              f"no voxel centre behind the surface to change sign; got {truncation}")
    if not (xy_bound > 0 and z_bound > 0):
        raise InputValueError(f"the TSDF volume's bounds must be > 0 m, got {xy_bound} (x, y) and {z_bound} (z)")


def tsdf_returns(points, pattern, voxel: float = TSDF_VOXEL, truncation: float = TSDF_TRUNCATION,
                 xy_bound: float = TSDF_XY_BOUND, z_bound: float = TSDF_Z_BOUND) -> PulseReturns:
    """One return per pulse of ``pattern`` from ``points`` (float64, the target's frame, the target at
    the origin): lidar_transfer's TSDF of the union's range image, cast with the pattern's rays
    (module docstring). A return's ``index`` is the image's point nearest its hit.

    Raises
    ------
    InputValueError
        no points, or a row with NaN or inf; none inside the volume's bounds and the pattern's rows; a
        voxel, truncation or bound that is not a positive length, a truncation under one voxel.
    """
    _check(voxel, truncation, xy_bound, z_bound)
    points = np.ascontiguousarray(points, np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputValueError(f"points: expected (n, 3), got shape {points.shape}")
    if not len(points):
        raise InputValueError("tsdf: no points to fuse (the union is empty)")
    refuse_nonfinite_rows(count_nonfinite_rows(points), len(points))
    img = range_image(points, pattern)
    fused = img.index[img.index >= 0]
    bound = np.array([xy_bound, xy_bound, z_bound])
    lo = np.maximum(-bound, np.floor(points.min(axis=0) + 0.5))  # their voxel_bounds cut to the rounded cloud's
    hi = np.minimum(bound, np.floor(points.max(axis=0) + 0.5))
    inside = np.all((points[fused] >= lo - truncation) & (points[fused] <= hi + truncation), axis=1)
    if not inside.any():
        raise InputValueError(f"tsdf: no point within the pattern's rows and the volume's bounds ({xy_bound} m in x "
                              f"and y, {z_bound} m in z about the target; --tsdf-xy-bound, --tsdf-z-bound)")
    dirs, v, h = pattern.rays()
    dirs = np.ascontiguousarray(dirs, np.float64)
    rmin, rmax = pattern.range_limits
    t = np.empty(len(dirs))
    _march(dirs, float(voxel), float(truncation), lo, hi, float(rmin), float(min(rmax, 1e9)), img.depth, img.edges,
           float(np.diff(img.edges).min()), t)
    hit = np.flatnonzero(np.isfinite(t))
    keys = np.asarray(pattern.ravel(np.c_[v[hit], h[hit]]), np.int64)
    hits = dirs[hit] * t[hit, None]
    _, near = nearest(hits, points[fused])
    order = np.argsort(keys, kind="stable")
    return PulseReturns(keys[order], t[hit][order], hits[order], fused[near][order].astype(np.int64))
