"""The paper's subsampling method, as published: sort by (h, v, R), keep the first
point of every bin. O(N log N). Used as the baseline in the benchmarks."""

from __future__ import annotations

import numpy as np


def sort_based_scan(points, origin, pattern):
    """Indices (ascending) kept by the paper's sort-based method.

    Same bin definitions as slr_ray (float64 after subtracting the origin);
    ties in range go to the lowest index (the sort is stable on the index).
    """
    d = np.asarray(points, dtype=np.float64) - np.asarray(origin, dtype=np.float64)
    r = np.sqrt((d * d).sum(axis=1))
    theta = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
    phi = np.arctan2(d[:, 1], d[:, 0])
    phi[phi < 0] += 2 * np.pi
    d_theta, d_phi, th0, th1 = pattern.radians
    rmin, rmax = pattern.range_limits
    nv, nh = pattern.shape
    seen = (r > 0) & (r >= rmin) & (r <= rmax) & (theta >= th0) & (theta <= th1)
    idx = np.flatnonzero(seen)
    v = np.minimum(np.floor((theta[idx] - th0) / d_theta), nv - 1).astype(np.int64)
    h = np.minimum(np.floor(phi[idx] / d_phi), nh - 1).astype(np.int64)
    order = np.lexsort((r[idx], v, h))  # last key sorts first: h, then v, then R
    hs, vs = h[order], v[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = (hs[1:] != hs[:-1]) | (vs[1:] != vs[:-1])
    return np.sort(idx[order[first]])
