"""Why a validation pair falls short: occlusion or artefact.

:func:`hidden_from` tells which points of a scene a scanner cannot see (a
ray cast on the scene's mesh); :func:`miss_breakdown` splits the true points
an SLR scan misses into those hidden from the primary scanner (no primary
can recover them) and those it saw (resolution and binning artefacts).
"""

from __future__ import annotations

import math

import numpy as np

from ..paper import SIMILARITY_THRESHOLD
from ..raycast import RayScene
from ..metrics import nearest_distances

__all__ = ["hidden_from", "miss_breakdown"]


def hidden_from(scene, points, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Which ``points`` (on the surfaces of ``scene``) a scanner at ``origin``
    cannot see: the segment to the point meets another surface first (ray cast
    on the scene's mesh, 1 mm tolerance)."""
    o = np.asarray(origin, np.float64)
    v = np.asarray(points, np.float64) - o
    dist = np.linalg.norm(v, axis=1)
    if not len(v):
        return np.zeros(0, bool)
    ok = dist > 0
    dirs = np.zeros_like(v)
    dirs[ok] = v[ok] / dist[ok, None]
    caster = RayScene.triangles(np.asarray(scene.mesh.vertices, np.float64), np.asarray(scene.mesh.faces), o)
    t = caster.intersect(o, dirs, exact=True).distances
    return ok & (t < dist - np.maximum(1e-3, 1e-6 * dist))


def miss_breakdown(scene, true_scan, slr_points, primary_origin=(0.0, 0.0, 0.0), threshold: float = SIMILARITY_THRESHOLD,
                   range_edges=(0.0, 5.0, 10.0, 20.0, 40.0, math.inf)) -> dict:
    """Why true points have no SLR point within ``threshold``.

    A true point of ``true_scan`` (a :class:`~slr_ray.meshscan.MeshScan` of
    ``scene`` from a secondary position) that the SLR scan misses is either
    **hidden** from the primary scanner (the segment from ``primary_origin``
    to the point crosses the scene first: no primary resolution can recover
    it) or **visible** to it (the primary saw that surface, but too coarsely,
    or the SLR scan picked another of its points: resolution and binning).
    Counts are split by label (ground, objects) and by range from the
    secondary position; ``hidden + visible == missed``.
    """
    true_pts = np.asarray(true_scan.points, np.float64)
    missed = ~(nearest_distances(true_pts, slr_points, upper_bound=threshold) < threshold)
    idx = np.flatnonzero(missed)
    hidden = np.zeros(len(true_pts), bool)
    if len(idx):
        hidden[idx] = hidden_from(scene, true_pts[idx], primary_origin)
    ground = np.asarray(true_scan.labels) == 0
    rng = np.linalg.norm(true_pts - np.asarray(true_scan.origin, np.float64), axis=1)

    def counts(mask):
        return {"true": int(mask.sum()), "missed": int((missed & mask).sum()),
                "hidden": int((hidden & mask).sum()), "visible": int((missed & ~hidden & mask).sum())}

    out = {"threshold": threshold, "all": counts(np.ones(len(true_pts), bool)), "ground": counts(ground),
           "objects": counts(~ground), "by_range": {}}
    for lo, hi in zip(range_edges[:-1], range_edges[1:]):
        out["by_range"][f"{lo:g}-{hi:g}"] = counts((rng >= lo) & (rng < hi))
    return out
