"""Novel-view LiDAR metrics: how close a simulated scan is to a real one, as the field scores it.

The novel-view LiDAR papers (LiDAR-NeRF, Tao et al. 2023; Neural LiDAR Fields,
Huang et al. 2023; LiDAR4D, Zheng et al. 2024) score a synthesised frame against
the real one by its points (Chamfer distance, F-score) and by its range image
(depth RMSE and median absolute error, ray-drop accuracy). This module computes
those numbers exactly (float64, a kd-tree or :class:`~slr_ray.metrics.cellgrid.CellGrid`,
no sampling), and splits each by range band, by beam (row of the range image)
and by whether the target point was *seen from the primary* (below).

Definitions
-----------
Target ``T`` (the real scan), simulated ``S``; ``d(p, X)`` the Euclidean
distance from ``p`` to its nearest point of ``X``.

Chamfer distance (:func:`point_metrics`)
    Two directional terms, each a **mean of squared distances** (m²):
    ``to_target = mean_{s in S} d(s, T)²`` (the accuracy side) and
    ``to_simulated = mean_{t in T} d(t, S)²`` (the completeness side).
    ``chamfer_sum = to_target + to_simulated`` is the number LiDAR-NeRF
    (``lidarnvs/eval.py``) and LiDAR4D (``utils/metrics.py``) report: their
    ``chamfer_3DDist`` CUDA kernel returns squared distances and both add the
    two directions' means. ``chamfer_mean`` is half of it (the mean of the two
    directions). Because squared metres are hard to read, the mean
    *distances* of both directions (metres, ``to_target_distance``,
    ``to_simulated_distance``) are reported too. Neural LiDAR Fields' code is
    not public; its paper's CD is not checked here.
F-score at a threshold ``tau``
    ``precision = |{s: d(s, T) < tau}| / |S|``, ``recall = |{t: d(t, S) < tau}| /
    |T|``, ``F = 2PR / (P + R)`` (0 when both are 0), **strictly closer** and
    on **distances**, tested from the input coordinates on a cell grid (as
    :func:`~slr_ray.metrics.agreement`, which it equals). The field quotes 5 cm; SLR's paper 10 cm. LiDAR-NeRF and
    LiDAR4D's code compare *squared* distances with 0.05, i.e. a distance
    threshold of sqrt(0.05) = 22.4 cm; pass ``thresholds=(..., 0.05 ** 0.5)``
    to reproduce their number.
Range-image depth errors (:func:`range_image_metrics`)
    Over the pulses where **both** images return: ``rmse = sqrt(mean(e²))``,
    ``medae = median(|e|)`` and ``mae = mean(|e|)``, ``e = simulated - real``
    (metres). LiDAR4D and LiDAR-NeRF compute them over the whole image with
    ranges clamped to [1e-6 or 1e-3 m, 80 m] (a dropped pixel counts as a tiny
    range), which mixes ray drop into depth; here ray drop is scored apart and
    nothing is clamped.
Ray-drop confusion
    Per pulse: returned or dropped, in the real and the simulated image.
    ``accuracy`` = share of pulses where the two agree (all pulses, as LiDAR4D's
    ``RaydropMeter``); a *drop* is the positive class: ``drop_recall`` = share
    of the real drops the simulation drops too, ``drop_precision`` = share of the
    simulated drops that are real drops (``nan`` with none).
Seen from the primary (:func:`seen_from`)
    A target point is *seen* when a primary point (the cloud the simulation is
    made of, in the target's frame) lies strictly closer than a threshold
    (default 10 cm, the SLR paper's). No SLR rule can return what the primary
    never recorded: the unseen part of the target bounds what any method can
    reach. A pulse of the range image is seen when its real point is; pulses
    with no real return are ``"no return"``.

Empty sets
    One side empty (an empty simulation, or an empty part of the target): its
    share is ``nan`` (no points to count), the other's is 0, ``F = 0`` (as
    LiDAR-NeRF's and LiDAR4D's ``fscore``, which turn that 0/0 into 0), the
    Chamfer terms measured from the non-empty side are ``inf`` and so are
    ``chamfer_sum`` and ``chamfer_mean``. Both empty: every figure ``nan``.
    Range images: depth errors over no pulse where both return are ``nan``;
    ``drop_recall`` with no real drop and ``drop_precision`` with no
    simulated drop are ``nan``. Ranges must be > 0 where finite: NaN or inf
    is "no return" (not 0, LiDAR-NeRF's convention: refused).

Splits
------
``groups`` are name -> ``(n_target,)`` labels of the target points (range
band, beam, seen...; NaN labels form one group). A target point counts in its own group; a simulated
point counts in the group of its nearest target point (so each group's
precision and recall describe one part of the real scan). For range images
the labels are per pulse. The totals do not depend on the splits.

Examples
--------
>>> import numpy as np
>>> t = np.array([[0.0, 0, 0], [1.0, 0, 0]])
>>> s = np.array([[0.0, 0, 0.03], [3.0, 0, 0]])
>>> m = point_metrics(t, s, thresholds=(0.05,))
>>> round(m.fscore[0.05]["recall"], 3), round(m.fscore[0.05]["precision"], 3)
(0.5, 0.5)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..arrays import as_points
from ..errors import InputValueError
from ..paper import SIMILARITY_THRESHOLD
from .cellgrid import CellGrid, GridUnsuitable
from .coverage import nearest
from .metric import Metric, Pair

__all__ = ["point_metrics", "PointMetrics", "range_image_metrics", "RangeImageMetrics", "seen_from",
           "nearest", "range_bands", "RANGE_BANDS", "FIELD_THRESHOLD", "PAPER_THRESHOLD",
           "LIDAR4D_CODE_THRESHOLD", "POINTS", "IMAGE"]

#: the novel-view field's F-score threshold (metres)
FIELD_THRESHOLD = 0.05
#: the SLR paper's threshold (metres)
PAPER_THRESHOLD = SIMILARITY_THRESHOLD
#: the distance threshold LiDAR-NeRF's and LiDAR4D's code apply (0.05 on squared distances)
LIDAR4D_CODE_THRESHOLD = math.sqrt(0.05)
#: range band edges (metres) of the splits
RANGE_BANDS = (0.0, 10.0, 20.0, 40.0, 80.0, math.inf)


def seen_from(target, primary, threshold: float = PAPER_THRESHOLD) -> np.ndarray:
    """``(n,) bool``: whether each ``target`` point has a ``primary`` point strictly
    closer than ``threshold`` (module docstring: "seen from the primary")."""
    if not (math.isfinite(threshold) and threshold > 0):
        raise InputValueError(f"threshold must be a finite number > 0, got {threshold!r}")
    t = as_points(target, "target")
    p = as_points(primary, "primary")
    try:
        return CellGrid(p, threshold).any_within(t)
    except GridUnsuitable:
        return nearest(t, p)[0] < threshold


def range_bands(ranges, edges=RANGE_BANDS) -> np.ndarray:
    """``(n,) <U`` label of each range's band, ``"a-b m"`` for ``[a, b)``; ``"none"`` for NaN."""
    r = np.asarray(ranges, dtype=np.float64)
    e = np.asarray(edges, dtype=np.float64)
    if e.ndim != 1 or len(e) < 2 or np.any(np.diff(e) <= 0):
        raise InputValueError(f"edges must be at least two increasing values, got {edges!r}")
    names = np.array([f"{a:g}-{b:g} m" for a, b in zip(e[:-1], e[1:])] + ["none"])
    k = np.searchsorted(e, r, side="right") - 1
    k = np.where(np.isnan(r) | (k < 0) | (k >= len(e) - 1), len(e) - 1, k)
    return names[k]


