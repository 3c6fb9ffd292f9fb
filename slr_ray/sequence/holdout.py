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

No method reads the held-out frame's points: they give its fitted table (the
grid every method fills and is scored on) and the target it is scored
against. ``rays`` fits the sensor's rays on the *other* frames of the window
(:func:`holdout_ray_model`) and takes the target's motion from the poses;
``tests/test_sequence_rays.py`` moves the held-out frame's points along their
rays and checks that not one return changes.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from ..errors import InputValueError, SlrWarning
from ..evaluate import THRESHOLDS, evaluation_table, fitted_pattern, frame_beams, score_simulation, scoring_target
from ..metrics import PAPER_THRESHOLD
from ..options import Options
from ..metrics import metric_columns
from ..sensors import beams_outside, source_elevation_range
from ..sensors import sensor as shipped_sensor
from .estimators import FPA_GAP
from .frames import Sequence
from .methods import (LABELS, REGISTRY, HeldOut, adjacent_frame, check_methods, holdout_ray_model, method_options,
                      methods_with)
from .methods import method as registered_method
from .sources import BEAMS_FROM_BANDS, SeeThrough, known_beams
from .terrestrial import (AUTO, DEFAULT_SPINNING, SPINNING, TERRESTRIAL, ScoringGrid, auto_sensor, is_terrestrial,
                          sensor_kind, terrestrial_grid)
from .union import FrameCache, Keep, accumulate, to_frame, window

__all__ = ["METHODS", "LABELS", "HoldoutOptions", "evaluate_holdout", "evaluate_sequence", "mean_rows", "DEFAULT_METHODS",
           "clamped_depth_errors", "lidar4d_holdout", "LIDAR4D_MAX_DEPTH", "holdout_ray_model", "simulate_holdout",
           "GRID_SOURCES", "others_pattern", "scoring_grid", "one_frame_refusal", "check_held_out_kinds",
           "beamless_frames"]

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

#: the methods (:data:`slr_ray.sequence.methods.REGISTRY`: name -> method, the tables' order); those that
#: work here have the ``holdout`` capability
METHODS = REGISTRY
#: ``sequence evaluate``'s methods unless told (those with the ``default`` capability)
DEFAULT_METHODS = tuple(methods_with("default"))


def _beams(frame, base, seq=None):
    where = f" ({seq.paths[frame.index]})" if seq is not None else ""
    return known_beams(frame.points, frame.attributes, base, f"frame {frame.name}{where}")


def _held_beams(seq: Sequence, target: int, frame, base):
    """The held-out frame's beams as ``slr-ray evaluate`` takes a frame's
    (:func:`slr_ray.evaluate.frame_beams`: a ``ring`` field checked, else the scan order), or ``None``
    with a warning: its grid is then the shipped table, not fitted to it (a frame out of scan order,
    or of another sensor). Beams that fill under half the table's rows: a warning that the sensor
    may not be the frames' (``--source-sensor``)."""
    ring = frame.attributes.get("ring")
    beams, how = frame_beams(frame.points, "auto" if ring is None else ring, base,
                             f"frame {seq.names[target]}'s ring field")
    if beams is None:
        warnings.warn(f"frame {seq.names[target]}: beams not known (no ring field, not in {base.name}'s scan order "
                      f"of {base.n_beams} rings: another sensor (--source-sensor), or shuffled points?): scored on "
                      f"{base.name}'s grid as given (the shipped table or card), not one fitted to the frame",
                      SlrWarning, stacklevel=3)
        return None
    used = len(np.unique(beams[beams >= 0]))
    if 2 * used < base.n_beams:
        warnings.warn(f"frame {seq.names[target]}: its points lie on {used} of {base.name}'s {base.n_beams} beams: "
                      "are the frames of this sensor (--source-sensor)?", SlrWarning, stacklevel=3)
    return beams


