"""A real pair of frames: scan B re-simulated from scan A at B's pose, scored against the real B.

The smallest real test of SLR. Two frames of one sensor, taken a short way
apart (two consecutive KITTI frames: the vehicle moved well under a metre):

1. **register** B to A (:func:`register`: Open3D ICP, point-to-plane, from
   the identity, coarse to fine; a coarse FPFH + RANSAC alignment first when
   ICP from the identity finds too few correspondences). The pose of B in A's
   frame, its fitness (share of B's points with an A point within the final
   correspondence distance) and inlier RMSE are recorded;
2. **move A into B's frame** and **re-simulate B** from it with B's sensor:
   B's own beam table when B's points carry their beams (a ``ring`` field, or
   the scan order of a KITTI ``.bin``: :func:`scan_order_beams`), fitted to B
   (:func:`fitted_pattern`: each beam's elevation the median of its points'),
   otherwise the shipped table (``sensor``);
3. **score** each method (:data:`METHODS`) against the real B with
   :mod:`slr_ray.metrics`: Chamfer distance and F-scores against all of B's
   points in its table's view, depth errors and ray drop against B's range
   image, each split by range band, beam and whether the part of B was seen
   from A. B's range image is made by the rule every simulated image is made
   by (nearest point per pulse, a point in the elevation band of the fitted
   table it falls in; as the novel-view papers project their ground truth), so
   a simulation equal to B scores a perfect image. (B's own beams set the
   table's elevations and the beam split, not the rows: on KITTI's frames the
   two differ for half of the points, and a frame scored against itself with
   beam rows for the real image and bands for the simulated one came out at
   1.85 m depth RMSE.)

Methods
-------
``zbuffer`` (no SLR)
    The baseline a user tries first: every point of A, moved to B's pose,
    that lies in B's field of view and range limits. Its range image is a
    z-buffer of those points in B's range image (nearest per pulse).
    **For a beam table that z-buffer is the binning rule itself**, pulse for
    pulse (both keep the nearest point per (beam band, column), ties to the
    lowest index; ``images_identical`` in the result checks it on every run):
    the novel-view papers' "project and keep the nearest per pixel" *is*
    SLR's binning on a range image. The baseline differs from binning only in
    its points: it keeps every point of A behind the nearest (no visibility
    rule), which the point metrics see.
``binning``
    :func:`slr_ray.prepare` ``(A, "binning")``: the nearest point per pulse.
``embree-knn``
    ``prepare(A, "embree")`` with its defaults and nothing about the primary:
    discs sized and oriented from the k nearest neighbours.
``embree-grid``
    ``prepare(A, "embree", primary_origin=A's origin, primary_pattern=A's
    table)``: the defaults a user gets by naming the primary (pulse-grid
    neighbours, tie window 3, discs turned to at most 80 deg).
``embree-beams``
    The same with ``primary_beams`` (each of A's points in its own beam's row
    of the pulse grid); only when A's beams are known.

A is moved into B's frame in float64; the primary's pulse grid is then tilted
by the (small) rotation between the frames, which moves rows of the
beam-table grid (not of the primary-beams grid, whose rows are the beams).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .arrays import as_points, as_rigid_pose
from .backends import BACKENDS, prepare, scanner_class
from .errors import InputValueError, SlrWarning
from .metrics import FIELD_THRESHOLD, LIDAR4D_CODE_THRESHOLD, PAPER_THRESHOLD, Pair, range_bands, score_pair, seen_from
from .options import Options
from .progress import bar as progress_bar, phase
from .registration import REGISTRATION_BOUNDS, Registration, check_registration, register
from .reports import (EVALUATION_FILES, SEQUENCE_COLUMNS, compact_json, evaluation_table, markdown_table,  # noqa: F401
                      reach_table, sequence_summary, splits_table, write_evaluation, write_sequence_evaluation)
from .scan import Scan
from .sensors import BeamPattern, fitted_pattern, scan_order_beams, sensor

__all__ = ["METHODS", "BEAM_SOURCES", "EVALUATION_FILES", "LABELS", "Registration", "register", "scan_order_beams", "fitted_pattern", "zbuffer",
           "EvaluateOptions", "evaluate_pair", "evaluation_table", "markdown_table", "splits_table", "compact_json",
           "write_evaluation", "frame_beams", "SPLITS", "ScoringTarget", "scoring_target", "score_simulation", "write_sequence_evaluation", "SEQUENCE_COLUMNS", "sequence_summary",
           "REACH", "source_reach", "reach_table", "rig_extrinsic"]

#: the methods scored, in table order, and their names in tables and figures
METHODS = ("zbuffer", "binning", "embree-knn", "embree-grid", "embree-beams")
LABELS = {"zbuffer": "no SLR (z-buffer)", "binning": "binning", "embree-knn": "embree (kNN discs)",
          "embree-grid": "embree (beam-table grid)", "embree-beams": "embree (primary beams)"}
BASELINE = METHODS[0]
#: the backend of each SLR method and what it is told of the primary (A): nothing, its origin and
#: pattern, or those and its beams; any other registered backend is a method of its own name (nothing)
METHOD_SCANS = {"binning": ("binning", None), "embree-knn": ("embree", None), "embree-grid": ("embree", "pattern"),
                "embree-beams": ("embree", "beams")}
#: the method whose range image is checked against the z-buffer's (``images_identical``)
BINNING_METHOD = "binning"
#: F-score thresholds of the table: the field's 5 cm, SLR's 10 cm, LiDAR-NeRF/LiDAR4D code's 22.4 cm
THRESHOLDS = (FIELD_THRESHOLD, PAPER_THRESHOLD, LIDAR4D_CODE_THRESHOLD)
#: registrations below this fitness are refused by :func:`evaluate_pair` (the gate's bound,
#: :data:`slr_ray.registration.REGISTRATION_BOUNDS`; real overlapping pairs: 0.84-0.99)
MIN_FITNESS = REGISTRATION_BOUNDS["min_fitness"]
#: registrations whose inlier RMSE exceeds this share of the final correspondence distance are refused
#: (KITTI's pairs: 0.072-0.075 m of 0.2; pairs spread evenly within 0.2 m give 0.115 m and more)
MAX_RMSE_SHARE = REGISTRATION_BOUNDS["max_rmse_share"]
#: frames with fewer points than this are not registered (a pose from 40 points is not to be trusted)
MIN_REGISTRATION_POINTS = 1000


# --- frames -------------------------------------------------------------------------------------------------

def zbuffer(points, pattern: BeamPattern, origin=(0.0, 0.0, 0.0), beams=None, backend: str = "z-buffer") -> Scan:
    """The nearest point per pulse of ``pattern`` (ties to the lowest index), as a :class:`Scan`.

    With ``beams`` each point goes to its own beam's row (a real frame's
    range image); without, to the band its elevation falls in, which is the
    binning backend's rule exactly.
    """
    p = as_points(points, "points")
    o = np.asarray(origin, np.float64)
    keys, ranges = pattern.pulse_ids(p, o, beams=beams)
    ok = np.flatnonzero(keys >= 0)
    order = np.lexsort((ok, ranges[ok], keys[ok]))  # by pulse, then range, then index
    k = keys[ok][order]
    first = np.r_[True, k[1:] != k[:-1]] if len(k) else np.zeros(0, bool)
    idx = ok[order][first]
    srt = np.argsort(idx, kind="stable")
    idx = idx[srt]
    return Scan.from_keys(k[first][srt], ranges[idx], idx, o, pattern, backend, len(p))


# --- the evaluation -----------------------------------------------------------------------------------------

def _resolve_sensor(name_or_pattern) -> BeamPattern:
    p = sensor(name_or_pattern) if isinstance(name_or_pattern, str) else name_or_pattern
    if not getattr(p, "has_beams", False):
        raise InputValueError(f"sensor must be a shipped sensor name or a BeamPattern, got {name_or_pattern!r}")
    return p


#: the beam sources of :func:`evaluate_pair`'s ``a_beams`` / ``b_beams`` besides an array
BEAM_SOURCES = ("auto", "scan-order")


def _beam_spread_problem(points, beams, base) -> str | None:
    """Why ``beams`` are not a scan's beams (None when they are): each beam's points must lie at one
    elevation (the median of the beams' median absolute deviations within twice the table's mean beam
    spacing; KITTI's frames: 0.24 deg against 0.95), and their azimuth step give a column count within
    8 times the table's (a random or shuffled ring field spreads over tens of degrees)."""
    p = as_points(points, "points")
    b = np.asarray(beams, np.int64)
    r = np.linalg.norm(p, axis=1)
    el = np.degrees(np.arcsin(np.divide(p[:, 2], r, out=np.zeros_like(r), where=r > 0)))
    az = np.arctan2(p[:, 1], p[:, 0])
    mads, steps = [], []
    for i in np.unique(b[b >= 0]):
        mine = b == i
        e = el[mine]
        mads.append(np.median(np.abs(e - np.median(e))))
        d = np.abs(np.diff(np.unwrap(az[mine])))
        d = d[d > 0]
        if len(d):
            steps.append(np.median(d))
    if not mads:
        return "no point has a beam (every id is -1)"
    spacing = float(np.mean(np.diff(np.sort(base.elevation_deg)))) if base.n_beams > 1 else 1.0
    spread = float(np.median(mads))
    if spread > 2 * spacing:
        return (f"their beams' points spread over {spread:.2f} deg of elevation (median absolute deviation), more "
                f"than twice the table's beam spacing ({spacing:.2f} deg): not a scan's beams")
    columns = 2 * math.pi / float(np.median(steps)) if steps else float(base.columns)
    if not base.columns / 8 <= columns <= base.columns * 8:
        return (f"their beams' azimuth step gives {columns:.4g} columns a turn, against the table's "
                f"{base.columns}: not a scan's beams")
    return None


def _beams_of(points, beams, base, what):
    """``(beams or None, how they were found)``; 'auto' falls back to none, saying why."""
    if isinstance(beams, str):
        if beams not in BEAM_SOURCES:
            raise InputValueError(f"{what} must be an array, None, 'auto' or 'scan-order', got {beams!r}")
        found = scan_order_beams(points, base.n_beams)
        why = (f"the points are not stored ring after ring in {base.n_beams} rings of one turn each, highest "
               "beam first (a KITTI .bin's order)") if found is None else _beam_spread_problem(points, found, base)
        if why is None:  # the scan order's rows as the table's beam ids, as an array's (fitted_pattern, pulse_ids)
            return np.asarray(base.beam_of_row)[found], "scan order"
        if beams == "scan-order":
            raise InputValueError(f"{what}: not in scan order: {why}")
        return None, f"none: not in scan order ({why})"
    if beams is None:
        return None, "none"
    b = np.asarray(beams)
    try:
        base.rows_of_beams(b, len(points))  # one integer a point, in the table
    except InputValueError as exc:
        raise InputValueError(f"{what}: {exc}") from None
    why = _beam_spread_problem(points, b, base)
    if why is not None:
        raise InputValueError(f"{what}: {why}")
    return b.astype(np.int64), "given"


def _split_labels(rows_of_points, ranges, seen):
    return {"range band": range_bands(ranges), "beam": rows_of_points,
            "seen": np.where(seen, "seen", "unseen")}


def frame_beams(points, beams, base, what: str = "beams"):
    """A frame's beams as :func:`evaluate_pair` takes them (its ``a_beams`` / ``b_beams``): an array
    (checked against ``base``'s table: ids in it, one elevation a beam), ``None``, ``'auto'`` or
    ``'scan-order'``. Returns ``(beams or None, how they were found)``; ``'auto'`` falls back to
    ``None`` saying why."""
    return _beams_of(points, beams, base, what)


#: the splits of a score (``groups`` of its blocks): by range band, by beam, seen from the primary or not
SPLITS = ("range band", "beam", "seen")


@dataclass
class ScoringTarget:
    """A real frame as every simulation of it is scored (:func:`scoring_target`)."""

    pattern: BeamPattern
    real: Scan              # the frame's own z-buffer in ``pattern`` (nearest point per pulse)
    image: dict             # its range image (``range``, ``index``)
    in_view: np.ndarray     # (n,) bool: the frame's points in the pattern's view
    points: np.ndarray      # (m, 3) those points: the target
    seen: np.ndarray        # (m,) bool: seen from the primary
    pixels: np.ndarray      # (rows, cols) each pulse's split label: seen, unseen, no return
    point_groups: dict
    splits: tuple = SPLITS
    pulse_groups: dict = field(default_factory=dict)  # further splits' labels per pulse (``source``)


def scoring_target(points, pattern, beams, primary, seen_threshold: float = PAPER_THRESHOLD,
                   splits=SPLITS) -> ScoringTarget:
    """The real frame ``points`` (its own frame) as :func:`evaluate_pair` scores every method against it:
    its range image by the rule every simulated image is made by (nearest point per pulse of
    ``pattern``, a point in the elevation band it falls in), so that a simulation equal to it scores a
    perfect image; the target points are its points in that table's view, each *seen* when a point
    of ``primary`` (the cloud the simulations come from, in the frame's frame) lies closer than
    ``seen_threshold``; the beam split by ``beams`` where known, else by band row. ``splits``: the
    groups scored (a subset of :data:`SPLITS`)."""
    band_keys, ranges = pattern.pulse_ids(points, np.zeros(3))
    in_view = band_keys >= 0
    real = zbuffer(points, pattern, backend="real")
    image = real.range_image()
    inside = points[in_view]
    if beams is not None:
        rows = pattern.rows_of_beams(beams, len(points))[in_view]
    else:
        rows = band_keys[in_view] // pattern.shape[1]
    seen = seen_from(inside, primary, seen_threshold)
    seen_all = np.zeros(len(points), bool)
    seen_all[in_view] = seen
    groups = _split_labels(rows, ranges[in_view], seen)
    pixels = np.full(image["range"].shape, "no return", dtype=object)
    filled = image["index"] >= 0
    pixels[filled] = np.where(seen_all[image["index"][filled]], "seen", "unseen")
    return ScoringTarget(pattern, real, image, in_view, inside, seen, pixels,
                         {k: v for k, v in groups.items() if k in splits}, tuple(splits))


def score_simulation(target: ScoringTarget, simulated, image, thresholds=THRESHOLDS) -> dict:
    """Every registered metric's block (:data:`slr_ray.metrics.REGISTRY`) of a simulation of ``target``:
    its points ``simulated`` and its range image ``image`` (in the target's pattern)."""
    real = target.image["range"]
    sim_ranges = np.where(np.isfinite(real), real, image)
    pulses = {"range band": range_bands(sim_ranges), "beam": np.arange(target.pattern.shape[0]),
              "seen": target.pixels.astype(str)}
    return score_pair(Pair(target.points, simulated, real, image, tuple(thresholds), target.point_groups,
                           {k: v for k, v in pulses.items() if k in target.splits} | target.pulse_groups))


#: what a source could have seen of each target point (the ``source`` split of :func:`evaluate_pair`), in
#: table order; a pulse with no real return is ``"no return"``
REACH = ("seen by source", "in source view, unseen", "outside source range", "outside source FOV")


def source_reach(points, transform, source_pattern: BeamPattern, source_points, seen) -> np.ndarray:
    """Each target point labelled by what the source frame could have seen of it (:data:`REACH`).

    ``points`` (m, 3): the target's, in its own frame; ``transform``: the target's pose in the source's
    frame (``a = R b + t``); ``seen`` (m,) bool: a source point lies near it. Unseen points are *outside
    source FOV* (no elevation band of ``source_pattern`` holds them, seen from the source's origin),
    *outside source range* (beyond the ranges the source frame's points span, within its table's limits),
    or else *in source view, unseen* (hidden from the source, or its pulse dropped)."""
    R, t = np.asarray(transform, np.float64)[:3, :3], np.asarray(transform, np.float64)[:3, 3]
    in_a = as_points(points, "points") @ R.T + t
    keys, ranges = source_pattern.with_(min_range=None, max_range=None).pulse_ids(in_a, np.zeros(3))
    r_a = np.linalg.norm(as_points(source_points, "source_points"), axis=1)
    lo, hi = source_pattern.range_limits
    lo, hi = max(lo, float(r_a.min(initial=np.inf))), min(hi, float(r_a.max(initial=0.0)))
    labels = np.full(len(in_a), REACH[3], dtype=object)
    fov = keys >= 0
    labels[fov] = np.where((ranges[fov] >= lo) & (ranges[fov] <= hi), REACH[1], REACH[2])
    labels[np.asarray(seen, bool)] = REACH[0]
    return labels.astype(str)


def _reach(target: ScoringTarget, b, T, pat_a, a) -> dict:
    """Adds the ``source`` split (:func:`source_reach`) to ``target``'s points and pulses; returns its counts
    (target points and real pulses per label: they sum to the target's)."""
    labels = source_reach(target.points, T, pat_a, a, target.seen)
    every = np.full(len(b), "no return", dtype=object)
    every[target.in_view] = labels
    pixels = np.full(target.image["range"].shape, "no return", dtype=object)
    filled = target.image["index"] >= 0
    pixels[filled] = every[target.image["index"][filled]]
    target.point_groups["source"] = labels
    target.pulse_groups["source"] = pixels.astype(str)
    return {"labels": list(REACH), "points": {k: int(np.count_nonzero(labels == k)) for k in REACH},
            "pulses": {k: int(np.count_nonzero(pixels == k)) for k in (*REACH, "no return")}}


@dataclass(frozen=True)
class EvaluateOptions(Options):
    """How :func:`evaluate_pair` re-simulates and scores a pair of frames.

    Attributes
    ----------
    sensor : str or BeamPattern
        The frames' sensor: a shipped name, a sensor card's path (``.json``)
        or a pattern (columns, range limits; the elevations where a frame's
        beams are unknown). ``source_sensor``'s old name.
    source_sensor : str or BeamPattern, optional
        Frame A's sensor (default ``sensor``).
    target_sensor : str or BeamPattern, optional
        Frame B's sensor (default the source's): another unit of the rig,
        re-simulated at its pose from A; B's pose must then be given
        (``transform`` or ``extrinsic``).
    methods : sequence of str
        A subset of :data:`METHODS`, or registered backends' names.
    seen_threshold : float
        A point of B is seen from A when an A point lies strictly closer (m).
    thresholds : sequence of float
        F-score thresholds (m).
    min_fitness : float
        A registration whose fitness (share of B's points with an A point
        within 0.2 m after the fit) is below this is refused: the pose is not
        to be trusted (frames that do not overlap, too few points). 0 accepts
        any; ignored with ``transform``. Registering also needs
        :data:`MIN_REGISTRATION_POINTS` points in each frame.
    max_rmse : float or None
        A registration whose inlier RMSE exceeds this (m; default
        :data:`MAX_RMSE_SHARE` of the 0.2 m correspondence distance) is
        refused; ignored with ``transform``.
    accept_registration : bool
        Score at the pose registration finds whatever it measures: the gate
        (:func:`slr_ray.registration.registration_checks`: fitness, reverse
        fitness, inlier RMSE, tilt; docs/evaluation.md "Registration gate")
        is skipped. Default False: a registration failing a check is refused.
    """

    sensor: str | BeamPattern = "velodyne_hdl64e_s2"
    methods: tuple | str = METHODS
    seen_threshold: float = PAPER_THRESHOLD
    thresholds: tuple = THRESHOLDS
    min_fitness: float = MIN_FITNESS
    max_rmse: float | None = None
    source_sensor: str | BeamPattern | None = None
    target_sensor: str | BeamPattern | None = None
    accept_registration: bool = False


def evaluate_pair(a_points, b_points, a_beams="auto", b_beams="auto", options: EvaluateOptions | None = None, *,
                  transform=None, extrinsic=None, progress: bool = False, **keywords) -> dict:
    """Re-simulate frame B from frame A at B's pose and score every method against the real B.

    Parameters
    ----------
    a_points, b_points : (n, 3), (m, 3) float
        Each frame in its own sensor frame (the sensor at the origin).
    a_beams, b_beams : (n,) int, None, 'auto' or 'scan-order'
        The beam (table position, -1 unknown) of each point; ``'scan-order'``
        derives them from the file order (:func:`scan_order_beams`) and
        refuses a frame not in scan order; ``'auto'`` (default) falls back to
        none there (``patterns``' ``beams`` in the result says which, and
        why). Beams, given or derived, whose points do not lie at one
        elevation a beam (a random or shuffled ring field) are refused.
    options : EvaluateOptions or dict, optional
        The sensor, the methods, the thresholds and the registration's
        bounds (``sensor``, ``methods``, ``seen_threshold``, ``thresholds``,
        ``min_fitness``, ``max_rmse``: described once, in
        :class:`EvaluateOptions`); each field may also be given as a keyword
        (``sensor="velodyne_vlp16"``, ``methods=("binning",)``).
    transform : (4, 4) float, optional
        B's pose in A's frame (``a = R b + t``), instead of registering: a
        rigid pose (:func:`slr_ray.arrays.as_rigid_pose`: a rotation to
        1e-5, last row ``0 0 0 1``, finite), which must put some of A's
        points in B's view. ``min_fitness`` and ``max_rmse`` are then ignored.
    extrinsic : (4, 4) float, optional
        The pose as a rig's extrinsic from A's sensor to B's: A's coordinates
        into B's frame (``b = E a``), ``transform``'s inverse (docs/cross_sensor.md).
    progress : bool
        Progress on stderr.

    Raises
    ------
    InputValueError
        A frame with no point within its table's view (not in its sensor's
        frame, or empty), a transform that is not a rigid pose or puts no
        point of A in B's view, beams that are not a scan's, too few points
        to register, or a registration failing the gate (fitness, reverse fitness, RMSE, tilt:
        :func:`slr_ray.registration.registration_checks`) unless ``accept_registration``.

    Returns
    -------
    dict
        ``registration``, ``patterns``, ``unseen_share`` (of B's points),
        ``cross_sensor``, ``source_reach`` (B's points and pulses per part of the
        ``source`` split, :func:`source_reach`; they sum to B's),
        ``rows`` (one per method: counts, seconds, and a block per registered
        metric, :data:`slr_ray.metrics.REGISTRY`: ``points``, a
        :class:`~slr_ray.metrics.PointMetrics`, and ``image``, a
        :class:`~slr_ray.metrics.RangeImageMetrics`, as dicts),
        ``images`` (range images, not JSON: ``real`` and per method), ``seconds``.
    """
    t_all = time.perf_counter()
    o = EvaluateOptions.of(options, **keywords)
    seen_threshold, thresholds = o.seen_threshold, o.thresholds
    methods = _checked_methods(o.methods, o.min_fitness, o.max_rmse)
    base_a, base_b, cross = _pair_sensors(o)
    T = _given_pose(transform, extrinsic, cross, base_a, base_b)  # before any work
    a, b = as_points(a_points, "a_points"), as_points(b_points, "b_points")
    (a_beams, a_how, pat_a), (b_beams, b_how, pat_b) = _frame(a, a_beams, base_a, "a"), _frame(b, b_beams, base_b, "b")
    seconds = {}
    _require_in_view((("a_points", a, pat_a), ("b_points", b, pat_b)))
    t0 = time.perf_counter()
    T, registration = _registration(a, b, T, o, progress)
    seconds["registration"] = time.perf_counter() - t0
    a_in_b, a_origin = _a_in_b(a, T, pat_b, registration)
    t0 = time.perf_counter()
    target = _target(b, b_beams, pat_b, a_in_b, seen_threshold)
    reach = _reach(target, b, T, pat_a, a)
    seconds["target"] = time.perf_counter() - t0
    rows, images, identical = _score_methods(methods, (a_in_b, a_origin, a_beams, pat_a, a, T), pat_b, target,
                                             thresholds, seconds, progress)
    seconds["total"] = time.perf_counter() - t_all
    return {"registration": registration, "cross_sensor": cross, "source_reach": reach,
            "patterns": {"a": pat_a.to_dict() | {"beams_known": a_beams is not None, "beams": a_how},
                         "b": pat_b.to_dict() | {"beams_known": b_beams is not None, "beams": b_how}},
            **_counts(target, a, b), "seen_threshold": seen_threshold, "thresholds": [float(x) for x in thresholds],
            "images_identical": {"zbuffer vs binning": identical},
            "rows": rows, "images": images, "seconds": {k: round(v, 3) for k, v in seconds.items()}}


def _counts(target: ScoringTarget, a, b) -> dict:
    """The result's ``frames`` (points, in view, pulses) and the shares of B's points and pulses unseen."""
    real, b_in, seen, filled = target.real, target.points, target.seen, target.image["index"] >= 0
    return {"frames": {"a_points": int(len(a)), "b_points": int(len(b)), "b_points_in_view": int(len(b_in)),
                       "b_pulses_returned": int(len(real)), "b_points_sharing_a_pulse": int(len(b_in) - len(real))},
            "unseen_share": float(np.mean(~seen)) if len(seen) else float("nan"),
            "unseen_pulse_share": float(np.mean(target.pixels[filled] == "unseen")) if filled.any() else float("nan")}


def _pair_sensors(o: EvaluateOptions) -> tuple:
    """``(source table, target table, cross)``: A's sensor (``source_sensor``, else ``sensor``) and B's
    (``target_sensor``, else A's), and whether they differ."""
    base_a = _resolve_sensor(o.sensor if o.source_sensor is None else o.source_sensor)
    if o.target_sensor is None:
        return base_a, base_a, False
    base_b = _resolve_sensor(o.target_sensor)
    return base_a, base_b, base_b.to_dict() != base_a.to_dict()


#: a rig's extrinsic whose 3 x 3 part is a rotation to this (every entry of R^T R - I) is taken as its nearest
#: rotation (a hand calibration's six-digit matrix: the Pandar64 to QT64 rig's is 0.0215 off, 1 % of scale)
EXTRINSIC_TOLERANCE = 0.05


def rig_extrinsic(extrinsic, name: str = "extrinsic") -> np.ndarray:
    """A rig's extrinsic as a rigid pose: its rotation part replaced by the nearest rotation (SVD) when it is
    one to :data:`EXTRINSIC_TOLERANCE` (said once, with how far it moved), refused beyond."""
    E = as_rigid_pose(extrinsic, name, tol=EXTRINSIC_TOLERANCE)
    u, _, vt = np.linalg.svd(E[:3, :3])
    R = u @ vt
    moved = float(np.max(np.abs(R - E[:3, :3])))
    if moved > 1e-6:
        warnings.warn(f"{name}: its 3 x 3 part is not quite a rotation: taken as the nearest rotation (entries moved "
                      f"by up to {moved:.3g})", SlrWarning, stacklevel=3)
    E[:3, :3] = R
    return E


def _given_pose(transform, extrinsic, cross: bool, base_a, base_b):
    """B's pose in A's frame from ``transform`` or ``extrinsic`` (its inverse), checked; a target sensor
    other than the source's needs one (another unit of a rig sits elsewhere: registration from the
    identity is no start)."""
    T = None if transform is None else as_rigid_pose(transform, "transform")
    if extrinsic is not None:
        if T is not None:
            raise InputValueError("transform and extrinsic: give one (extrinsic is transform's inverse)")
        T = np.linalg.inv(rig_extrinsic(extrinsic))
        T[3] = (0.0, 0.0, 0.0, 1.0)
    if T is None and cross:
        raise InputValueError(
            f"target_sensor {base_b.name!r} is not the source's ({base_a.name!r}): give B's pose, transform= (B's "
            "pose in A's frame, --transform) or extrinsic= (A's coordinates into B's frame, --extrinsic)")
    return T


def _checked_methods(methods, min_fitness, max_rmse) -> tuple | list:
    """``methods`` as a sequence, refused when empty, unknown or given twice; and the registration's
    bounds refused when they are not numbers in range (before any work)."""
    if not (isinstance(min_fitness, (int, float)) and 0 <= min_fitness <= 1):
        raise InputValueError(f"min_fitness must be a number in [0, 1] (a share of B's points), got {min_fitness!r}")
    if isinstance(methods, str):
        methods = (methods,)
    if not len(methods):
        raise InputValueError(f"methods: none given; choose from {list(METHODS)}")
    unknown = [m for m in methods if m not in METHODS and m not in BACKENDS]
    if unknown:
        raise InputValueError(f"unknown method(s) {unknown}; choose from {list(METHODS)} or a backend's name")
    twice = sorted({m for m in methods if list(methods).count(m) > 1})
    if twice:
        raise InputValueError(f"methods: {', '.join(twice)} given twice (each method is one row)")
    if max_rmse is not None and not (isinstance(max_rmse, (int, float)) and max_rmse > 0):
        raise InputValueError(f"max_rmse must be a number > 0 (m), got {max_rmse!r}")
    return methods


def _frame(pts, beams, base, name) -> tuple:
    """``(beams, how, pattern)`` of a frame: its beams (:func:`_beams_of`) and its table fitted to them."""
    beams, how = _beams_of(pts, beams, base, f"{name}_beams")
    return beams, how, (fitted_pattern(pts, beams, base) if beams is not None else base)


def _require_in_view(frames) -> None:
    """Refuse a frame ``(name, points, pattern)`` none of whose points lies in its sensor's view."""
    for name, pts, pat in frames:
        if not np.any(pat.pulse_ids(pts, np.zeros(3))[0] >= 0):
            raise InputValueError(
                f"{name}: none of its {len(pts)} points lies within the sensor's view (elevation bands of "
                f"{pat.name or 'its table'}, ranges up to {pat.max_range} m) about the origin; each frame must be "
                "in its own sensor's frame (the sensor at (0, 0, 0)): subtract the scanner position first")


def _registration(a, b, T, o, progress) -> tuple:
    """``(T, registration dict)``: B registered to A, refused when it fails a check of the gate
    (:func:`slr_ray.registration.check_registration`, with ``o.min_fitness`` and ``o.max_rmse``)
    unless ``o.accept_registration``; or the given pose ``T``."""
    if not isinstance(o.accept_registration, (bool, np.bool_)):
        raise InputValueError(f"accept_registration must be True or False, got {o.accept_registration!r}")
    if T is None:
        few = [(name, len(pts)) for name, pts in (("A", a), ("B", b)) if len(pts) < MIN_REGISTRATION_POINTS]
        if few:
            raise InputValueError(
                f"frame {few[0][0]} has {few[0][1]:,} points, too few to register (at least "
                f"{MIN_REGISTRATION_POINTS:,} in each frame): give B's pose (transform, --transform)")
        with phase(f"registering B to A ({len(b):,} and {len(a):,} points)", progress=progress):
            reg = register(b, a)
        if not o.accept_registration:
            bounds = {"min_fitness": o.min_fitness} | (
                {} if o.max_rmse is None else {"max_rmse_share": o.max_rmse / reg.max_distance})
            check_registration(reg, bounds, remedy="give B's pose (transform, --transform), or score at this pose "
                                                   "anyway (accept_registration=True, --accept-registration)")
        T = reg.transform
        registration = reg.to_dict()
    else:
        registration = Registration(T, float("nan"), float("nan"), float("nan"), "given", 0.0).to_dict()
    return T, registration


def _a_in_b(a, T, pat_b, registration) -> tuple:
    """``(a_in_b, a_origin)``: A's points and sensor in B's frame, refused when none is in B's view."""
    R, t = T[:3, :3], T[:3, 3]
    a_in_b = (a - t) @ R  # R^T (a - t), row by row, in float64
    a_origin = -(R.T @ t)
    if not np.any(pat_b.pulse_ids(a_in_b, np.zeros(3))[0] >= 0):
        raise InputValueError(
            f"at B's pose ({registration['translation_norm_m']:.4g} m from A's sensor) none of A's {len(a)} points "
            "lies within B's view: the frames do not overlap there; check the pose (transform, --transform)")
    return a_in_b, a_origin


def _target(b, b_beams, pat_b, a_in_b, seen_threshold) -> ScoringTarget:
    """The real B as every method is scored against it (:func:`scoring_target`: its range image by the
    rule every simulated image is made by, its points in view, which A sees, and the splits' labels)."""
    return scoring_target(b, pat_b, b_beams, a_in_b, seen_threshold)


#: degrees: B's axes tilted from A's by more than this (another unit of a rig), the methods told of A's pulse
#: grid are prepared in A's own frame and B's pulses cast into it turned by B's pose (:func:`posed_scan`):
#: in B's frame A's grid would be tilted (rows across beams). KITTI's pairs: under 0.2 deg, unchanged.
MAX_GRID_TILT_DEG = 1.0


def tilt_deg(transform) -> float:
    """The angle between B's up axis and A's (degrees) of the pose ``transform`` (B's in A's frame)."""
    return math.degrees(math.acos(max(-1.0, min(1.0, float(np.asarray(transform)[2, 2])))))


def posed_scan(scanner, transform, pattern: BeamPattern, points_in_b) -> Scan:
    """A scan of ``pattern`` at B's pose ``transform`` (B's in A's frame) by ``scanner``, prepared on A's
    points in A's frame (a scanner that casts rays): each pulse's ray turned into A's frame and cast from B's
    origin there; a point met by several rays keeps its nearest ray's pulse, and a point the pattern would
    not see from B (``points_in_b``: the same points in B's frame) is not returned, as a scan's rule is."""
    T = np.asarray(transform, np.float64)
    dirs, v, h = pattern.rays()
    idx, dist = scanner.cast(T[:3, 3], dirs @ T[:3, :3].T, pattern.range_limits[1])
    hit = np.flatnonzero(idx >= 0)
    order = hit[np.lexsort((dist[hit], idx[hit]))]  # by point, nearest ray first
    first = order[np.r_[True, idx[order][1:] != idx[order][:-1]]] if len(order) else order
    keys, ranges = pattern.pulse_ids(points_in_b[idx[first]], np.zeros(3))
    keep = first[keys >= 0]
    return Scan(indices=idx[keep].astype(np.intp), ranges=ranges[keys >= 0], origin=np.zeros(3), pattern=pattern,
                pulses=np.column_stack([v[keep], h[keep]]).astype(np.int64), backend=scanner.backend,
                n_input=len(points_in_b), info={"cast": "posed: B's rays turned into A's frame"})


def _score_methods(methods, frame_a, pat_b, target, thresholds, seconds, progress) -> tuple:
    """``(rows, images, identical)``: each method's simulation of B from A's points in B's frame
    (``frame_a``: ``(a_in_b, a_origin, a_beams, pat_a)``), scored against the real B (``target``, a
    :class:`ScoringTarget`) by every registered metric (its seconds into ``seconds``)."""
    a_in_b, a_origin, a_beams, pat_a, a, T = frame_a
    rows, images = [], {"real": target.image["range"]}
    binning_img = None
    todo = [m for m in methods if not (METHOD_SCANS.get(m, (m, None))[1] == "beams" and a_beams is None)]
    for m in progress_bar(todo, "methods", "method", progress=progress, leave=True):
        t0 = time.perf_counter()
        prep = 0.0
        if m == BASELINE:
            sc = zbuffer(a_in_b, pat_b, backend="z-buffer")
            keys, _ = pat_b.pulse_ids(a_in_b, np.zeros(3))
            sim_idx = np.flatnonzero(keys >= 0)  # every point of A in B's view: no visibility rule
        else:
            backend, told = METHOD_SCANS.get(m, (m, None))
            posed = told is not None and scanner_class(backend).casts_rays and tilt_deg(T) > MAX_GRID_TILT_DEG
            opts = {} if told is None else scanner_class(backend).primary_options(
                np.zeros(3) if posed else a_origin, pat_a)
            if told == "beams":
                opts["primary_beams"] = a_beams
            scanner = prepare(a if posed else a_in_b, backend, **opts)
            prep = scanner.prepare_seconds
            sc = posed_scan(scanner, T, pat_b, a_in_b) if posed else scanner.scan(np.zeros(3), pat_b)
            sim_idx = sc.indices
        img = sc.range_image()["range"]
        images[m] = img
        if m == BINNING_METHOD:
            binning_img = img
        blocks = score_simulation(target, a_in_b[sim_idx], img, thresholds)
        rows.append({"method": m, "label": LABELS.get(m, m), "points_out": int(len(sim_idx)),
                     "pulses_returned": int(len(sc)),
                     "prepare_seconds": round(prep, 3), "seconds": round(time.perf_counter() - t0, 3)} | blocks)
        seconds[m] = time.perf_counter() - t0
    if BASELINE in images and binning_img is not None:
        identical = bool(np.array_equal(images[BASELINE], binning_img, equal_nan=True))
    else:
        identical = None
    return rows, images, identical