def _fscore(p: float, r: float) -> float:
    """``2PR / (P + R)``; 0 when both are 0, and when one side is empty (``nan``) and the other's
    share is 0 (an empty simulation recovered nothing: LiDAR-NeRF's and LiDAR4D's ``fscore`` turn
    that 0/0 into 0 too); ``nan`` only when both sides are empty."""
    if math.isnan(p) and math.isnan(r):
        return float("nan")
    if math.isnan(p) or math.isnan(r):
        return 0.0
    return 0.0 if p + r == 0 else 2 * p * r / (p + r)


def _mean(x) -> float:
    return float(np.mean(x)) if len(x) else float("nan")


def _within(query, reference, tau, d) -> np.ndarray:
    """Whether each query point has a reference point strictly closer than ``tau``, from the
    input coordinates (the cell grid: what a brute-force loop gives, points at exactly ``tau``
    included); ``d < tau`` from the kd-tree's distances where the grid does not suit the cloud."""
    try:
        return CellGrid(reference, tau).any_within(query)
    except GridUnsuitable:
        return d < tau


def _point_block(d_t, d_s, hits) -> dict:
    """The figures of one set of target-side (``d_t``: target to simulated) and
    simulated-side (``d_s``: simulated to target) nearest distances; ``hits``:
    threshold -> (target within, simulated within) booleans."""
    to_t, to_s = _mean(np.square(d_s)), _mean(np.square(d_t))
    # one side empty: the other side's term is inf and this side's nan; the sum is inf, not nan
    cd = math.inf if (len(d_t) == 0) != (len(d_s) == 0) else to_t + to_s
    out = {"target_points": int(len(d_t)), "simulated_points": int(len(d_s)),
           "to_target": to_t, "to_simulated": to_s, "chamfer_sum": cd, "chamfer_mean": 0.5 * cd,
           "to_target_distance": _mean(d_s), "to_simulated_distance": _mean(d_t), "fscore": {}}
    for tau, (h_t, h_s) in hits.items():
        p = float(np.count_nonzero(h_s) / len(h_s)) if len(h_s) else float("nan")
        r = float(np.count_nonzero(h_t) / len(h_t)) if len(h_t) else float("nan")
        out["fscore"][float(tau)] = {"precision": p, "recall": r, "fscore": _fscore(p, r)}
    return out