@dataclass(frozen=True)
class HoldoutOptions(Options):
    """How :func:`evaluate_holdout` re-simulates a held-out frame and scores it.

    Attributes
    ----------
    sensor : str or BeamPattern
        The frames' sensor (its shipped table or card, or the pattern): a spinning unit's; or
        ``"terrestrial"`` (a uniform grid fitted to each held-out frame), or ``"auto"`` (each held-out
        frame's kind from its points: :func:`scoring_grid`, :mod:`slr_ray.sequence.terrestrial`; the
        default, as :func:`evaluate_sequence`'s: name ``"velodyne_hdl64e_s2"`` for the old default).
    methods : sequence of str
        A subset of :data:`METHODS`.
    half : int or None
        Frames each side of the held-out one accumulated (its window).
    radius : float or None
        Or the frames whose poses lie within this many metres.
    drop_moving : bool
        Leave out the points of moving objects (SemanticKITTI's labels).
    thresholds : sequence of float
        F-score thresholds (m).
    seen_threshold : float
        A point of the frame is seen when a point of the union lies strictly closer (m).
    fpa_gap : float
        The first-peak average's gap (m; ``fpa`` and ``rays``). ``gap=``, its old name, still works.
    see_through : SeeThrough or None
        Leave out of the union what other frames saw through (the held-out frame does not vote:
        it is what is scored).
    grid_from : str
        Where the held-out frame's scoring grid (each row's elevation, the column count) is fitted:
        ``"target"`` its own points (the default, as ``slr-ray evaluate`` fits a pair's), or
        ``"others"`` the other frames of its window (strictly leak-free: :func:`others_pattern`).
    method_options : dict or None
        The registered methods' other options by flat key (``PREFIX_FIELD``:
        :func:`slr_ray.sequence.methods.method_options`); over ``fpa_gap`` where both name it.
    target_sensor : str, BeamPattern or None
        The held-out frames' own unit where it is not ``sensor`` (a shipped name, a card's path or a
        pattern): their grid is fitted on its table, never the source's; the other frames stay
        ``sensor``'s. The target's beams outside the elevations the source frames saw are scored
        apart (:func:`reach_split`). None: the frames' sensor.
    """

    sensor: object = AUTO
    methods: tuple = DEFAULT_METHODS
    half: int | None = 2
    radius: float | None = None
    drop_moving: bool = True
    thresholds: tuple = THRESHOLDS
    seen_threshold: float = PAPER_THRESHOLD
    fpa_gap: float = FPA_GAP
    see_through: SeeThrough | None = None
    grid_from: str = "target"
    method_options: dict | None = None
    target_sensor: object = None

    @classmethod
    def of(cls, options=None, /, **keywords):
        """:meth:`Options.of`, ``gap`` (the old name of ``fpa_gap``) taken with a deprecation warning."""
        if isinstance(options, Mapping) and "gap" in options:
            options = {("fpa_gap" if k == "gap" else k): v for k, v in options.items()}
            warnings.warn("HoldoutOptions: gap is fpa_gap now", DeprecationWarning, stacklevel=2)
        if "gap" in keywords:
            warnings.warn("HoldoutOptions: gap= is fpa_gap= now", DeprecationWarning, stacklevel=2)
            keywords["fpa_gap"] = keywords.pop("gap")
        return super().of(options, **keywords)

    def flat_options(self) -> dict:
        """Every registered method's options by flat key (``fpa_gap`` and ``method_options`` over the defaults)."""
        return method_options({"fpa_gap": self.fpa_gap} | dict(self.method_options or {}))

    def methods_settings(self, names) -> dict:
        """The options (:class:`~slr_ray.sequence.methods.MethodOptions`) of each method of ``names``, by name."""
        flat = self.flat_options()
        return {name: REGISTRY[name].options.from_flat(flat) for name in names}


#: the splits of a held-out frame's scores (:data:`slr_ray.evaluate.SPLITS`: seen from the union or not)
HOLDOUT_SPLITS = ("seen",)

#: where a held-out frame's scoring grid may be fitted (HoldoutOptions.grid_from)
GRID_SOURCES = ("target", "others")


