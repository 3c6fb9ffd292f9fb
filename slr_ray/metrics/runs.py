"""A validation run's figures from its rows: the paper's statistics of scan agreement.

Every statistic here is computed from ``results.csv`` rows (records: one dict
a pair, as :func:`slr_ray.validation.load_rows` reads them; values as text or
numbers): the headline numbers, one series of pairs picked by scene,
primary, backend and truth (:func:`series`), and the paper's figures of a
series (:func:`series_stats`: coverage, the paper's similarity, with
precision beside it where the rows have it). :mod:`slr_ray.validation.report`
assembles them into the report; :mod:`slr_ray.plotting` draws them.
"""

from __future__ import annotations

import math

import numpy as np

from ..paper import DISTANCE_BANDS, NEAR_DISTANCE

__all__ = ["headline", "series", "series_stats", "full_pairs"]


def _float(v) -> float:
    return float(v) if v not in (None, "") else math.nan


def headline(rows) -> dict:
    """The paper's two headline figures, per backend and truth semantics."""
    out = {}
    for b in sorted({r["backend"] for r in rows}):
        for t in sorted({r["truth"] for r in rows}):
            rr = [r for r in rows if r["backend"] == b and r["truth"] == t]
            sim = np.array([float(r["similarity"]) for r in rr])
            dist = np.array([float(r["distance_m"]) for r in rr])
            prec = np.array([_float(r.get("precision")) for r in rr])
            near = dist < NEAR_DISTANCE
            out[f"{b}/{t}"] = {
                "pairs": len(rr),
                f"mean_similarity_below_{NEAR_DISTANCE:g}m": float(sim[near].mean()) if near.any() else None,
                f"min_similarity_below_{NEAR_DISTANCE:g}m": float(sim[near].min()) if near.any() else None,
                "fraction_pairs_above_0.8": float((sim > 0.8).mean()) if len(sim) else None,
                f"mean_precision_below_{NEAR_DISTANCE:g}m": _nanmean(prec[near]),
            }
    return out


def _nanmean(x):
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(x.mean()) if len(x) else None


def series(rows, scenes=None, resolution=None, backend="binning", truth="center", positions=None):
    """``(distance_m, similarity, precision)`` arrays of the rows selected (precision nan where absent)."""
    out = [r for r in rows if r["backend"] == backend and r["truth"] == truth
           and (scenes is None or r["scene"] in scenes)
           and (resolution is None or float(r["primary_resolution"]) == float(resolution))
           and (positions is None or (r["scene"], r["position"]) in positions)]
    return (np.array([float(r["distance_m"]) for r in out]), np.array([float(r["similarity"]) for r in out]),
            np.array([_float(r.get("precision")) for r in out]))


def series_stats(distance, similarity, precision=None) -> dict:
    """The paper's figures for one series of pairs.

    The mean (and min) similarity below 17.5 m, the share of those above 90 %,
    the share of all pairs above 80 %, the mean per distance band and the
    least-squares slope per 10 m; with ``precision``, its mean overall, below
    17.5 m and per band (``None`` where no row has it).
    """
    d, s = np.asarray(distance, float), np.asarray(similarity, float)
    p = np.full(len(d), np.nan) if precision is None else np.asarray(precision, float)
    near = d < NEAR_DISTANCE
    bands = {}
    for lo, hi in DISTANCE_BANDS:
        m = (d >= lo) & (d < hi)
        if m.any():
            bands[f"{lo:g}-{hi:g}"] = {"pairs": int(m.sum()), "mean": float(s[m].mean()),
                                       "precision": _nanmean(p[m])}
    slope = float(np.polyfit(d, s, 1)[0] * 10) if len(d) > 2 and np.ptp(d) > 0 else None
    sn = s[near]
    return {"pairs": int(len(s)), "mean": float(s.mean()) if len(s) else None, "precision": _nanmean(p),
            "below_17.5m": {"pairs": int(len(sn)), "mean": float(sn.mean()) if len(sn) else None,
                            "min": float(sn.min()) if len(sn) else None,
                            "share_above_0.9": float((sn > 0.9).mean()) if len(sn) else None,
                            "precision": _nanmean(p[near])},
            "share_above_0.8": float((s > 0.8).mean()) if len(s) else None,
            "bands": bands, "slope_per_10m": slope}


def full_pairs(rows, resolution, series_names, exact: bool = True) -> set:
    """The (scene, position) pairs at one primary that have a row for every (backend, truth) series
    (``exact``: and no other series)."""
    have: dict = {}
    for r in rows:
        if float(r["primary_resolution"]) == float(resolution):
            have.setdefault((r["scene"], r["position"]), set()).add((r["backend"], r["truth"]))
    want = set(series_names)
    return {k for k, v in have.items() if (v == want if exact else v >= want)}