@dataclass(frozen=True)
class PointMetrics:
    """Chamfer distance and F-scores of a simulated cloud against a target (module docstring).

    Attributes
    ----------
    to_target, to_simulated : float
        Mean squared nearest distance, simulated -> target and target ->
        simulated (m²; ``nan`` when the side measured from is empty, ``inf``
        when the other side is empty).
    chamfer_sum : float
        ``to_target + to_simulated``: LiDAR-NeRF's and LiDAR4D's CD.
    chamfer_mean : float
        Half of it.
    to_target_distance, to_simulated_distance : float
        Mean nearest distances (metres).
    fscore : dict float -> dict
        Per threshold (metres): ``precision``, ``recall``, ``fscore``.
    target_points, simulated_points : int
    groups : dict
        name -> label -> the same figures for that part of the target.
    """

    to_target: float
    to_simulated: float
    chamfer_sum: float
    chamfer_mean: float
    to_target_distance: float
    to_simulated_distance: float
    fscore: dict
    target_points: int
    simulated_points: int
    groups: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain JSON (thresholds as strings, cm)."""
        def plain(block):
            b = dict(block)
            b["fscore"] = {f"{100 * k:g}cm": v for k, v in block["fscore"].items()}
            return b

        top = plain({k: getattr(self, k) for k in ("target_points", "simulated_points", "to_target",
                                                     "to_simulated", "chamfer_sum", "chamfer_mean",
                                                     "to_target_distance", "to_simulated_distance", "fscore")})
        top["groups"] = {g: {str(lab): plain(b) for lab, b in d.items()} for g, d in self.groups.items()}
        return top


def _labels(groups, n, what) -> dict:
    out = {}
    for name, lab in (groups or {}).items():
        lab = np.asarray(lab)
        if lab.shape != (n,):
            raise InputValueError(f"groups[{name!r}] must hold one label per {what} ({n}), got shape {lab.shape}")
        out[name] = _unique(lab, name)
    return out


def _unique(lab, name):
    """``(labels, inverse)``: each distinct label once (NaN labels one group) and each item's position in it."""
    try:
        u, inv = np.unique(lab, return_inverse=True)
    except TypeError as exc:  # None beside strings and the like: numpy cannot order them
        raise InputValueError(f"groups[{name!r}]: labels must be of one orderable kind "
                              f"(numbers or strings): {exc}") from None
    return u, inv.reshape(-1)


def _thresholds(thresholds) -> list[float]:
    """One threshold or a sequence of them, each a finite number > 0 (metres)."""
    items = [thresholds] if np.ndim(thresholds) == 0 and not isinstance(thresholds, str) else thresholds
    try:
        if isinstance(items, str):
            raise TypeError("a string")
        th = [float(x) for x in items]
        if any(isinstance(x, (str, bytes)) or x is None for x in items):
            raise TypeError("not numbers")
    except (TypeError, ValueError):
        raise InputValueError(f"thresholds must be a number or a sequence of numbers (metres), got {thresholds!r}") \
            from None
    if not all(math.isfinite(x) and x > 0 for x in th):
        raise InputValueError(f"thresholds must be finite numbers > 0, got {thresholds!r}")
    return th