def others_pattern(others, base, cache: FrameCache):
    """``base`` fitted (:func:`~slr_ray.sensors.fitted_pattern`) to the frames ``others`` together, each
    in its own frame: each row's elevation the median of the others' points of its beam, the column
    count from their azimuth steps. ``base`` itself where no frame's beams are known."""
    pts, beams = [], []
    for i in others:
        f, _ = cache.get(i)
        b = _beams(f, base, cache.seq)
        if b is None or len(f.points) == 0:
            continue
        known = b >= 0
        pts.append(f.points[known])
        beams.append(b[known])
    if not pts:
        return base
    return fitted_pattern(np.concatenate(pts), np.concatenate(beams), base)


def _table_of(sensor):
    return shipped_sensor(sensor) if isinstance(sensor, str) else sensor


def reach_split(others, base, pattern, cache: FrameCache) -> dict:
    """Which of ``pattern``'s rows (a target unit's grid) the source frames ``others`` could fill: a
    beam outside the elevations they saw from their own origins (1st-99th percentile,
    :func:`~slr_ray.sensors.source_elevation_range`, as :func:`~slr_ray.sensors.conversion_reach`
    says a conversion's) is out of reach. Returns ``rows_out`` (``(rows,)`` bool) and what the
    result reports."""
    lo, hi = source_elevation_range(np.concatenate([cache.get(i)[0].points for i in others]))
    out = beams_outside(pattern, (lo, hi))
    rows_out = np.zeros(pattern.n_beams, bool)
    if len(out):
        rows_out[pattern.rows_of_beams(out)] = True
    return {"rows_out": rows_out, "report": {
        "source_elevation_range_deg": [round(lo, 3), round(hi, 3)], "target_beams_out_of_reach": int(len(out)),
        "target_beams_out_of_reach_deg": sorted(round(float(pattern.elevation_deg[b]), 3) for b in out)}}


