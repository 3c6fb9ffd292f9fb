"""Leave-one-out evaluation of a sequence: each held-out frame re-simulated from the others.

For each held-out frame B the other frames of its window are accumulated
(:func:`~slr_ray.sequence.union.accumulate`), moved into B's frame at B's pose
(float64) and scanned with B's sensor (its beam table fitted to B, as
:func:`slr_ray.evaluate.evaluate_pair` does) by each method (:data:`METHODS`),
then scored against the real B with :mod:`slr_ray.metrics` exactly as
``slr-ray evaluate`` scores a pair: the same target (B's points in its table's
view, its range image by the nearest-per-pulse rule), the same table keys
(:func:`slr_ray.evaluate.evaluation_table`), one row per method per frame and a
mean over the frames.
"""

from __future__ import annotations

import math
import time

import numpy as np
from tqdm import tqdm

from ..errors import InputValueError
from ..evaluate import THRESHOLDS, evaluation_table, fitted_pattern, scan_order_beams, zbuffer
from ..metrics import PAPER_THRESHOLD, point_metrics, range_image_metrics, seen_from
from ..sensors import sensor as shipped_sensor
from .estimators import FPA_GAP, estimate
from .frames import Sequence
from .sources import SeeThrough
from .union import FrameCache, accumulate, discs_of_frames, to_frame, window

__all__ = ["METHODS", "LABELS", "evaluate_holdout", "evaluate_sequence", "mean_rows", "DEFAULT_METHODS",
           "clamped_depth_errors", "lidar4d_holdout", "LIDAR4D_MAX_DEPTH"]

#: LiDAR4D's depth clamp (utils/metrics.py, compute_depth_errors: min 1e-6, max 80 m)
LIDAR4D_MAX_DEPTH = 80.0
LIDAR4D_MIN_DEPTH = 1e-6


def clamped_depth_errors(real, simulated, min_depth: float = LIDAR4D_MIN_DEPTH,
                         max_depth: float = LIDAR4D_MAX_DEPTH) -> tuple[float, float]:
    """Depth RMSE and median absolute error as LiDAR4D's code computes them: over the whole image,
    no return (NaN here, 0 in its panoramas) counted as a range of ``min_depth``, every range
    clamped to ``[min_depth, max_depth]``: ray drop mixes into depth (``slr_ray.metrics`` scores
    the two apart)."""
    g = np.clip(np.nan_to_num(np.asarray(real, np.float64), nan=0.0, posinf=0.0), min_depth, max_depth)
    p = np.clip(np.nan_to_num(np.asarray(simulated, np.float64), nan=0.0, posinf=0.0), min_depth, max_depth)
    e = g - p
    return float(np.sqrt(np.mean(e * e))), float(np.median(np.abs(e)))


def lidar4d_holdout(n_frames: int) -> list[int]:
    """LiDAR4D's KITTI-360 split (data/preprocess/kitti360_to_nerf.py): 51 frames, the 11th, 21st,
    31st and 41st held out (start + 10, 20, 30, 40), every other frame the scene."""
    if n_frames != 51:
        raise InputValueError(f"the LiDAR4D protocol takes a sequence of 51 frames (its KITTI-360 scenes), got "
                              f"{n_frames}: pick 51 frames, or hold out frames by --holdout / --every")
    return [10, 20, 30, 40]

METHODS = ("zbuffer", "adjacent", "nearest", "fpa", "embree-knn", "embree-sources")
DEFAULT_METHODS = ("zbuffer", "adjacent", "nearest", "fpa")
LABELS = {"zbuffer": "no SLR (z-buffer of the union)", "adjacent": "binning, adjacent frame alone",
          "nearest": "nearest (binning of the union)", "fpa": "first-peak average (union)",
          "embree-knn": "embree kNN discs (union)",
          "embree-sources": "embree discs from each source frame's pulse grid"}


def _beams(frame, base):
    ring = frame.attributes.get("ring")
    if ring is not None:
        return np.asarray(ring, np.int64)
    return scan_order_beams(frame.points, base.n_beams)


def _adjacent(frames, target):
    """The nearest frame to ``target`` in index, the one before on a tie."""
    return min(frames, key=lambda i: (abs(i - target), i > target))


