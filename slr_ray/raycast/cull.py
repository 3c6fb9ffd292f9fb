"""Directions that could meet a scene, seen from one ray origin: a cube map of them.

A ray that enters a scene's bounding box and meets nothing still costs a
descent of Embree's BVH (about 40 ns); seen from outside a cloud, or towards
its sky, most rays are of that kind. :func:`voxel_boxes` groups a scene's
primitives once, at build, by voxel of a grid of at most ``GRID`` cells a side
over the scene's bounds, and keeps for each occupied voxel the box of its
primitives' bounds: for a disc its centre plus and minus its radius on every
axis (the bound Embree itself uses), for a triangle its vertices' box; each
box padded far beyond float32 rounding. For a cast, :func:`direction_map`
projects each box from the ray origin onto the six faces of a cube of
``FACE`` x ``FACE`` cells a face and marks every cell the box's directions
could fall in; :func:`could_hit` looks a ray's direction up. A ray whose cell
is unmarked meets no box, hence no primitive: it is a miss without a call into
Embree. Every bound is an over-estimate, so the answers are Embree's own; a
ray whose direction is zero, not finite, or outside float32's comfortable
range (components summing to less than 1e-30 or more than 1e30 in absolute
value: Embree traces a float32 direction, denormal or infinite there) is always
handed to Embree.
"""

from __future__ import annotations

import numpy as np
from numba import get_num_threads, njit, prange

from ..arrays import bounds

__all__ = ["voxel_boxes", "direction_map", "could_hit", "float32_margin", "GRID", "FACE"]

#: voxels a side of the grid (at most GRID**3 boxes; the longest axis gets GRID)
GRID = 64
#: cells a side of one face of the direction cube (0.7 deg at a face's centre, 0.35 at its corners)
FACE = 128
#: a map's marking stops after this many times its cells (then: no culling for that cast)
_BUDGET = 32
#: margin on a projected coordinate (a direction given in float64 and traced in float32 moves by ~1e-7)
_UV_MARGIN = 1e-6
#: directions whose |dx| + |dy| + |dz| lies outside these are handed to Embree: below, float32
#: holds their components as denormals (a few significant bits; Embree traces another direction,
#: and answers hits at NaN distances); above, its arithmetic overflows
_D_MIN = 1e-30
_D_MAX = 1e30
#: bytes of the per-chunk accumulators of :func:`voxel_boxes` at most (a chunk a thread holds 48 B a
#: voxel: 12.6 MB for a full 64^3 grid, 0.8 GB on 64 threads without this bound)
_ACC_BYTES = 64 << 20


@njit(cache=True, inline="always")
def _voxel(x, lo, inv, dims):
    i = int((x - lo) * inv)
    return min(max(i, 0), dims - 1)


@njit(cache=True, parallel=True)
def _accumulate(vertices, faces, n, lo, inv, dims, n_chunks):
    """Per chunk of primitives, the per-voxel min (cols 0-2) and max (3-5) of their bounds."""
    n_cells = dims[0] * dims[1] * dims[2]
    acc = np.empty((n_chunks, n_cells, 6))
    acc[:, :, :3] = np.inf
    acc[:, :, 3:] = -np.inf
    step = (n + n_chunks - 1) // n_chunks
    for c in prange(n_chunks):
        a = acc[c]
        for p in range(c * step, min(n, (c + 1) * step)):
            if faces.shape[0]:  # a triangle: its vertices' box
                v0, v1, v2 = faces[p, 0], faces[p, 1], faces[p, 2]
                x0, x1, x2 = np.float64(vertices[v0, 0]), np.float64(vertices[v1, 0]), np.float64(vertices[v2, 0])
                y0, y1, y2 = np.float64(vertices[v0, 1]), np.float64(vertices[v1, 1]), np.float64(vertices[v2, 1])
                z0, z1, z2 = np.float64(vertices[v0, 2]), np.float64(vertices[v1, 2]), np.float64(vertices[v2, 2])
                xlo, ylo, zlo = min(x0, x1, x2), min(y0, y1, y2), min(z0, z1, z2)
                xhi, yhi, zhi = max(x0, x1, x2), max(y0, y1, y2), max(z0, z1, z2)
                cx, cy, cz = 0.5 * (xlo + xhi), 0.5 * (ylo + yhi), 0.5 * (zlo + zhi)
            else:  # a disc (float4: centre, radius): its centre plus and minus its radius
                cx, cy, cz = np.float64(vertices[p, 0]), np.float64(vertices[p, 1]), np.float64(vertices[p, 2])
                r = np.float64(vertices[p, 3])
                xlo, ylo, zlo, xhi, yhi, zhi = cx - r, cy - r, cz - r, cx + r, cy + r, cz + r
            cell = ((_voxel(cz, lo[2], inv, dims[2]) * dims[1] + _voxel(cy, lo[1], inv, dims[1])) * dims[0]
                    + _voxel(cx, lo[0], inv, dims[0]))
            a[cell, 0] = min(a[cell, 0], xlo)
            a[cell, 1] = min(a[cell, 1], ylo)
            a[cell, 2] = min(a[cell, 2], zlo)
            a[cell, 3] = max(a[cell, 3], xhi)
            a[cell, 4] = max(a[cell, 4], yhi)
            a[cell, 5] = max(a[cell, 5], zhi)
    return acc


