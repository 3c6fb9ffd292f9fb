"""How close a simulated scan is to the true one (the paper's measure)."""

from __future__ import annotations

import numpy as np

from .arrays import as_points

__all__ = ["similarity", "nearest_distances"]


def nearest_distances(query, reference, workers: int = -1, upper_bound: float = np.inf) -> np.ndarray:
    """Distance from each ``query`` point to its nearest ``reference`` point.

    ``inf`` for every query point when ``reference`` is empty (what Open3D's
    ``compute_point_cloud_distance`` leaves undefined), and for those with no
    reference point closer than ``upper_bound`` (a bound makes the search
    several times faster when many points have no close neighbour).
    """
    from scipy.spatial import cKDTree

    q = as_points(query, "query").astype(np.float64, copy=False)
    r = as_points(reference, "reference").astype(np.float64, copy=False)
    if len(r) == 0:
        return np.full(len(q), np.inf)
    if len(q) == 0:
        return np.empty(0)
    # recentre so the tree works on small numbers whatever the coordinates
    c = r.mean(axis=0)
    d, _ = cKDTree(r - c).query(q - c, k=1, workers=workers, distance_upper_bound=upper_bound)
    return d


def similarity(true_points, simulated_points, threshold: float = 0.10, workers: int = -1) -> float:
    """Fraction of true points whose nearest simulated point is closer than ``threshold``.

    The paper's similarity of a secondary (true) scan and its SLR scan, with
    10 cm. Empty ``true_points`` gives ``nan`` (nothing to match); empty
    ``simulated_points`` with some true points gives 0.0.
    """
    if threshold <= 0:
        raise ValueError(f"threshold must be > 0, got {threshold}")
    d = nearest_distances(true_points, simulated_points, workers, upper_bound=threshold)
    if len(d) == 0:
        return float("nan")
    return float(np.count_nonzero(d < threshold) / len(d))
