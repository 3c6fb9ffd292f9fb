"""Per-pulse estimators: one return per pulse from a union of frames.

``nearest``
    The nearest point per pulse: SLR's rule (the binning backend's reduction),
    the reference.
``fpa``
    PCGen's *first-peak average*: the nearest cluster of points along the
    pulse, its points averaged. The points of one pulse are taken in order of
    range; the cluster is the run from the nearest point while each next point
    lies within ``gap`` metres of the one before; the return is the cluster's
    centroid. On a dense union a pulse's candidates spread over the whole
    footprint of the pulse (on the ground, metres in range at grazing
    incidence): the nearest of them is the footprint's near edge, biased
    short; the centroid sits near the footprint's middle, where the real beam
    hits.
``embree-knn``
    The embree backend on the union with its defaults (kNN discs).

Each returns a :class:`PulseReturns`: the occupied pulses (flat ids), their
ranges, the returned points (in the scanner's frame) and, for carrying
attributes, the union point each return stands for (the nearest point of the
pulse, or the disc's point).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from ..backends import prepare
from ..errors import InputValueError

__all__ = ["PulseReturns", "estimate", "merge_nearest", "ESTIMATORS", "FPA_GAP", "nearest_returns", "fpa_returns",
           "embree_returns"]

ESTIMATORS = ("nearest", "fpa", "embree-knn")
#: the fpa cluster's largest step between consecutive ranges (m)
FPA_GAP = 0.1


@dataclass
class PulseReturns:
    """One return per occupied pulse, in ascending pulse id."""

    keys: np.ndarray      # (m,) int64 flat pulse ids
    ranges: np.ndarray    # (m,) float64
    points: np.ndarray    # (m, 3) float64, scanner frame
    index: np.ndarray     # (m,) int64 into the union: the point whose attributes the return carries

    def __len__(self) -> int:
        return len(self.keys)

    def image(self, pattern) -> np.ndarray:
        """The range image (rows by columns; NaN: no return)."""
        rows, cols = pattern.shape
        img = np.full(rows * cols, np.nan)
        img[self.keys] = self.ranges
        return img.reshape(rows, cols)


def _sorted(keys, ranges, index, points):
    order = np.argsort(keys, kind="stable")
    return PulseReturns(keys[order].astype(np.int64), ranges[order], points[order], index[order].astype(np.int64))


def nearest_returns(points, pattern) -> PulseReturns:
    """The nearest point per pulse (SLR's rule) of ``points`` (float64, scanner frame)."""
    points = np.ascontiguousarray(points, np.float64)
    keys, ranges, idx = pattern.reduce(points, np.zeros(3))
    return _sorted(np.asarray(keys), np.asarray(ranges, np.float64), np.asarray(idx), points[idx])


def fpa_returns(points, pattern, gap: float = FPA_GAP) -> PulseReturns:
    """The first-peak average per pulse (module docstring) of ``points`` (float64, scanner frame)."""
    if not gap > 0:
        raise InputValueError(f"the fpa gap must be > 0 m, got {gap}")
    gap, points = float(gap), np.ascontiguousarray(points, np.float64)
    keys, ranges = pattern.pulse_ids(points, np.zeros(3))
    ok = np.flatnonzero(keys >= 0)
    k, r = keys[ok], ranges[ok]
    order = np.lexsort((ok, r, k))  # by pulse, then range, then index (the nearest's tie rule)
    k, r, idx = k[order], r[order], ok[order]
    if not len(k):
        return _sorted(np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3)))
    new_pulse = np.r_[True, k[1:] != k[:-1]]
    breaks = new_pulse | np.r_[False, np.diff(r) > gap]
    cluster = np.cumsum(breaks) - 1
    pulse_no = np.cumsum(new_pulse) - 1
    first_cluster = cluster[np.flatnonzero(new_pulse)]
    member = cluster == first_cluster[pulse_no]
    n = np.bincount(pulse_no[member], minlength=len(first_cluster)).astype(np.float64)
    p = points[idx[member]]
    centroid = np.column_stack([np.bincount(pulse_no[member], weights=p[:, j], minlength=len(n)) for j in range(3)])
    centroid /= n[:, None]
    rng = np.linalg.norm(centroid, axis=1)
    first = np.flatnonzero(new_pulse)
    return _sorted(k[first], rng, idx[first], centroid)


def embree_returns(points, pattern) -> PulseReturns:
    """The embree backend's scan (its default kNN discs) of ``points`` (float64, scanner frame)."""
    points = np.ascontiguousarray(points, np.float64)
    sc = prepare(points, "embree").scan(np.zeros(3), pattern)
    idx = np.asarray(sc.indices)
    return _sorted(np.asarray(sc.pulse_ids), np.asarray(sc.ranges, np.float64), idx, points[idx])


def merge_nearest(parts) -> tuple[PulseReturns, np.ndarray]:
    """The nearest rule over a union given as parts: each part's :class:`PulseReturns` by
    ``nearest`` with ``index`` already offset to the union's numbering (parts in union order).
    Equal to ``estimate(union, pattern, "nearest")``: per pulse the least range, ties to the
    lowest index. Returns it and each return's position in the parts' returns, concatenated."""
    if not parts:
        return PulseReturns(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64)), \
            np.zeros(0, np.int64)
    # one pass per part over a dense table of the pulses (each part holds a pulse at most once;
    # no sort of the parts' keys: that was a tenth of a 61-frame window's time)
    size = 1 + max((int(p.keys[-1]) for p in parts if len(p.keys)), default=-1)
    best_r = np.full(size, np.inf)
    best_i = np.full(size, np.iinfo(np.int64).max)
    best_at = np.full(size, -1, np.int64)
    at = 0
    for p in parts:
        slot = p.keys
        better = (p.ranges < best_r[slot]) | ((p.ranges == best_r[slot]) & (p.index < best_i[slot]))
        s = slot[better]
        best_r[s], best_i[s], best_at[s] = p.ranges[better], p.index[better], at + np.flatnonzero(better)
        at += len(p.keys)
    keys = np.flatnonzero(best_at >= 0)
    best_at = best_at[keys]
    pts = np.concatenate([p.points for p in parts])
    return PulseReturns(keys, best_r[keys], pts[best_at], best_i[keys]), best_at


def estimate(points, pattern, estimator: str = "nearest", gap: float = FPA_GAP) -> PulseReturns:
    """One return per pulse of ``pattern`` from ``points`` (float64, in the scanner's frame:
    the scanner at the origin) by ``estimator`` (:data:`ESTIMATORS`; ``gap``: fpa's)."""
    pts = np.ascontiguousarray(points, np.float64)
    rules = {ESTIMATORS[0]: nearest_returns, ESTIMATORS[1]: partial(fpa_returns, gap=gap),
             ESTIMATORS[2]: embree_returns}
    if estimator not in rules:
        raise InputValueError(f"unknown estimator {estimator!r}; choose from {list(ESTIMATORS)}")
    return rules[estimator](pts, pattern)