@njit(cache=True)
def _merge(acc):
    """The occupied voxels' boxes, ``(m, 6)``, from the chunks' accumulators."""
    n_chunks, n_cells = acc.shape[0], acc.shape[1]
    out = np.empty((n_cells, 6))
    m = 0
    for cell in range(n_cells):
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        for c in range(n_chunks):
            lo0 = min(lo0, acc[c, cell, 0])
            lo1 = min(lo1, acc[c, cell, 1])
            lo2 = min(lo2, acc[c, cell, 2])
            hi0 = max(hi0, acc[c, cell, 3])
            hi1 = max(hi1, acc[c, cell, 4])
            hi2 = max(hi2, acc[c, cell, 5])
        if lo0 <= hi0:
            out[m, 0], out[m, 1], out[m, 2], out[m, 3], out[m, 4], out[m, 5] = lo0, lo1, lo2, hi0, hi1, hi2
            m += 1
    return out[:m].copy()


def float32_margin(lo, hi) -> float:
    """A margin far beyond float32 rounding for geometry within ``(lo, hi)`` (float64, scene frame):
    1e-5 of the extent and of the coordinates' magnitude, and 1 micrometre. Embree's own bounds
    are conservative in float32, so nothing it could report a hit for lies beyond it."""
    return 1e-5 * float(np.max(hi - lo)) + 1e-5 * float(max(np.abs(lo).max(), np.abs(hi).max())) + 1e-6


def voxel_boxes(vertices: np.ndarray, faces: np.ndarray | None, n: int, grid: int = GRID,
                extent=None) -> np.ndarray:
    """``(m, 6)`` float64 boxes ``(lo, hi)`` (scene frame) that hold every primitive's bounds,
    one per occupied voxel of a grid of at most ``grid`` cells a side.

    Parameters
    ----------
    vertices : float32 array
        Discs: Embree's ``(n, 4)`` vertex buffer (centre, radius); triangles:
        the ``(v, 3)`` vertex buffer.
    faces : (n, 3) uint32 or None
        Triangles' vertex indices; None for discs.
    n : int
        Primitives.
    extent : (lo, hi), optional
        Bounds of the vertex rows (the scene's, computed once there); default: computed here.
    """
    if n == 0:
        return np.zeros((0, 6))
    f = np.zeros((0, 3), np.uint32) if faces is None else faces
    lo, hi = bounds(vertices[:n] if faces is None else vertices[:int(f[:n].max()) + 1]) if extent is None else extent
    extent = float(np.max(hi - lo))
    cell = extent / grid if extent > 0 else 1.0
    dims = np.maximum(1, np.minimum(grid, np.ceil((hi - lo) / cell).astype(np.int64)))
    n_chunks = _chunks(n, int(np.prod(dims)), get_num_threads())
    boxes = _merge(_accumulate(vertices, f, n, lo, 1.0 / cell, dims, n_chunks))
    pad = float32_margin(boxes[:, :3].min(axis=0), boxes[:, 3:].max(axis=0))
    boxes[:, :3] -= pad
    boxes[:, 3:] += pad
    return boxes