def _reach_targets(b, beams, pat, u, rows_out, seen_threshold) -> dict:
    """The held-out frame's points on the target's beams in and out of the source's reach, each scored
    as a target of its own (:func:`slr_ray.evaluate.scoring_target`); a part with no point: absent."""
    keys, _ = pat.pulse_ids(b, np.zeros(3))
    out_pt = (keys >= 0) & rows_out[np.maximum(keys, 0) // pat.columns]
    parts = {}
    for name, m in (("in reach", ~out_pt), ("out of reach", out_pt)):
        if m.any() and (keys[m] >= 0).any():
            parts[name] = scoring_target(b[m], pat, None if beams is None else beams[m], u, seen_threshold,
                                         splits=HOLDOUT_SPLITS)
    return parts


def _reach_columns(parts, rows_out, pat, sim, img, thresholds, res) -> dict:
    """A method's F-score, depth errors and points on the target's rows in / out of the source's reach
    (its simulation's points and image cut to those rows; the rows cut away count as empty in both)."""
    keys, _ = pat.pulse_ids(sim, np.zeros(3))
    sim_out = (keys >= 0) & rows_out[np.maximum(keys, 0) // pat.columns]
    cols = {}
    for name, target in parts.items():
        keep_rows = rows_out if name == "out of reach" else ~rows_out
        im = np.where(keep_rows[:, None], img, np.nan)
        pts = sim[sim_out] if name == "out of reach" else sim[~sim_out]
        c = metric_columns(score_simulation(target, pts, im, thresholds), res)
        cols |= {f"{k} {name}": c[k] for k in ("F@5cm", "depth_medae_m", "depth_rmse_m") if k in c}
        cols[f"points {name}"] = int(len(pts))
        cols[f"target points {name}"] = int(len(target.points))
    return cols


def scoring_grid(seq: Sequence, target: int, frame, sensor, grid_from: str, others, cache: FrameCache) -> ScoringGrid:
    """The held-out frame's scoring grid (:class:`~slr_ray.sequence.terrestrial.ScoringGrid`): ``sensor`` a
    beam table (or its name, a card): spinning, that table fitted to the frame (or to ``others``); ``"auto"``:
    spinning on the shipped table :func:`~slr_ray.sequence.terrestrial.auto_sensor` finds (a ring field,
    a shipped sensor's scan order or elevation bands), else terrestrial; ``"terrestrial"``: a uniform grid fitted to the frame (or to the
    adjacent frame of ``others``)."""
    if isinstance(sensor, str) and sensor == AUTO:
        what = (f"frame {seq.names[target]} ({seq.paths[target]}), read with the default {DEFAULT_SPINNING}'s table "
                "(no --source-sensor named)")
        found = auto_sensor(frame.points, frame.attributes, what)
        sensor = found if found is not None else TERRESTRIAL
        if found is not None and grid_from != "others" and found.meta.get("beams_from") == BEAMS_FROM_BANDS:
            beams = known_beams(frame.points, frame.attributes, found)  # found by its bands: they are its beams
            return ScoringGrid(SPINNING, fitted_pattern(frame.points, beams, found), beams, found,
                               f"spinning: {found.name}'s beam table fitted to the frame (no ring field, not in "
                               "scan order: its points on that table's elevation bands, its beams)")
    if is_terrestrial(sensor):
        own = grid_from == "target"
        source = frame if own else cache.get(adjacent_frame(others, target))[0]
        pattern, how, yaw = terrestrial_grid(source.points, f"frame {seq.names[source.index]}", turn_columns=own)
        if not own:  # the steps of the adjacent setup's grid; its columns from the frame's own x axis
            how += f" (frame {seq.names[source.index]}, the adjacent one: --grid-from others)"
        return ScoringGrid(TERRESTRIAL, pattern, None, None, how, yaw)
    base = shipped_sensor(sensor) if isinstance(sensor, str) else sensor
    if grid_from == "others":
        return ScoringGrid(SPINNING, others_pattern(others, base, cache), _beams(frame, base, seq), base,
                           f"spinning: {base.name}'s beam table fitted to the other frames of the window")
    beams = _held_beams(seq, target, frame, base)
    if beams is None:
        return ScoringGrid(SPINNING, base, None, base, f"spinning: {base.name}'s shipped table (the frame's beams "
                                                       "not known)")
    return ScoringGrid(SPINNING, fitted_pattern(frame.points, beams, base), beams, base,
                       f"spinning: {base.name}'s beam table fitted to the frame")


def _check_kind(grid: ScoringGrid, methods, see_through=None) -> None:
    """Refuse, before any method runs, the methods (and the see-through removal) that need the frames' beam
    table on a terrestrial grid."""
    if grid.base is None and see_through is not None:
        raise InputValueError(f"--remove-moving visibility casts the frames' own beams: {grid.how.split(':')[0]} "
                              "frames have none (leave it out, or name the frames' sensor if they are a spinning "
                              "unit's: --source-sensor)")
    if grid.base is None:
        need = [m for m in methods if REGISTRY[m].needs_source_sensor]
        if need:
            raise InputValueError(f"{', '.join(need)} need(s) the frames' beam table ({REGISTRY[need[0]].source_why}): "
                                  f"{grid.how.split(':')[0]} frames have none; use embree-knn, or name the frames' "
                                  "sensor if they are a spinning unit's (--source-sensor)")


def beamless_frames(seq: Sequence, frames, base, until_known: bool = False) -> list:
    """The names of the frames ``frames`` whose beams ``base``'s table does not know (no ring field, not in
    its scan order: :func:`~slr_ray.sequence.terrestrial.sensor_kind` terrestrial; ``base`` None: no shipped
    table, :func:`~slr_ray.sequence.terrestrial.auto_sensor`); ``until_known``: stop at
    the first frame it knows. A frame whose header holds a ``ring`` field is known without reading it
    (:meth:`~slr_ray.sequence.layouts.FrameSource.fields`); any other is read, its points only."""
    flat = []
    for h in frames:
        names = seq.layout.fields(seq, h)
        if names is not None and "ring" in names:
            kind = SPINNING
        else:
            pts, attrs = seq.layout.frame(seq, h)
            if base is None:
                kind = SPINNING if auto_sensor(pts, attrs) is not None else TERRESTRIAL
            else:
                kind = sensor_kind(pts, attrs, base)
        if kind == TERRESTRIAL:
            flat.append(seq.names[h])
        elif until_known:
            break
    return flat


def check_held_out_kinds(seq: Sequence, holdout, sensor, methods, see_through=None) -> None:
    """With ``sensor`` ``"auto"``, refuse up front (before any window is read, any grid fitted, any frame
    registered) the methods and the see-through removal that need the frames' beam table where a held-out
    frame is terrestrial (:func:`_check_kind`'s refusal, naming the frames): :func:`beamless_frames` in no
    shipped table (:func:`~slr_ray.sequence.terrestrial.auto_sensor`), as :func:`scoring_grid` decides."""
    if not (isinstance(sensor, str) and sensor == AUTO):
        return
    if see_through is None and not any(REGISTRY[m].needs_source_sensor for m in methods if m in REGISTRY):
        return
    flat = beamless_frames(seq, holdout, None)
    if flat:
        try:
            _check_kind(ScoringGrid(TERRESTRIAL, None, None, None, "terrestrial"), methods, see_through)
        except InputValueError as exc:
            raise InputValueError(f"held-out frame(s) {', '.join(flat)} (no ring field, in no shipped sensor's "
                                  f"scan order or elevation bands): {exc}") from None


def evaluate_holdout(seq: Sequence, target: int, options: HoldoutOptions | None = None, *,
                     cache: FrameCache | None = None, **keywords) -> dict:
    """Frame ``target`` re-simulated from the other frames of its window by every method
    (``options``: a :class:`HoldoutOptions`, or its fields as keywords)."""
    o = HoldoutOptions.of(options, **keywords)
    sensor, half, radius, drop_moving = o.sensor, o.half, o.radius, o.drop_moving
    thresholds, seen_threshold, see_through = o.thresholds, o.seen_threshold, o.see_through
    if o.grid_from not in GRID_SOURCES:
        raise InputValueError(f"grid_from {o.grid_from!r}: choose from {list(GRID_SOURCES)}")
    methods = check_methods(o.methods, "holdout")
    settings, gap = o.methods_settings(methods), o.flat_options()["fpa_gap"]
    cross = o.target_sensor is not None
    if cross and o.grid_from == "others":
        raise InputValueError("grid_from 'others' fits the held-out frame's grid on the other frames: they are the "
                              "source's, not the target sensor's (use grid_from 'target')")
    if cross and isinstance(sensor, str) and sensor == AUTO:
        raise InputValueError("a target sensor is scored against the source frames' own table: name it "
                              "(--source-sensor)")
    cache = cache or FrameCache(seq)
    others = window(seq, target, half, radius)
    if not others:
        raise InputValueError(f"frame {seq.names[target]}: no other frame in its window")
    fb, _ = cache.get(target)
    grid = scoring_grid(seq, target, fb, o.target_sensor if cross else sensor, o.grid_from, others, cache)
    _check_kind(grid, methods, see_through)
    pat, beams, base = grid.pattern, grid.beams, grid.base
    if cross:  # the grid is the target's; the other frames (their beams, the rays' fit) the source's
        tbase, base = grid.base, _table_of(sensor)
    b, pose = grid.turned(fb.points), grid.turned_pose(fb.pose)  # the frame in its grid's axes
    band_keys, _ = pat.pulse_ids(b, np.zeros(3))
    in_view = band_keys >= 0
    if not in_view.any():
        raise InputValueError(f"{seq.paths[target]}: none of its points lies within {pat.name}'s view about "
                              "its origin (is the frame in its sensor's frame?)")
    keep = Keep(drop_moving, see_through, (target,))
    union = accumulate(seq, others, keep, cache=cache)
    u = to_frame(union.points, pose)
    if len(u) and not np.any(pat.pulse_ids(u, np.zeros(3))[0] >= 0):  # as slr-ray evaluate refuses a pair
        raise InputValueError(f"frame {seq.names[target]}: at its pose none of the {len(u)} points of its window "
                              f"({', '.join(seq.names[i] for i in others)}) lies within its view: the frames do not "
                              "overlap there; check the poses")
    # scored as slr-ray evaluate scores a pair (the same target, every registered metric's block), split
    # by seen / unseen only
    scored = scoring_target(b, pat, beams, u, seen_threshold, splits=HOLDOUT_SPLITS)
    real_img, b_in, seen = scored.image, scored.points, scored.seen
    adj = adjacent_frame(others, target)
    rows, extra = [], {}
    infos = {REGISTRY[m].info: None for m in REGISTRY if REGISTRY[m].info}  # every key, run or not
    held = HeldOut(seq, target, others, union, u, pat, base, cache, pose, keep,
                   target_base=tbase if cross else None)
    reach = reach_split(others, base, pat, cache) if cross else None
    parts = _reach_targets(b, beams, pat, u, reach["rows_out"], seen_threshold) if cross else {}
    by_reach = {}
    for m in methods:
        t0 = time.perf_counter()
        ret, sim, info = REGISTRY[m].simulate(held, settings[m])
        if REGISTRY[m].info:
            infos[REGISTRY[m].info] = info
        img = ret.image(pat)
        blocks = score_simulation(scored, sim, img, thresholds)
        extra[m] = clamped_depth_errors(real_img["range"], img)
        if cross:
            by_reach[m] = _reach_columns(parts, reach["rows_out"], pat, sim, img, thresholds, {
                "thresholds": [float(x) for x in thresholds], "seen_threshold": seen_threshold})
        rows.append({"method": m, "label": LABELS[m], "points_out": int(len(sim)), "pulses_returned": int(len(ret)),
                     "seconds": round(time.perf_counter() - t0, 3)} | blocks)
    res = {"frame": seq.names[target], "fpa_gap_m": gap} | infos | {"index": int(target), "window": [seq.names[i] for i in others],
           "adjacent": seq.names[adj], "union_points": int(len(union)), "removed": union.removed,
           "see_through": see_through.to_dict() if see_through else None,
           "target_points_in_view": int(len(b_in)), "in_view_share": float(len(b_in) / len(b)),
           "unseen_share": float(np.mean(~seen)), "sensor_kind": grid.kind, "grid": grid.how,
           "grid_yaw_deg": float(np.degrees(grid.yaw)),
           "pattern": pat.to_dict() | {"beams_known": beams is not None, "grid_from": o.grid_from},
           "thresholds": [float(x) for x in thresholds], "seen_threshold": seen_threshold, "rows": rows,
           "target_sensor": (getattr(tbase, "name", None) if cross else None)} | (reach["report"] if cross else {})
    res["table"] = [{"frame": res["frame"]} | r
                    | {"lidar4d_depth_rmse_m": extra[m][0], "lidar4d_depth_medae_m": extra[m][1]}
                    | by_reach.get(m, {})
                    for m, r in zip(methods, evaluation_table(res))]
    return res


def simulate_holdout(seq: Sequence, target: int, method: str = "rays", sensor: str = AUTO,
                     half: int | None = 2, drop_moving: bool = True, gap: float = FPA_GAP, pattern=None):
    """What ``method`` returns for the held-out frame ``target`` (a :class:`PulseReturns` in ``pattern``,
    default the target's fitted table as :func:`evaluate_holdout` fits it). The held-out frame's points
    are read for its table only: every method's returns depend on its pose and the other frames.
    ``sensor`` as :class:`HoldoutOptions`' (default ``"auto"``, as :func:`evaluate_sequence`'s)."""
    m = registered_method(method, "holdout")
    cache = FrameCache(seq)
    others = window(seq, target, half)
    if not others:
        raise InputValueError(f"frame {seq.names[target]}: no other frame in its window")
    fb, _ = cache.get(target)
    grid = scoring_grid(seq, target, fb, sensor, "target", others, cache)
    _check_kind(grid, (method,))
    base, pattern, pose = grid.base, grid.pattern if pattern is None else pattern, grid.turned_pose(fb.pose)
    keep = Keep(drop_moving, None, (target,))
    union = accumulate(seq, others, keep, cache=cache)
    held = HeldOut(seq, target, others, union, to_frame(union.points, pose), pattern, base, cache, pose, keep)
    return m.simulate(held, HoldoutOptions.of(None, fpa_gap=gap).methods_settings((method,))[method])[0]


def mean_rows(tables: list[list[dict]]) -> list[dict]:
    """Per method, the mean over frames of every numeric column (``frame``: ``"mean"``); a column of
    counts (integers in every frame: ``points``) takes its mean rounded to an integer."""
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
                if finite and all(isinstance(v, int) for v in vals):
                    row[k] = int(round(row[k]))
        out.append(row)
    return out


def one_frame_refusal(seq: Sequence) -> str:
    """Why a sequence of one frame cannot be evaluated (one line)."""
    return (f"{seq.root or seq.paths[0]}: a sequence of {len(seq)} frame (one scan): a held-out frame is "
            "re-simulated from the other frames, so evaluation needs two or more (a campaign's registered setups, "
            "a drive's frames); slr-ray scan or augment re-simulate one scan from other positions")


def evaluate_sequence(seq: Sequence, holdout, sensor: str = AUTO, methods=DEFAULT_METHODS,
                      half: int | None = 2, radius: float | None = None, drop_moving: bool = True,
                      progress: bool = False, **kw) -> dict:
    """Every held-out frame (sequence indices) by :func:`evaluate_holdout`; ``mean`` over them.

    ``sensor`` (:class:`HoldoutOptions`' ``sensor``) defaults to ``"auto"``, as ``slr-ray sequence
    evaluate`` without ``--source-sensor``: each held-out frame with a ring field or in
    ``velodyne_hdl64e_s2``'s scan order (KITTI's) is scored on that spinning unit's table, as the
    old default scored it; any other on a terrestrial scanner's grid fitted to it (the old default
    scored it on the HDL-64E's table, with a warning). Name the sensor (``"velodyne_hdl64e_s2"``, a card)
    for the old behaviour everywhere, and with ``target_sensor`` (a target unit is re-simulated from
    the source frames' own table: ``"auto"`` is refused there)."""
    holdout = [int(h) for h in holdout]
    if len(seq) < 2:
        raise InputValueError(one_frame_refusal(seq))
    if not holdout:
        raise InputValueError("no frame held out")
    bad = [h for h in holdout if not 0 <= h < len(seq)]
    if bad:
        raise InputValueError(f"held-out frame(s) {bad} not in a sequence of {len(seq)} frames")
    t0 = time.perf_counter()
    st = kw.get("see_through")
    if kw.get("target_sensor") is not None:
        seq = seq.of_mixed_sensors()  # the held-out frames may be another unit's
    cache = FrameCache(seq, size=2 * (half or 2) + 3 + (2 * st.half if st else 0))
    options = HoldoutOptions.of(None, sensor=sensor, methods=methods, half=half, radius=radius,
                                drop_moving=drop_moving, **kw)
    frames = [evaluate_holdout(seq, h, options, cache=cache)
              for h in tqdm(holdout, desc="held-out frames", disable=not progress)]
    return {"frames": frames, "mean": mean_rows([f["table"] for f in frames]),
            "methods": list(methods), "window": {"half": half, "radius": radius}, "drop_moving": drop_moving,
            "see_through": st.to_dict() if st else None, "target_sensor": frames[0].get("target_sensor"),
            "seconds": round(time.perf_counter() - t0, 3)}