def point_metrics(target, simulated, thresholds=(FIELD_THRESHOLD, PAPER_THRESHOLD), groups: dict | None = None,
                  n_threads: int | None = None, *, workers: int | None = None) -> PointMetrics:
    """Chamfer distance and F-scores of ``simulated`` against ``target``, whole and split.

    Parameters
    ----------
    target, simulated : (n, 3), (m, 3) float
        The real scan and the simulated one, in one frame.
    thresholds : sequence of float
        F-score thresholds, metres (default 5 cm, the field's, and 10 cm, SLR's).
    groups : dict of str -> (n,) array, optional
        Labels of the target points; each split reports the same figures per
        label (a simulated point in the label of its nearest target point).
    n_threads : int, optional
        kd-tree threads (default all; ``workers`` is a deprecated alias).

    Returns
    -------
    PointMetrics
    """
    t = as_points(target, "target")
    s = as_points(simulated, "simulated")
    th = _thresholds(thresholds)
    labs = _labels(groups, len(t), "target point")
    d_t, _ = nearest(t, s, n_threads, workers=workers)
    d_s, j = nearest(s, t, n_threads, workers=workers)
    hits = {tau: (_within(t, s, tau, d_t), _within(s, t, tau, d_s)) for tau in th}
    top = _point_block(d_t, d_s, hits)
    out = {}
    for name, (uniq, inv) in labs.items():
        s_inv = inv[j] if len(t) else np.empty(0, np.intp)  # a simulated point: its nearest target's label
        out[name] = {}
        for k, u in enumerate(uniq):
            mt, ms = inv == k, s_inv == k
            out[name][u.item()] = _point_block(d_t[mt], d_s[ms], {tau: (a[mt], b[ms]) for tau, (a, b) in hits.items()})
    return PointMetrics(groups=out, **top)


def _image_block(real, sim) -> dict:
    """Depth errors and ray-drop confusion of two flat range arrays (NaN: no return)."""
    r_ret, s_ret = np.isfinite(real), np.isfinite(sim)
    both = r_ret & s_ret
    e = (sim[both] - real[both]).astype(np.float64)
    r_drop, s_drop = ~r_ret, ~s_ret
    n = len(real)
    hit = np.count_nonzero(r_drop & s_drop)
    n_rd, n_sd = np.count_nonzero(r_drop), np.count_nonzero(s_drop)
    return {"pulses": int(n), "both_return": int(len(e)),
            "rmse": float(np.sqrt(np.mean(e * e))) if len(e) else float("nan"),
            "medae": float(np.median(np.abs(e))) if len(e) else float("nan"),
            "mae": float(np.mean(np.abs(e))) if len(e) else float("nan"),
            "sse": float(np.sum(e * e)),
            "real_returns": int(n - n_rd), "simulated_returns": int(n - n_sd),
            "accuracy": float(np.count_nonzero(r_ret == s_ret) / n) if n else float("nan"),
            "drop_recall": float(hit / n_rd) if n_rd else float("nan"),
            "drop_precision": float(hit / n_sd) if n_sd else float("nan")}


@dataclass(frozen=True)
class RangeImageMetrics:
    """Depth errors and ray-drop confusion of a simulated range image against a real one.

    Attributes
    ----------
    rmse, medae, mae : float
        Metres, over the pulses where both return (``nan`` with none).
    sse : float
        Sum of squared depth errors (m²): how the RMSE splits among groups.
    both_return, real_returns, simulated_returns, pulses : int
    accuracy, drop_recall, drop_precision : float
        Ray drop (module docstring).
    groups : dict
        name -> label -> the same figures for those pulses.
    """

    rmse: float
    medae: float
    mae: float
    sse: float
    both_return: int
    real_returns: int
    simulated_returns: int
    pulses: int
    accuracy: float
    drop_recall: float
    drop_precision: float
    groups: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        out = {k: v for k, v in self.__dict__.items() if k != "groups"}
        out["groups"] = {g: {str(lab): b for lab, b in d.items()} for g, d in self.groups.items()}
        return out