def _chunks(n: int, n_cells: int, threads: int) -> int:
    """Chunks of primitives :func:`voxel_boxes` accumulates in parallel: one a thread, one per
    65,536 primitives, and no more than ``_ACC_BYTES`` of accumulators (48 B a voxel a chunk)."""
    return max(1, min(threads, n // 65536 + 1, _ACC_BYTES // (48 * n_cells)))


@njit(cache=True, inline="always")
def _range(lo_j, hi_j, lo_i, hi_i):
    """Bounds on x_j / x_i over the box's points with x_i > 0 (``hi_i > 0``)."""
    if hi_j > 0.0:
        top = hi_j / lo_i if lo_i > 0.0 else np.inf
    else:
        top = hi_j / hi_i
    if lo_j < 0.0:
        bottom = lo_j / lo_i if lo_i > 0.0 else -np.inf
    else:
        bottom = lo_j / hi_i
    return bottom - _UV_MARGIN, top + _UV_MARGIN


@njit(cache=True, inline="always")
def _cell(u, face):
    """The cell of a finite ``u`` in [-1, 1] (clamped: the last cell holds +1)."""
    return min(max(int((u + 1.0) * (0.5 * face)), 0), face - 1)


@njit(cache=True)
def direction_map(boxes, origin, face=FACE, budget=_BUDGET):
    """``(6 * face * face,)`` uint8: 1 where a direction from ``origin`` (scene frame, the
    origin Embree traces from) could meet one of ``boxes``. Face ``2 * axis + (0 for +,
    1 for -)``; on the face of axis ``i``, ``u = d[(i + 1) % 3] / |d[i]|`` and ``v = d[(i + 2) % 3] / |d[i]|``,
    rows ``v``, columns ``u``.

    Marking stops after ``budget`` times the map's cells (large boxes that overlap,
    e.g. long triangles from all over a scene): the map is then empty, which
    :func:`could_hit` reads as "any direction could hit" (no culling, no error)."""
    out = np.zeros(6 * face * face, np.uint8)
    left = budget * out.shape[0]
    lo = np.empty(3)
    hi = np.empty(3)
    for b in range(boxes.shape[0]):
        for a in range(3):
            lo[a] = boxes[b, a] - origin[a]
            hi[a] = boxes[b, a + 3] - origin[a]
        for i in range(3):
            j = (i + 1) % 3
            k = (i + 2) % 3
            for s in range(2):
                lo_i, hi_i = (lo[i], hi[i]) if s == 0 else (-hi[i], -lo[i])
                if not hi_i > 0.0:
                    continue  # no point of the box on this side
                u0, u1 = _range(lo[j], hi[j], lo_i, hi_i)
                v0, v1 = _range(lo[k], hi[k], lo_i, hi_i)
                if u0 > 1.0 or u1 < -1.0 or v0 > 1.0 or v1 < -1.0:
                    continue
                c0, c1 = _cell(max(u0, -1.0), face), _cell(min(u1, 1.0), face)
                r0, r1 = _cell(max(v0, -1.0), face), _cell(min(v1, 1.0), face)
                base = (2 * i + s) * face * face
                left -= (r1 - r0 + 1) * (c1 - c0 + 1)
                if left < 0:
                    return np.zeros(0, np.uint8)
                for r in range(r0, r1 + 1):
                    row = base + r * face
                    for c in range(c0, c1 + 1):
                        out[row + c] = 1
    return out


@njit(cache=True, inline="always")
def could_hit(dmap, face, dx, dy, dz):
    """Whether direction ``d`` falls in a marked cell of ``dmap`` (:func:`direction_map`);
    True for an empty map (no culling), a zero, non-finite, tiny or huge direction
    (``_D_MIN``, ``_D_MAX``). Past one
    test of the direction (taken almost never), the cell is found without branches
    (selects; 2-3 ns a ray)."""
    if dmap.shape[0] == 0:
        return True
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    if not (ax + ay + az >= _D_MIN and ax + ay + az <= _D_MAX):
        return True  # zero, infinite, NaN, float32-denormal or huge: Embree's answer (and no NaN below)
    on_x = (ax >= ay) & (ax >= az)
    on_y = (not on_x) & (ay >= az)
    m = ax if on_x else (ay if on_y else az)
    u = dy if on_x else (dz if on_y else dx)
    v = dz if on_x else (dx if on_y else dy)
    neg = (dx < 0.0) if on_x else ((dy < 0.0) if on_y else (dz < 0.0))
    f = (0 if on_x else (2 if on_y else 4)) + (1 if neg else 0)
    inv = 1.0 / m
    return dmap[(f * face + _cell(v * inv, face)) * face + _cell(u * inv, face)] != 0
