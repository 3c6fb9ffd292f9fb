"""Fixed-radius neighbour tests on a uniform cell grid.

:class:`CellGrid` buckets a reference cloud into cubic cells a little larger
than a search radius, so that every reference point closer than the radius
to a query point lies in the query's cell or one of its 26 neighbours. A
hash of the occupied cells (open addressing, built in O(n)) keeps memory
proportional to the points, whatever the extent of the cloud.

It answers the question the coverage/precision metrics ask millions of times
per validation pair, "is there a point within 10 cm?", several times faster
than a kd-tree built for the purpose (no tree; an early exit at the first
match; see ``benchmarks/bench_agreement.py``). Distances are computed from
the input coordinates in float64, exactly as a brute-force loop would, so the
answers are the same, points exactly at the radius included (strictly closer
counts).

Examples
--------
>>> import numpy as np
>>> grid = CellGrid(np.array([[0.0, 0, 0], [1.0, 0, 0]]), 0.1)
>>> grid.any_within(np.array([[0.05, 0, 0], [0.5, 0, 0], [1.0, 0.1, 0]]))
array([ True, False, False])
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..arrays import as_points, bounds
from ..errors import InputValueError

__all__ = ["CellGrid", "GridUnsuitable"]

#: cells are this much larger than the radius, relative: the floor of a
#: coordinate divided by the cell size may be off by rounding, and this margin
#: keeps two points closer than the radius within one cell of each other
_MARGIN = 1e-6
#: cell indices are packed into an int64 key, 21 bits per axis
_AXIS_BITS = 21
_HASH = np.uint64(0x9E3779B97F4A7C15)


class GridUnsuitable(ValueError):
    """The cloud cannot be gridded at this radius (it spans too many cells);
    use a kd-tree instead."""


class CellGrid:
    """Reference points bucketed in cubic cells of side ``radius * (1 + 1e-6)``.

    Parameters
    ----------
    points : (n, 3) float
        The reference cloud (not copied beyond one reordered float64 copy).
    radius : float
        The largest radius :meth:`any_within` will be asked about (> 0).

    Raises
    ------
    GridUnsuitable
        When the cloud spans more than 2**21 - 3 cells along an axis.
    """

    def __init__(self, points, radius: float):
        if not (math.isfinite(radius) and radius > 0):
            raise InputValueError(f"radius must be a finite number > 0, got {radius!r}")
        pts = as_points(points, "points").astype(np.float64, copy=False)
        self.radius = float(radius)
        self.cell = self.radius * (1 + _MARGIN)
        self.n = len(pts)
        if self.n == 0:
            self.lo = np.zeros(3)
            self.dims = np.zeros(3, np.int64)
            self._empty = True
            return
        self._empty = False
        # No limit on the coordinates themselves: ``x - lo`` is one correctly
        # rounded subtraction (relative error 2**-53 of the offset inside the
        # box, not of |x|), so a cell index is off by at most ~3e-16 * dims
        # < 1e-9 cells, far inside the 1e-6 margin, at UTM or 1e12 coordinates.
        # one cell of slack on each side: a query's neighbour cells stay inside the key space
        lo, hi = bounds(pts)
        self.lo = lo - self.cell
        span = np.floor((hi - self.lo) / self.cell) + 2  # float first: a tiny radius overflows int64
        if not np.all(span < (1 << _AXIS_BITS) - 1):
            raise GridUnsuitable(f"the cloud spans {span.tolist()} cells of {self.cell:.3g}")
        self.dims = span.astype(np.int64)
        cap = 1 << max(4, int(2 * self.n - 1).bit_length())
        self._keys = np.full(cap, -1, np.int64)
        self._start = np.zeros(cap, np.int64)
        self._count = np.zeros(cap, np.int64)
        self._points = np.empty((self.n, 3))
        _build(pts, self.lo, 1.0 / self.cell, self._keys, self._start, self._count, self._points)

    @property
    def nbytes(self) -> int:
        if self._empty:
            return 0
        return self._keys.nbytes + self._start.nbytes + self._count.nbytes + self._points.nbytes

    def any_within(self, query, radius: float | None = None) -> np.ndarray:
        """``(m,) bool``: whether each query point has a reference point
        strictly closer than ``radius`` (default: the grid's; at most that)."""
        r = self.radius if radius is None else float(radius)
        if not (r > 0 and r <= self.radius):
            raise InputValueError(f"radius must be in (0, {self.radius}], got {radius!r}")
        q = as_points(query, "query").astype(np.float64, copy=False)
        out = np.zeros(len(q), bool)
        if self._empty or len(q) == 0:
            return out
        _any_within(np.ascontiguousarray(q), self.lo, 1.0 / self.cell, self.dims, r, self._keys,
                    self._start, self._count, self._points, out)
        return out


@njit(cache=True, inline="always")
def _slot(key, shift):
    """Fibonacci hashing: the product's top bits (those that depend on every bit of the key)."""
    return np.int64((np.uint64(key) * _HASH) >> np.uint64(shift))


@njit(cache=True, inline="always")
def _shift(capacity):
    """64 - log2(capacity), for a power-of-two capacity."""
    b = 0
    while (1 << b) < capacity:
        b += 1
    return 64 - b


@njit(cache=True, inline="always")
def _key(ix, iy, iz):
    return (ix << (2 * _AXIS_BITS)) | (iy << _AXIS_BITS) | iz


@njit(cache=True, inline="always")
def _find(keys, key, shift, mask):
    s = _slot(key, shift)
    while True:
        k = keys[s]
        if k == key:
            return s
        if k == -1:
            return -1
        s = (s + 1) & mask


@njit(cache=True)
def _build(pts, lo, inv, keys, start, count, out):
    """Bucket ``pts`` by cell: a counting sort through the cell hash."""
    n = pts.shape[0]
    mask = keys.shape[0] - 1
    shift = _shift(keys.shape[0])
    slot_of = np.empty(n, np.int64)
    for i in range(n):
        key = _key(np.int64(math.floor((pts[i, 0] - lo[0]) * inv)),
                   np.int64(math.floor((pts[i, 1] - lo[1]) * inv)),
                   np.int64(math.floor((pts[i, 2] - lo[2]) * inv)))
        s = _slot(key, shift)
        while keys[s] != -1 and keys[s] != key:
            s = (s + 1) & mask
        keys[s] = key
        count[s] += 1
        slot_of[i] = s
    total = 0
    for s in range(keys.shape[0]):
        start[s] = total
        total += count[s]
    fill = start.copy()
    for i in range(n):
        s = slot_of[i]
        j = fill[s]
        fill[s] = j + 1
        out[j, 0], out[j, 1], out[j, 2] = pts[i, 0], pts[i, 1], pts[i, 2]


@njit(cache=True, parallel=True)
def _any_within(q, lo, inv, dims, r, keys, start, count, pts, out):
    mask = keys.shape[0] - 1
    shift = _shift(keys.shape[0])
    for i in prange(q.shape[0]):
        x, y, z = q[i, 0], q[i, 1], q[i, 2]
        fx = math.floor((x - lo[0]) * inv)
        fy = math.floor((y - lo[1]) * inv)
        fz = math.floor((z - lo[2]) * inv)
        # a query more than a cell outside the reference's box has no neighbour
        if not (fx >= 0 and fy >= 0 and fz >= 0 and fx < dims[0] and fy < dims[1] and fz < dims[2]):
            continue
        cx, cy, cz = np.int64(fx), np.int64(fy), np.int64(fz)
        found = False
        for t in range(27):
            # the query's own cell first: most matches are there
            t2 = (t + 13) % 27
            dx = t2 % 3 - 1
            dy = (t2 // 3) % 3 - 1
            dz = t2 // 9 - 1
            ix, iy, iz = cx + dx, cy + dy, cz + dz
            if ix < 0 or iy < 0 or iz < 0:
                continue
            s = _find(keys, _key(ix, iy, iz), shift, mask)
            if s < 0:
                continue
            for j in range(start[s], start[s] + count[s]):
                ax = x - pts[j, 0]
                ay = y - pts[j, 1]
                az = z - pts[j, 2]
                if math.sqrt(ax * ax + ay * ay + az * az) < r:
                    found = True
                    break
            if found:
                break
        out[i] = found
