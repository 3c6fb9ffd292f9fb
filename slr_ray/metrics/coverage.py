"""How close a simulated scan is to the true one, in both directions.

:func:`similarity` is the paper's measure: **coverage**, the share of true
points with a simulated point within 10 cm. It cannot see simulated points
that have no true point near them (see-through points: surfaces behind
another that a real scanner would not record); an SLR scan that kept every
primary point would score 100 %. :func:`agreement` adds **precision** (the
share of simulated points within the threshold of a true point) and their
harmonic mean, the F-score, as point-cloud benchmarks report them (Tanks and
Temples: precision, recall and F-score at a distance threshold).
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass

import numpy as np

from .. import lazy
from ..arrays import as_points
from ..errors import InputValueError
from ..paper import SIMILARITY_THRESHOLD
from .cellgrid import CellGrid, GridUnsuitable

#: scipy.spatial, loaded on first use (slr_ray.lazy: the command line starts without it)
scipy_spatial = lazy.module("scipy.spatial")

__all__ = ["similarity", "agreement", "Agreement", "nearest", "nearest_distances"]


def _kdtree_workers(n_threads, workers) -> int:
    """scipy's ``workers`` (-1: all) from ``n_threads`` (None: all), or from the
    deprecated ``workers`` keyword."""
    if workers is not None:
        warnings.warn("workers= is deprecated; use n_threads= (None: all cores)", DeprecationWarning, stacklevel=3)
        n_threads = workers
    return -1 if n_threads is None or n_threads == -1 else int(n_threads)


def nearest(query, reference, n_threads: int | None = None, upper_bound: float = np.inf, *,
            workers: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distance to and index of each ``query`` point's nearest ``reference`` point:
    the one kd-tree lookup of the package (the tree recentred on the reference's
    mean, so it works on small numbers whatever the coordinates).

    Returns
    -------
    distances : (m,) float64
        ``inf`` for every query point when ``reference`` is empty, and for
        those with no reference point closer than ``upper_bound``.
    indices : (m,) intp
        Into ``reference``; ``len(reference)`` (scipy's sentinel) where the
        distance is ``inf``. Ties go to whichever point the kd-tree meets first.

    ``n_threads``: threads of the query (default all cores; ``workers``,
    scipy's name, is a deprecated alias).
    """
    kd_workers = _kdtree_workers(n_threads, workers)
    q = as_points(query, "query").astype(np.float64, copy=False)
    r = as_points(reference, "reference").astype(np.float64, copy=False)
    if len(r) == 0 or len(q) == 0:
        return np.full(len(q), np.inf), np.full(len(q), len(r), np.intp)
    c = r.mean(axis=0)
    d, i = scipy_spatial.cKDTree(r - c).query(q - c, k=1, workers=kd_workers, distance_upper_bound=upper_bound)
    return d, i.astype(np.intp)


def nearest_distances(query, reference, n_threads: int | None = None, upper_bound: float = np.inf, *,
                      workers: int | None = None) -> np.ndarray:
    """Distance from each ``query`` point to its nearest ``reference`` point.

    ``inf`` for every query point when ``reference`` is empty (what Open3D's
    ``compute_point_cloud_distance`` leaves undefined), and for those with no
    reference point closer than ``upper_bound`` (a bound makes the search
    several times faster when many points have no close neighbour).
    ``n_threads``: threads of the kd-tree query (default all cores;
    ``workers``, scipy's name, is a deprecated alias).
    """
    return nearest(query, reference, n_threads, upper_bound, workers=workers)[0]


def similarity(true_points, simulated_points, threshold: float = SIMILARITY_THRESHOLD, n_threads: int | None = None,
               *, workers: int | None = None) -> float:
    """Fraction of true points whose nearest simulated point is closer than ``threshold``.

    The paper's similarity of a secondary (true) scan and its SLR scan, with
    10 cm. Empty ``true_points`` gives ``nan`` (nothing to match); empty
    ``simulated_points`` with some true points gives 0.0.
    """
    if not threshold > 0:
        raise InputValueError(f"threshold must be > 0, got {threshold}")
    return _share_within(as_points(true_points, "true_points"), as_points(simulated_points, "simulated_points"),
                         threshold, _kdtree_workers(n_threads, workers))


@dataclass(frozen=True)
class Agreement:
    """Coverage, precision and F-score of a simulated scan against a true one.

    Attributes
    ----------
    coverage : float
        Share of true points with a simulated point closer than ``threshold``
        (the paper's similarity; ``nan`` with no true point).
    precision : float
        Share of simulated points with a true point closer than ``threshold``
        (``nan`` with no simulated point).
    fscore : float
        ``2 P C / (P + C)``; 0 when both are 0, ``nan`` when either is ``nan``.
    threshold : float
        Metres.
    true_points, simulated_points : int
    """

    coverage: float
    precision: float
    fscore: float
    threshold: float
    true_points: int
    simulated_points: int

    def to_dict(self) -> dict:
        return asdict(self)


def _share_within(query, reference, threshold, workers) -> float:
    """Share of ``query`` points with a ``reference`` point strictly closer than
    ``threshold``: on a cell grid (no tree, early exit), or a kd-tree where the
    grid does not suit the cloud (an extent of more than 2e6 cells)."""
    if len(query) == 0:
        return float("nan")
    try:
        hit = CellGrid(reference, threshold).any_within(query)
    except GridUnsuitable:
        d = nearest_distances(query, reference, workers, upper_bound=threshold)  # scipy's workers: -1 all
        hit = d < threshold
    return float(np.count_nonzero(hit) / len(hit))


def agreement(true_points, simulated_points, threshold: float = SIMILARITY_THRESHOLD,
              n_threads: int | None = None, *, workers: int | None = None) -> Agreement:
    """Coverage and precision of ``simulated_points`` against ``true_points``.

    Parameters
    ----------
    true_points, simulated_points : (n, 3), (m, 3) float
    threshold : float
        Metres (the paper: 0.10). A pair exactly ``threshold`` apart does not
        match (strictly closer, as :func:`similarity`).
    n_threads : int, optional
        Threads of the kd-tree queries (default all cores; ``workers``, scipy's
        name, is a deprecated alias), where a kd-tree is used:
        the test runs on a :class:`~slr_ray.metrics.cellgrid.CellGrid` of cells of the
        threshold's size (numba's threads) unless the cloud spans more than
        2e6 such cells along an axis.

    Returns
    -------
    Agreement

    Examples
    --------
    >>> import numpy as np
    >>> true = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    >>> slr = np.array([[0.0, 0, 0.05], [5.0, 0, 0]])  # one match, one see-through point
    >>> a = agreement(true, slr)
    >>> a.coverage, a.precision, a.fscore
    (0.5, 0.5, 0.5)
    """
    if not threshold > 0:
        raise InputValueError(f"threshold must be > 0, got {threshold}")
    t = as_points(true_points, "true_points")
    s = as_points(simulated_points, "simulated_points")
    kd_workers = _kdtree_workers(n_threads, workers)
    cov = _share_within(t, s, threshold, kd_workers)
    prec = _share_within(s, t, threshold, kd_workers)
    if np.isnan(cov) or np.isnan(prec):
        f = float("nan")
    else:
        f = 0.0 if cov + prec == 0 else 2 * cov * prec / (cov + prec)
    return Agreement(cov, prec, f, float(threshold), len(t), len(s))
