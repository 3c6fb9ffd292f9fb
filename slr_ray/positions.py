"""Choosing secondary scanner positions (the paper's sections 2.1-2.2).

The grid method: cover the xy plane with square cells, drop empty cells, drop
cells with too few ground points around their centre, optionally drop cells
whose azimuth coverage is below a *minimum profile*, then draw cells at random
and a uniform position inside each. The scanner's height is the mean height of
the ground points around it plus the scanner height.

The azimuth test (decided here, the paper leaves it open): a cell's histogram
counts the points of a **scan simulated at the cell** (binning backend, at the
profile's resolution, from the cell centre at scanner height), not the raw
cloud points around it. Raw counts measure the primary scanner's sampling
density, which falls with distance from the primary position whatever the
occlusion; a simulated scan counts what a scanner at the cell would see, which
is what the profile was made from (reference scans) and what the test is
meant to catch (cells around a corner, behind large objects).
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import signal
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import lazy
from .arrays import as_points
from .backends import prepare
from .errors import InputValueError, MissingDependencyError, SlrNote, SlrWarning
from .options import Options
from .paper import (CELL_SIZE, GROUND_COUNT_RADIUS, GROUND_HEIGHT_RADIUS, MIN_GROUND_POINTS, SCANNER_HEIGHT,
                    SECONDARY_RESOLUTION)
from .pattern import ScanPattern
from .progress import bar as progress_bar
from .progress import phase

#: scipy.spatial, loaded on first use (slr_ray.lazy: the command line starts without it)
scipy_spatial = lazy.module("scipy.spatial")

__all__ = ["CandidateCells", "AzimuthProfile", "CellOptions", "PositionOptions", "candidate_cells", "select_positions",
           "azimuth_histogram", "minimum_profile", "default_profile", "suggest_resolution",
           "label_ground", "ground_labels", "DEFAULT_PROFILE_PATH"]

#: Words of this module's messages that name arguments, and the flags of ``slr-ray`` that set them.
CLI_FLAGS = {"pass allow_fewer=True": "give --allow-fewer", "min_ground_points": "--min-ground-points"}

DEFAULT_PROFILE_PATH = Path(__file__).resolve().parent / "data" / "default_profile.json"
#: ``min_ground_points="auto"``: this fraction of the most ground points any cell has. The paper's
#: 50,000 is for its 0.036 deg scans (``demo``'s scaling); on the demo's scene scanned from its centre
#: the best cell holds 50,000 / 0.002545 points at any resolution (both scale with the pulse density:
#: 0.3 deg 282,906 vs 720, 0.2 deg 636,502 vs 1,620), so "auto" is the paper's threshold scaled by the
#: cloud's density (docs/positions.md).
AUTO_GROUND_FRACTION = 0.002545
STAGES = ("non_empty", "ground_support", "azimuth_profile")


# --- minimum profiles ------------------------------------------------------------

def azimuth_histogram(points, origin, bins: int = 360) -> np.ndarray:
    """Counts of ``points`` in ``bins`` equal azimuth sectors around ``origin``,
    sorted ascending (whatever the elevation)."""
    pts = as_points(points)
    d = pts[:, :2].astype(np.float64) - np.asarray(origin, np.float64)[:2]
    phi = np.arctan2(d[:, 1], d[:, 0])
    phi = np.where(phi < 0, phi + 2 * np.pi, phi)
    h = np.minimum((phi / (2 * np.pi) * bins).astype(np.int64), bins - 1)
    return np.sort(np.bincount(h, minlength=bins))


@dataclass(eq=False)
class AzimuthProfile:
    """A minimum profile: sorted per-degree counts a scan must reach everywhere.
    A value: equal (and hashed) by its counts, pattern and meta, so that options
    holding one (:class:`CellOptions`) compare and hash.

    Attributes
    ----------
    counts : (360,) int64
        Ascending.
    pattern : ScanPattern
        The resolution (and limits) of the reference scans; cells are tested
        with scans simulated at this pattern.
    meta : dict
        How it was made.
    """

    counts: np.ndarray
    pattern: ScanPattern
    meta: dict = field(default_factory=dict)

    def __eq__(self, other):
        if not isinstance(other, AzimuthProfile):
            return NotImplemented
        return (np.array_equal(self.counts, other.counts) and self.pattern == other.pattern
                and self.meta == other.meta)

    def __hash__(self):
        return hash((np.asarray(self.counts).tobytes(), self.pattern))

    def passes(self, histogram) -> bool:
        """True when a sorted histogram is >= the profile in every bin."""
        return bool(np.all(np.asarray(histogram) >= self.counts))

    def save(self, path) -> Path:
        path = Path(path)
        path.write_text(json.dumps({"counts": self.counts.tolist(), "pattern": self.pattern.to_dict(),
                                    "meta": self.meta}, indent=1))
        return path

    @classmethod
    def load(cls, path) -> "AzimuthProfile":
        try:
            d = json.loads(Path(path).read_text())
            counts = np.asarray(d["counts"], dtype=np.int64)
            pattern = ScanPattern.from_dict(d["pattern"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputValueError(f"cannot read azimuth profile {path}: {exc}") from None
        if counts.ndim != 1 or np.any(np.diff(counts) < 0):
            raise InputValueError(f"{path}: counts must be one ascending list")
        return cls(counts, pattern, d.get("meta", {}))


def minimum_profile(scans, pattern: ScanPattern | None = None, bins: int = 360, meta=None) -> AzimuthProfile:
    """Element-wise minimum of the sorted azimuth histograms of reference scans.

    Parameters
    ----------
    scans : iterable of (points, origin)
        Each a reference scan (the points it returned) and its scanner position.
    pattern : ScanPattern
        The pattern the reference scans were taken with (default 0.144 deg).
    """
    hists = [azimuth_histogram(p, o, bins) for p, o in scans]
    if not hists:
        raise InputValueError("minimum_profile needs at least one scan")
    return AzimuthProfile(np.min(hists, axis=0), pattern or ScanPattern(SECONDARY_RESOLUTION),
                          {"n_scans": len(hists), **(meta or {})})


def default_profile() -> AzimuthProfile:
    """The profile shipped with slr_ray (built from synthetic scans; see its ``meta``)."""
    return AzimuthProfile.load(DEFAULT_PROFILE_PATH)


# --- cells -----------------------------------------------------------------------

@dataclass
class CandidateCells:
    """Grid cells and what each stage of the selection kept.

    Attributes
    ----------
    cell_size : float
    corner : (2,) float64
        Lower-left corner of cell (0, 0).
    ij : (k, 2) int64
        Indices of the non-empty cells.
    centres : (k, 2) float64
    ground_counts : (k,) int64
        Ground points within ``ground_count_radius`` of each centre.
    kept : dict of str -> (k,) bool
        Cumulative: which cells survive up to each stage.
    stages : list of dict
        Per stage: name, cells before, removed, kept (what a user tunes from).
    params : dict
    """

    cell_size: float
    corner: np.ndarray
    ij: np.ndarray
    centres: np.ndarray
    ground_counts: np.ndarray
    kept: dict
    stages: list
    params: dict
    seconds: float = 0.0
    #: the ground points' 2-D kd-tree, kept for drawing positions in these cells (not compared, not shown)
    ground_index: object = field(default=None, repr=False, compare=False)

    @property
    def final(self) -> np.ndarray:
        """Indices (into ``ij``) of the cells that passed every stage."""
        return np.flatnonzero(self.kept[STAGES[-1]])

    def __len__(self) -> int:
        return len(self.final)

    def summary(self) -> dict:
        return {"cell_size": self.cell_size, "candidates": len(self), "stages": self.stages,
                "params": self.params, "seconds": round(self.seconds, 3)}


def _ground_tree(points, is_ground):
    g = points[is_ground]
    centre = g[:, :2].mean(axis=0) if len(g) else np.zeros(2)
    # unbalanced, non-compact: 3x faster to build on 2e7 points, and the counts are exact either way
    return scipy_spatial.cKDTree(g[:, :2] - centre, balanced_tree=False, compact_nodes=False), g, centre


def _check_ground(points, is_ground):
    pts = as_points(points).astype(np.float64, copy=False)
    g = np.asarray(is_ground)
    if g.dtype != bool:
        raise InputValueError(f"is_ground must be a boolean array, got dtype {g.dtype}")
    if g.shape != (len(pts),):
        raise InputValueError(f"is_ground must have shape ({len(pts)},), got {g.shape}")
    return pts, g


def _ground_z(tree, g, centre, xy, radius):
    """Mean z of ground points within ``radius`` of each xy (nan where none)."""
    out = np.full(len(xy), np.nan)
    for i, lst in enumerate(tree.query_ball_point(xy - centre, radius, workers=-1)):
        if lst:
            out[i] = g[lst, 2].mean()
    return out


@dataclass(frozen=True)
class CellOptions(Options):
    """Where a secondary scanner may stand: the rules of a candidate cell (paper §2.1).

    Attributes
    ----------
    cell_size : float
        Cell side in metres (2).
    min_ground_points : int or 'auto'
        Cells with fewer ground points within ``ground_count_radius`` (5 m) of
        their centre are dropped (50,000: the paper's, for its 0.036 deg TLS
        scans). ``'auto'``: the paper's threshold scaled by the cloud's
        density, 0.2545 % of the most any cell has (at least 1), for a sparse
        cloud (a sensor frame, an airborne tile) or a denser one.
    ground_count_radius : float
        Metres around a cell's centre its ground points are counted in.
    ground_height_radius : float
        A scanner stands on the mean ground height within this many metres.
    scanner_height : float
        Metres above the ground a scanner stands.
    profile : AzimuthProfile or None
        Minimum profile of the azimuth test; None skips the test.
    """

    cell_size: float = CELL_SIZE
    min_ground_points: int = MIN_GROUND_POINTS
    ground_count_radius: float = GROUND_COUNT_RADIUS
    ground_height_radius: float = GROUND_HEIGHT_RADIUS
    scanner_height: float = SCANNER_HEIGHT
    profile: AzimuthProfile | None = None


@dataclass(frozen=True)
class PositionOptions(CellOptions):
    """:class:`CellOptions`, and what :func:`select_positions` does with too few cells.

    Attributes
    ----------
    allow_fewer : bool
        With fewer candidates than ``n``: False (default) raises, True returns
        all the positions there are and warns (:class:`~slr_ray.errors.SlrWarning`)
        naming both counts.
    """

    allow_fewer: bool = False


def candidate_cells(points, is_ground, options: CellOptions | None = None, *, progress: bool = False,
                    **keywords) -> CandidateCells:
    """Grid cells where a secondary scanner may stand (paper §2.1).

    Parameters
    ----------
    points : (n, 3) float
    is_ground : (n,) bool
    options : CellOptions or dict, optional
        The rules of a cell; its fields may also be given as keywords
        (``candidate_cells(pts, g, min_ground_points=1000)``).
    progress : bool
        Progress bar over the azimuth test (one simulated scan per cell).
    """
    o = CellOptions.of(options, **keywords)
    cell_size, min_ground_points, ground_count_radius = o.cell_size, o.min_ground_points, o.ground_count_radius
    profile, scanner_height, ground_height_radius = o.profile, o.scanner_height, o.ground_height_radius
    t0 = time.perf_counter()
    pts, g = _check_ground(points, is_ground)
    if cell_size <= 0 or ground_count_radius <= 0 or ground_height_radius <= 0:
        raise InputValueError("cell_size, ground_count_radius and ground_height_radius must be > 0")
    auto = isinstance(min_ground_points, str) and min_ground_points == "auto"
    if not auto and (isinstance(min_ground_points, str) or min_ground_points < 0):
        raise InputValueError(f"min_ground_points must be an integer >= 0 or 'auto', got {min_ground_points!r}")
    params = dict(cell_size=cell_size, min_ground_points=min_ground_points,
                  ground_count_radius=ground_count_radius, scanner_height=scanner_height,
                  ground_height_radius=ground_height_radius,
                  profile=None if profile is None else profile.meta.get("name", "custom"))
    if len(pts) == 0:
        z = np.empty((0, 2))
        return CandidateCells(cell_size, np.zeros(2), z.astype(np.int64), z, np.empty(0, np.int64),
                              {s: np.empty(0, bool) for s in STAGES},
                              [{"stage": s, "before": 0, "removed": 0, "kept": 0} for s in STAGES],
                              params, time.perf_counter() - t0)
    corner = np.floor(pts[:, :2].min(axis=0) / cell_size) * cell_size
    ij_all = np.floor((pts[:, :2] - corner) / cell_size).astype(np.int64)
    nx, ny = ij_all.max(axis=0) + 1
    cell_ids = ij_all[:, 0] * ny + ij_all[:, 1]
    # a per-cell table only when it is small next to the cloud: a tiny cell_size over a large
    # extent would ask for terabytes (0.001 m over the autzen tile: 4.8 TiB); sorting ids never does
    occupied = (np.flatnonzero(np.bincount(cell_ids, minlength=nx * ny)) if nx * ny <= 4 * len(pts) + 1024
                else np.unique(cell_ids))
    ij = np.column_stack([occupied // ny, occupied % ny])
    centres = corner + (ij + 0.5) * cell_size
    stages = [{"stage": "non_empty", "before": int(nx * ny), "removed": int(nx * ny - len(ij)),
               "kept": int(len(ij))}]
    kept = {"non_empty": np.ones(len(ij), bool)}

    tree, gpts, gcentre = _ground_tree(pts, g)
    if len(gpts):
        counts = np.asarray(tree.query_ball_point(centres - gcentre, ground_count_radius,
                                                  return_length=True, workers=-1), dtype=np.int64)
    else:
        counts = np.zeros(len(ij), np.int64)
    if auto:  # the paper's threshold scaled by the cloud's density (AUTO_GROUND_FRACTION)
        min_ground_points = max(1, math.ceil(AUTO_GROUND_FRACTION * int(counts.max(initial=0))))
        params.update(min_ground_points=min_ground_points, min_ground_points_rule="auto")
    ok = counts >= min_ground_points
    kept["ground_support"] = ok.copy()
    stages.append({"stage": "ground_support", "before": int(len(ij)), "removed": int((~ok).sum()),
                   "kept": int(ok.sum())})

    az = _azimuth_test(pts, ok, (tree, gpts, gcentre), centres, o, progress)
    kept["azimuth_profile"] = az
    stages.append({"stage": "azimuth_profile", "before": int(ok.sum()), "removed": int(ok.sum() - az.sum()),
                   "kept": int(az.sum()), **({"skipped": True} if profile is None else {})})
    return CandidateCells(cell_size, corner, ij, centres, counts, kept, stages, params,
                          time.perf_counter() - t0, ground_index=(tree, gpts, gcentre))


def _azimuth_test(pts, ok, ground_index, centres, o: CellOptions, progress) -> np.ndarray:
    """Which cells pass the azimuth test (``o.profile``'s; every cell of ``ok`` where there is none):
    a scan from the cell's ground height plus ``o.scanner_height``, its azimuth histogram against the
    profile."""
    tree, gpts, gcentre = ground_index
    profile, scanner_height, ground_height_radius = o.profile, o.scanner_height, o.ground_height_radius
    az = ok.copy()
    if profile is not None:
        scanner = prepare(pts)
        todo = np.flatnonzero(ok)
        zs = _ground_z(tree, gpts, gcentre, centres[todo], ground_height_radius)
        bar = None
        if progress:
            bar = progress_bar(total=len(todo), desc="azimuth test", unit="cell")
        for i, z in zip(todo, zs):
            if not np.isfinite(z):
                az[i] = False
            else:
                origin = np.array([centres[i, 0], centres[i, 1], z + scanner_height])
                scan = scanner.scan(origin, profile.pattern)
                az[i] = profile.passes(azimuth_histogram(pts[scan.indices], origin, len(profile.counts)))
            if bar is not None:
                bar.update()
        if bar is not None:
            bar.close()
    return az


def select_positions(points, is_ground, n: int, seed=None, options: PositionOptions | None = None, *,
                     cells: CandidateCells | None = None, return_cells: bool = False, progress: bool = False,
                     **keywords):
    """Draw ``n`` secondary scanner positions (paper §2.1-2.2).

    Cells that pass :func:`candidate_cells` are drawn at random without
    replacement, then a position uniform inside each; its z is the mean z of
    the ground points within ``ground_height_radius`` (3 m) of that xy plus
    ``scanner_height`` (1.65 m). A drawn position with no ground point within
    3 m is redrawn inside its cell (up to 20 times), then the cell is skipped.

    Parameters
    ----------
    n : int
    seed : int or numpy Generator
        Same seed, same positions.
    options : PositionOptions or dict, optional
        The rules of a cell (:class:`CellOptions`) and ``allow_fewer``; its
        fields may also be given as keywords (``min_ground_points=1000``,
        ``allow_fewer=True``).
    cells : CandidateCells, optional
        Reuse a :func:`candidate_cells` result (its parameters win).
    return_cells : bool
        Also return the :class:`CandidateCells` (per-stage counts).
    progress : bool
        A progress bar over the azimuth test (one simulated scan per cell).

    Returns
    -------
    positions : (m, 3) float64
        ``m == n`` unless ``allow_fewer``.
    """
    o = PositionOptions.of(options, **keywords)
    ground_count_radius, ground_height_radius = o.ground_count_radius, o.ground_height_radius
    scanner_height, allow_fewer = o.scanner_height, o.allow_fewer
    if int(n) != n or n < 0:
        raise InputValueError(f"n must be a non-negative integer, got {n!r}")
    pts, g = _check_ground(points, is_ground)
    if cells is None:
        cells = candidate_cells(pts, g, o, progress=progress)
    rng = np.random.default_rng(seed)
    final = cells.final
    removed = ", ".join(f"{s['stage']} removed {s['removed']}" for s in cells.stages if not s.get("skipped"))
    if cells.stages[1]["removed"] and cells.stages[1]["kept"] < n:  # the number to lower min_ground_points to
        radius = cells.params.get("ground_count_radius", ground_count_radius)
        removed += f"; the most ground points within {radius:g} m of a cell's centre is {cells.ground_counts.max():,}"
    if len(final) < n and not allow_fewer:
        raise InputValueError(f"only {len(final)} candidate cells for n={n}: {removed} "
                              "(lower min_ground_points, or pass allow_fewer=True to accept fewer)", flags=CLI_FLAGS)
    tree, gpts, gcentre = cells.ground_index if cells.ground_index is not None else _ground_tree(pts, g)
    out = []
    size = cells.cell_size
    for i in rng.permutation(final):
        if len(out) == n:
            break
        lo = cells.corner + cells.ij[i] * size
        for _ in range(20):
            xy = lo + rng.uniform(0, size, 2)
            z = _ground_z(tree, gpts, gcentre, xy[None], ground_height_radius)[0]
            if np.isfinite(z):
                out.append([xy[0], xy[1], z + scanner_height])
                break
    positions = np.array(out, dtype=np.float64).reshape(-1, 3)
    if len(positions) < n:
        why = (f"{len(final)} candidate cells ({removed})" if len(final) < n else
               f"{len(final) - len(positions)} of the {len(final)} candidate cells had no ground point within "
               f"{ground_height_radius:g} m of any position drawn in them")
        if not allow_fewer:
            raise InputValueError(f"only {len(positions)} positions could be placed for n={n}: {why} "
                                  "(lower min_ground_points, or pass allow_fewer=True to accept fewer)",
                                  flags=CLI_FLAGS)
        warnings.warn(f"{len(positions)} positions of the {n} asked: {why}", SlrWarning, stacklevel=2)
    return (positions, cells) if return_cells else positions


def require_positions(positions, n: int, cells: CandidateCells, name) -> None:
    """Raise :class:`InputValueError` when ``n`` positions were asked and none found.

    ``allow_fewer`` accepts fewer, never none: with no position there is
    nothing to write (the ``positions`` and ``augment`` commands alike).
    """
    if n and not len(positions):
        raise InputValueError(f"{name}: no scanner position found ("
                              + ", ".join(f"{s['stage']} removed {s['removed']}" for s in cells.stages
                                          if not s.get("skipped")) + "): lower min_ground_points, or check the ground",
                              flags=CLI_FLAGS)


# --- resolution -------------------------------------------------------------------

def suggest_resolution(points, position, *, radius: float = 30.0, k: int = 8, quantile: float = 0.5,
                       reference: float = SECONDARY_RESOLUTION, sample: int = 200_000, seed=0) -> float:
    """An angular resolution (degrees) that the cloud's density supports at ``position``.

    Reasoning: a simulated scan cannot be finer than the cloud it samples.
    A point at distance ``d`` from the new position whose neighbours are ``s``
    apart subtends ``s / d`` radians; pulses finer than that find no point in
    between and the scan becomes as sparse as the cloud. The suggestion is the
    ``quantile`` (median by default) of ``s / d`` over the points within
    ``radius`` of the position (``s``: mean distance to the ``k`` nearest
    neighbours), never finer than ``reference`` (0.144 deg, the paper's fixed
    choice). This also works for MLS clouds, which have no single primary
    scanner.
    """
    pts = as_points(points).astype(np.float64, copy=False)
    pos = np.asarray(position, np.float64)
    d = np.linalg.norm(pts - pos, axis=1)
    near = np.flatnonzero((d > 0.5) & (d <= radius))
    if len(near) < k + 1:
        raise InputValueError(f"too few points ({len(near)}) within {radius} m of the position")
    rng = np.random.default_rng(seed)
    probe = near if len(near) <= sample else rng.choice(near, sample, replace=False)
    c = pts[near].mean(axis=0)
    tree = scipy_spatial.cKDTree(pts[near] - c)
    dist, _ = tree.query(pts[probe] - c, k=k + 1, workers=-1)
    s = dist[:, 1:].mean(axis=1)
    ang = np.degrees(np.quantile(s / d[probe], quantile))
    return float(max(ang, reference))


# --- ground labels ----------------------------------------------------------------

def label_ground(points, *, cloth_resolution: float = 0.5, rigidness: int = 2,
                 class_threshold: float = 0.5, iterations: int = 500, time_step: float = 0.65,
                 slope_smooth: bool = False) -> np.ndarray:
    """Ground labels by Cloth Simulation Filtering (PyPI ``cloth-simulation-filter``).

    The cloth is dropped from above the inverted cloud; points within
    ``class_threshold`` of it are ground. CSF runs in a child interpreter (numpy and
    CSF only, so a script without a ``__main__`` guard is safe), which reads the
    points from a pipe and writes the ground indices to another (no copy of the cloud
    on disk; CSF's console output goes to the null device, and with ``exportCloth``
    off it writes no file): this process's working directory, stdout and threads are
    never touched, so it is safe to call from threads, and a crash inside CSF is an
    error here, not the end of the program. On Linux the child dies with this process
    (``prctl(PR_SET_PDEATHSIG)``: a ``kill -9`` of the caller leaves no CSF running).

    Returns
    -------
    is_ground : (n,) bool
    """
    if importlib.util.find_spec("CSF") is None:
        raise MissingDependencyError(
            'ground labelling needs cloth-simulation-filter: pip install cloth-simulation-filter')
    for name, value, lo in (("cloth_resolution", cloth_resolution, 0.0), ("class_threshold", class_threshold, 0.0),
                            ("time_step", time_step, 0.0)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > lo):
            raise InputValueError(f"{name} must be a finite number > 0, got {value!r}")  # CSF segfaults on 0
    if int(iterations) != iterations or iterations < 1 or int(rigidness) not in (1, 2, 3):
        raise InputValueError(f"iterations must be >= 1 and rigidness 1, 2 or 3; got {iterations!r}, {rigidness!r}")
    pts = as_points(points).astype(np.float64, copy=False)
    if len(pts) == 0:
        return np.zeros(0, bool)
    params = {"bSloopSmooth": bool(slope_smooth), "cloth_resolution": float(cloth_resolution),
              "rigidness": int(rigidness), "class_threshold": float(class_threshold),
              "interations": int(iterations), "time_step": float(time_step)}
    # a child interpreter that imports numpy and CSF only: not multiprocessing's spawn, whose
    # child re-runs the caller's __main__ (a plain script without a __main__ guard ran twice
    # and CSF "crashed"); one OpenMP thread: CSF's threads race (20,000 then 20,001 ground points).
    # The points go through its stdin (a view of the array: no copy, no file a kill -9 would leave)
    centred = np.ascontiguousarray(pts - pts.mean(axis=0))
    run = subprocess.run([sys.executable, "-c", _CSF_CHILD, json.dumps(params), str(os.getpid())],
                         input=memoryview(centred).cast("B"), capture_output=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1"})
    if run.returncode != 0:
        if run.returncode < 0:  # a signal: nothing to do with the cloth
            raise InputValueError(f"CSF was stopped by signal {_signal_name(-run.returncode)} (killed from outside, "
                                  "or out of memory: a smaller cloud or a coarser cloth_resolution needs less)")
        last = (run.stderr.decode(errors="replace").strip().splitlines() or [f"exit status {run.returncode}"])[-1]
        raise InputValueError(f"CSF crashed ({last}); try other cloth parameters")
    ground = np.frombuffer(run.stdout, np.int64)
    out = np.zeros(len(pts), bool)
    out[ground] = True
    return out


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return str(number)


# CSF in its own interpreter (see label_ground): argv holds the parameters as JSON and the caller's
# pid; stdin the centred points (float64, x y z); stdout gets the ground indices (int64). On Linux
# it asks to be killed when its caller dies (PR_SET_PDEATHSIG = 1), then checks that the caller has
# not died already. CSF prints to fd 1: that goes to the null device, the answer to a copy of fd 1.
_CSF_CHILD = """
import os, signal, sys
if sys.platform.startswith("linux"):
    import ctypes
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != int(sys.argv[2]):
        os._exit(3)
answer = os.fdopen(os.dup(1), "wb")
os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
import json
import numpy as np
import CSF
params = json.loads(sys.argv[1])
pts = np.frombuffer(sys.stdin.buffer.read(), np.float64).reshape(-1, 3)
csf = CSF.CSF()
for k, v in params.items():
    setattr(csf.params, k, v)
csf.setPointCloud(pts.tolist() if len(pts) < 10_000 else np.array(pts))
ground, off = CSF.VecInt(), CSF.VecInt()
csf.do_filtering(ground, off, False)
answer.write(np.asarray(list(ground), dtype=np.int64).tobytes())
answer.close()
"""


def ground_labels(cloud, attribute: str | None = None, value: int | None = None, csf: bool | None = None,
                  cloth_resolution: float = 0.5, *, progress: bool = False) -> np.ndarray:
    """Ground labels of a :class:`~slr_ray.io.PointCloud`: its own, else found by CSF.

    Labels are read, in this order, from ``attribute`` when given, else from
    ``is_ground``, LAS ``classification`` 2, or ``label`` 0 (the labels
    ``slr-ray scene scan`` writes, and every scan of such a cloud carries);
    the first of those that marks some point is used. A cloud with none is
    labelled by Cloth Simulation Filtering (:func:`label_ground`, the paper's
    choice; deterministic). Whatever was not read from named or standard
    labels (``label`` 0, CSF) is said by a :class:`~slr_ray.errors.SlrNote`
    warning with the count.

    Parameters
    ----------
    cloud : PointCloud
    attribute : str, optional
        A per-point attribute holding the labels; ground is where it equals
        ``value`` (or is true, for a boolean attribute).
    value : int, optional
        The ground value of ``attribute`` (default 2, LAS ground); an error
        without ``attribute`` (it would be ignored).
    csf : bool, optional
        None (default): CSF when the cloud has no labels. True: CSF whatever
        labels the cloud has. False: never CSF (no labels is an error).
    cloth_resolution : float
        CSF's cloth cell (m).
    progress : bool
        Name CSF on stderr when it runs longer than 2 s (its time grows with
        the cloud's extent over the cloth cell: a minute for a 1 km airborne
        tile at 0.5 m).

    Returns
    -------
    (n,) bool

    Raises
    ------
    InputValueError
        When the named attribute is missing or marks no point, or there are
        no labels and ``csf`` is False.
    """
    attrs = cloud.attributes
    if value is not None and not attribute:
        raise InputValueError(f"a ground value ({value}) needs the attribute that holds it: "
                              "give attribute= too", flags={"attribute=": "--ground-attribute NAME"})
    if attribute:
        return _labels_of_attribute(attrs, attribute, value, csf)
    if not csf:
        tried = []
        for name, ground_value in (("is_ground", True), ("classification", 2), ("label", 0)):
            if name not in attrs or np.ndim(attrs[name]) != 1:
                continue
            a = np.asarray(attrs[name])
            found = a.astype(bool) if ground_value is True else a == ground_value
            if found.any():
                if name == "label":
                    warnings.warn(f"ground labels from 'label' == 0 (those of slr-ray scene scan): "
                                  f"{int(found.sum()):,} of {len(found):,} points (others: --ground-attribute, "
                                  "--ground-value)", SlrNote, stacklevel=2)
                return found
            tried.append(f"{name} {'true' if ground_value is True else ground_value}")
        if csf is False:
            if tried:
                raise InputValueError(f"the input's ground labels ({', '.join(tried)}) mark no point as ground")
            raise InputValueError("the input has no ground labels (is_ground, classification 2, label 0): "
                                  "name one with attribute=", flags={"attribute=": "--ground-attribute"})
        why = (f"the input's labels ({', '.join(tried)}) mark no point as ground" if tried
               else "the input has no ground labels (is_ground, classification 2, label 0)")
    else:
        why = "ground by CSF, as asked"
    size = np.ptp(cloud.points[:, :2], axis=0) if len(cloud.points) else np.zeros(2)
    with phase(f"CSF: labelling the ground of {len(cloud.points):,} points (cloth {cloth_resolution:g} m over "
               f"{size[0]:,.0f} x {size[1]:,.0f} m)", progress=progress):
        ground = label_ground(cloud.points, cloth_resolution=cloth_resolution)
    warnings.warn(f"{why}: CSF labelled {int(ground.sum()):,} of {len(ground):,} points as ground "
                  f"(cloth {cloth_resolution:g} m)", SlrNote, stacklevel=2)
    return ground


def _labels_of_attribute(attrs, attribute: str, value, csf) -> np.ndarray:
    """Ground where ``attrs[attribute]`` equals ``value`` (default 2) or is true (:func:`ground_labels`)."""
    if csf:
        raise InputValueError("ground labels from an attribute or by CSF, not both: drop csf=True or "
                              "attribute=", flags={"csf=True": "--csf", "attribute=": "--ground-attribute"})
    value = 2 if value is None else value
    if attribute not in attrs:
        raise InputValueError(f"no attribute {attribute!r} in the input (has {sorted(attrs)})")
    a = np.asarray(attrs[attribute])
    return a.astype(bool) if a.dtype == bool else a == value