def range_image_metrics(real, simulated, groups: dict | None = None) -> RangeImageMetrics:
    """Depth errors and ray-drop confusion of ``simulated`` against ``real``.

    Parameters
    ----------
    real, simulated : (rows, cols) float
        Range images of one pattern, NaN (or inf) where a pulse has no return
        (:meth:`slr_ray.Scan.range_image`'s ``range``).
    groups : dict of str -> (rows, cols) or (rows,) array, optional
        Labels per pulse (or per row: a beam's label for all its pulses).

    Returns
    -------
    RangeImageMetrics
    """
    try:
        a = np.asarray(real, dtype=np.float64)
        b = np.asarray(simulated, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputValueError(f"real and simulated must be range images of numbers: {exc}") from None
    for name, img in (("real", a), ("simulated", b)):
        bad = np.isfinite(img) & (img <= 0)
        if bad.any():
            raise InputValueError(f"{name} holds {np.count_nonzero(bad)} range(s) <= 0; a pulse with no return is NaN "
                                  "(or inf) here, not 0 as in LiDAR-NeRF's panoramas: "
                                  "np.where(img > 0, img, np.nan) converts one")
    if a.ndim != 2 or a.shape != b.shape:
        raise InputValueError(f"real and simulated must be range images of one shape, got {a.shape} and {b.shape}")
    shape = a.shape
    a = np.where(np.isfinite(a), a, np.nan).ravel()
    b = np.where(np.isfinite(b), b, np.nan).ravel()
    labs = {}
    for name, lab in (groups or {}).items():
        lab = np.asarray(lab)
        if lab.shape == shape[:1]:
            lab = np.repeat(lab, shape[1])
        elif lab.shape == shape:
            lab = lab.ravel()
        else:
            raise InputValueError(f"groups[{name!r}] must be one label per pulse {shape} or per row, "
                                  f"got shape {lab.shape}")
        labs[name] = _unique(lab, name)
    top = _image_block(a, b)
    out = {name: {u.item(): _image_block(a[inv == k], b[inv == k]) for k, u in enumerate(uniq)}
           for name, (uniq, inv) in labs.items()}
    return RangeImageMetrics(groups=out, **top)


# --- the registry's entries: a pair's blocks and their table columns ---------------------------------------

def _cm(x) -> str:
    return f"{100 * x:g}cm"


def _points_entry(pair: Pair) -> dict:
    return point_metrics(pair.target, pair.simulated, thresholds=pair.thresholds, groups=pair.point_groups).to_dict()


def _points_columns(p: dict, result: dict) -> dict:
    """Chamfer distances, P/R/F per threshold, the recall of the seen part and the unseen part's share of
    the real -> simulated Chamfer term."""
    row = {"cd_sum_m2": p["chamfer_sum"], "cd_to_real_m": p["to_target_distance"],
           "cd_to_sim_m": p["to_simulated_distance"]}
    for tau in result["thresholds"]:
        f = p["fscore"][_cm(tau)]
        row[f"P@{_cm(tau)}"], row[f"R@{_cm(tau)}"], row[f"F@{_cm(tau)}"] = f["precision"], f["recall"], f["fscore"]
    seen = p["groups"].get("seen", {})
    tau = result["seen_threshold"]
    row[f"R@{_cm(tau)} seen"] = seen.get("seen", {}).get("fscore", {}).get(_cm(tau), {}).get("recall", math.nan)
    n_t = p["target_points"]
    un = seen.get("unseen", {})
    row["unseen share of real->sim CD"] = (un.get("to_simulated", 0.0) * un.get("target_points", 0)
                                          / (p["to_simulated"] * n_t)) if n_t and p["to_simulated"] else math.nan
    return row


def _image_entry(pair: Pair) -> dict:
    return range_image_metrics(pair.real_image, pair.image, groups=pair.pulse_groups).to_dict()


def _image_columns(im: dict, result: dict) -> dict:
    """Depth errors, ray drop, and the unseen pulses' share of the squared depth error."""
    row = {"depth_rmse_m": im["rmse"], "depth_medae_m": im["medae"], "both_return": im["both_return"],
           "drop_accuracy": im["accuracy"], "drop_recall": im["drop_recall"], "drop_precision": im["drop_precision"]}
    seen = im["groups"].get("seen", {})
    row["unseen share of depth SSE"] = seen.get("unseen", {}).get("sse", 0.0) / im["sse"] if im["sse"] else math.nan
    row["rmse seen pulses"] = seen.get("seen", {}).get("rmse", math.nan)
    return row


#: the field's point metrics (:func:`point_metrics`) as a registered metric: block ``points``
POINTS = Metric("points", _points_entry, _points_columns)
#: the field's range-image metrics (:func:`range_image_metrics`) as a registered metric: block ``image``
IMAGE = Metric("image", _image_entry, _image_columns)