def evaluate_holdout(seq: Sequence, target: int, sensor: str = "velodyne_hdl64e_s2", methods=DEFAULT_METHODS,
                     half: int | None = 2, radius: float | None = None, drop_moving: bool = True,
                     thresholds=THRESHOLDS, seen_threshold: float = PAPER_THRESHOLD,
                     gap: float = FPA_GAP, cache: FrameCache | None = None,
                     see_through: SeeThrough | None = None) -> dict:
    """Frame ``target`` re-simulated from the other frames of its window by every method; with
    ``see_through`` the union leaves out what other frames saw through (the target itself does
    not vote: it is what is scored)."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputValueError(f"unknown method(s) {unknown}; choose from {list(METHODS)}")
    base = shipped_sensor(sensor) if isinstance(sensor, str) else sensor
    cache = cache or FrameCache(seq)
    others = window(seq, target, half, radius)
    if not others:
        raise InputValueError(f"frame {seq.names[target]}: no other frame in its window")
    fb, _ = cache.get(target)
    b = fb.points
    beams = _beams(fb, base)
    pat = fitted_pattern(b, beams, base) if beams is not None else base
    band_keys, _ = pat.pulse_ids(b, np.zeros(3))
    in_view = band_keys >= 0
    if not in_view.any():
        raise InputValueError(f"{seq.paths[target]}: none of its points lies within {pat.name}'s view about "
                              "its origin (is the frame in its sensor's frame?)")
    real_img = zbuffer(b, pat, backend="real").range_image()
    b_in = b[in_view]
    union = accumulate(seq, others, drop_moving=drop_moving, cache=cache, see_through=see_through, exclude=(target,))
    u = to_frame(union.points, fb.pose)
    seen = seen_from(b_in, u, seen_threshold)
    groups = {"seen": np.where(seen, "seen", "unseen")}
    seen_all = np.zeros(len(b), bool)
    seen_all[in_view] = seen
    pix = np.full(real_img["range"].shape, "no return", dtype=object)
    filled = real_img["index"] >= 0
    pix[filled] = np.where(seen_all[real_img["index"][filled]], "seen", "unseen")
    adj = _adjacent(others, target)
    rows, extra = [], {}
    for m in methods:
        t0 = time.perf_counter()
        if m == "zbuffer":
            ret = estimate(u, pat, "nearest")
            keys, _ = pat.pulse_ids(u, np.zeros(3))
            sim = u[keys >= 0]
        elif m == "adjacent":
            a = u[union.frame_of_point == adj]
            ret = estimate(a, pat, "nearest")
            sim = ret.points
        elif m == "embree-sources":
            ret, _ = discs_of_frames(cache, others, fb.pose, pat, base, drop_moving, see_through, (target,))
            sim = ret.points
        else:
            ret = estimate(u, pat, m, gap=gap)
            sim = ret.points
        img = ret.image(pat)
        pm = point_metrics(b_in, sim, thresholds=thresholds, groups=groups)
        im = range_image_metrics(real_img["range"], img, groups={"seen": pix.astype(str)})
        extra[m] = clamped_depth_errors(real_img["range"], img)
        rows.append({"method": m, "label": LABELS[m], "points_out": int(len(sim)), "pulses_returned": int(len(ret)),
                     "seconds": round(time.perf_counter() - t0, 3), "points": pm.to_dict(), "image": im.to_dict()})
    res = {"frame": seq.names[target], "fpa_gap_m": gap, "index": int(target), "window": [seq.names[i] for i in others],
           "adjacent": seq.names[adj], "union_points": int(len(union)), "removed": union.removed,
           "see_through": see_through.to_dict() if see_through else None,
           "target_points_in_view": int(len(b_in)), "unseen_share": float(np.mean(~seen)),
           "pattern": pat.to_dict() | {"beams_known": beams is not None},
           "thresholds": [float(x) for x in thresholds], "seen_threshold": seen_threshold, "rows": rows}
    res["table"] = [{"frame": res["frame"]} | r
                    | {"lidar4d_depth_rmse_m": extra[m][0], "lidar4d_depth_medae_m": extra[m][1]}
                    for m, r in zip(methods, evaluation_table(res))]
    return res


def mean_rows(tables: list[list[dict]]) -> list[dict]:
    """Per method, the mean over frames of every numeric column (``frame``: ``"mean"``)."""
    by_method: dict = {}
    for table in tables:
        for r in table:
            by_method.setdefault(r["method"], []).append(r)
    out = []
    for method, rs in by_method.items():
        row = {"frame": "mean", "method": method}
        for k in rs[0]:
            if k in row:
                continue
            vals = [r.get(k) for r in rs]
            if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
                finite = [float(v) for v in vals if math.isfinite(v)]
                row[k] = sum(finite) / len(finite) if finite else math.nan
        out.append(row)
    return out


def evaluate_sequence(seq: Sequence, holdout, sensor: str = "velodyne_hdl64e_s2", methods=DEFAULT_METHODS,
                      half: int | None = 2, radius: float | None = None, drop_moving: bool = True,
                      progress: bool = False, **kw) -> dict:
    """Every held-out frame (sequence indices) by :func:`evaluate_holdout`; ``mean`` over them."""
    holdout = [int(h) for h in holdout]
    if not holdout:
        raise InputValueError("no frame held out")
    bad = [h for h in holdout if not 0 <= h < len(seq)]
    if bad:
        raise InputValueError(f"held-out frame(s) {bad} not in a sequence of {len(seq)} frames")
    t0 = time.perf_counter()
    st = kw.get("see_through")
    cache = FrameCache(seq, size=2 * (half or 2) + 3 + (2 * st.half if st else 0))
    frames = [evaluate_holdout(seq, h, sensor, methods, half, radius, drop_moving, cache=cache, **kw)
              for h in tqdm(holdout, desc="held-out frames", disable=not progress)]
    return {"frames": frames, "mean": mean_rows([f["table"] for f in frames]),
            "methods": list(methods), "window": {"half": half, "radius": radius}, "drop_moving": drop_moving,
            "see_through": st.to_dict() if st else None,
            "seconds": round(time.perf_counter() - t0, 3)}
