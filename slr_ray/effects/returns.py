"""Beam divergence and multiple returns: a pulse is a cone, sampled by sub-rays.

As HELIOS++ does (``FullWaveformPulseRunnable::computeSubrays``), the cone
of full angle ``divergence`` is sampled in concentric rings: ring 0 is the
pulse's axis, ring ``k`` holds ``6 k`` sub-rays at ``k`` ring steps from it
(HELIOS++: ``(int)(2 pi) * k`` rays at ``k * divergence / beamSampleQuality``).
Here the outer ring's cells end at the cone's edge (ring step ``half-angle /
(rings - 1/2)``) and every sub-ray carries the area of its cell, so a
return's *footprint share* is the share of the cone's cross-section it
covers (a uniform, top-hat beam; the centre cell is a quarter of a ring
step's disc, each ring cell ``pi / 3`` ring steps squared).

Each sub-ray meets the first disc along it (the embree backend's discs,
:meth:`~slr_ray.backends.embree.DiscScanner.cast`). A pulse's hits, sorted
by distance, are grouped into returns where consecutive hits lie less than
``separation`` apart (HELIOS++ finds peaks in a simulated waveform; a
receiver cannot separate two echoes closer than about its pulse length).
A return reports

* its range: the share-weighted mean distance of its hits, along the pulse's
  axis (a unit reports a range in its beam's direction);
* its point: the point whose discs took most of its share (attributes,
  labels and intensity follow it);
* its share of the footprint, and its strength: share times the point's
  intensity where the cloud has intensity, the share alone otherwise.

Returns below ``min_share`` are not detected. The rest are numbered along
the range (``return_number`` 1 = first, ``number_of_returns``), as LAS
records them.

The binning backend has no footprint beyond its pulse bin: it keeps one
point per bin and cannot split a pulse into returns; a cone wider than the
bin would need the points of neighbouring bins, which it never compares.
Divergence and multiple returns need the embree backend.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["footprint_samples", "subray_directions", "group_returns", "select_returns"]


def footprint_samples(divergence_rad: float, rings: int):
    """Sub-rays of a cone: angular offsets from its axis and their footprint weights.

    Returns
    -------
    offsets : (s, 2) float64
        ``(angle from the axis, angle around it)``, radians; ``s = 1 + 3 rings (rings - 1)``.
    weights : (s,) float64
        The share of the cone's cross-section each sub-ray stands for (sum 1).
    """
    half = 0.5 * float(divergence_rad)
    if rings == 1:
        return np.zeros((1, 2)), np.ones(1)
    step = half / (rings - 0.5)
    off, w = [(0.0, 0.0)], [0.25 * math.pi * step * step]
    for k in range(1, rings):
        n = 6 * k
        for j in range(n):
            off.append((k * step, 2 * math.pi * j / n))
            w.append(2 * math.pi * k * step * step / n)
    w = np.asarray(w)
    return np.asarray(off), w / w.sum()


def _frames(d):
    """Two unit vectors orthogonal to each direction and to each other."""
    helper = np.where(np.abs(d[:, [2]]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(d, u)


def subray_directions(directions, offsets) -> np.ndarray:
    """``(m * s, 3)`` sub-ray unit vectors, pulse-major: the ``s`` sub-rays of
    ``offsets`` around each of the ``m`` pulse ``directions``."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    u, w = _frames(d)
    a, b = offsets[:, 0], offsets[:, 1]
    ca, sa = np.cos(a), np.sin(a)
    out = (ca[None, :, None] * d[:, None, :]
           + (sa * np.cos(b))[None, :, None] * u[:, None, :]
           + (sa * np.sin(b))[None, :, None] * w[:, None, :])
    return out.reshape(-1, 3)


@njit(cache=True)
def _group(idx, t, weights, strength_of, separation, min_share):
    """Per pulse (row of idx/t, s sub-rays): returns as flat arrays."""
    m, s = idx.shape
    cap = m * s
    pulse = np.empty(cap, np.int64)
    rng = np.empty(cap)
    share = np.empty(cap)
    point = np.empty(cap, np.int64)
    strength = np.empty(cap)
    rnum = np.empty(cap, np.int64)
    nret = np.empty(cap, np.int64)
    k = 0
    for p in range(m):
        order = np.argsort(t[p])
        n_hit = 0
        for q in range(s):
            if idx[p, order[q]] >= 0:
                n_hit += 1
        first_of_pulse = k
        q = 0
        while q < n_hit:
            # one group: consecutive hits closer than separation
            e = q + 1
            while e < n_hit and t[p, order[e]] - t[p, order[e - 1]] < separation:
                e += 1
            wsum = 0.0
            tsum = 0.0
            for j in range(q, e):
                r = order[j]
                wsum += weights[r]
                tsum += weights[r] * t[p, r]
            if wsum >= min_share:
                # the point with most weight in the group (the first hit of equals)
                best_w = -1.0
                best_pt = -1
                for j in range(q, e):
                    pt = idx[p, order[j]]
                    acc = 0.0
                    for jj in range(q, e):
                        if idx[p, order[jj]] == pt:
                            acc += weights[order[jj]]
                    if acc > best_w + 1e-15:
                        best_w = acc
                        best_pt = pt
                pulse[k] = p
                rng[k] = tsum / wsum
                share[k] = wsum
                point[k] = best_pt
                strength[k] = wsum * strength_of[best_pt]
                k += 1
            q = e
        for j in range(first_of_pulse, k):
            rnum[j] = j - first_of_pulse + 1
            nret[j] = k - first_of_pulse
    return pulse[:k], rng[:k], share[:k], point[:k], strength[:k], rnum[:k], nret[:k]


def group_returns(indices, distances, weights, separation: float, min_share: float, intensity=None) -> dict:
    """Group each pulse's sub-ray hits into returns (module docstring).

    Parameters
    ----------
    indices, distances : (m, s)
        Per pulse and sub-ray: the point hit (-1 on a miss) and its distance.
    weights : (s,) float
        Footprint weights of the sub-rays (:func:`footprint_samples`).
    intensity : (n,) float, optional
        Per point of the cloud: a return's strength is share times it.

    Returns
    -------
    dict
        ``pulse`` (row of the input), ``range``, ``share``, ``index``,
        ``strength``, ``return_number``, ``number_of_returns``: one entry per
        detected return, ordered by pulse then range.
    """
    idx = np.ascontiguousarray(indices, np.int64)
    t = np.ascontiguousarray(np.where(idx >= 0, distances, np.inf), np.float64)
    n_points = int(idx.max(initial=-1)) + 1
    strength_of = (np.ones(max(n_points, 1)) if intensity is None
                   else np.ascontiguousarray(intensity, np.float64))
    out = _group(idx, t, np.ascontiguousarray(weights, np.float64), strength_of, float(separation),
                 float(min_share))
    keys = ("pulse", "range", "share", "index", "strength", "return_number", "number_of_returns")
    return dict(zip(keys, out))


def select_returns(groups: dict, kinds) -> np.ndarray:
    """Indices into ``groups`` of the returns of ``kinds`` ({'first', 'last',
    'strongest', 'all'}), each return once, in pulse and range order."""
    n = len(groups["pulse"])
    if "all" in kinds or n == 0:
        return np.arange(n)
    keep = np.zeros(n, bool)
    rn, nr = groups["return_number"], groups["number_of_returns"]
    if "first" in kinds:
        keep |= rn == 1
    if "last" in kinds:
        keep |= rn == nr
    if "strongest" in kinds:
        start = np.flatnonzero(rn == 1)  # each pulse's returns are contiguous
        best = np.maximum.reduceat(groups["strength"], start)
        per = np.repeat(best, nr[start])
        s = groups["strength"] == per
        # the first of equal strengths
        first_equal = np.zeros(n, bool)
        cand = np.flatnonzero(s)
        pulse_of = groups["pulse"][cand]
        _, first = np.unique(pulse_of, return_index=True)
        first_equal[cand[first]] = True
        keep |= first_equal
    return np.flatnonzero(keep)
