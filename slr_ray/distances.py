"""Distance distributions with pulse-sized bins (the paper's Experiment 2).

Pulse-sized bins: the edges are the distances at which the zenith-bin edges of
an ideal scanner ``height`` above a flat ground plane meet the ground,
``R_k = H / cos(k * d_theta)`` (k = 0, 1, ... from the nadir), so bins widen
with distance, both because pulses widen and because the ground foreshortens.
A pure ground plane seen by that scanner puts one ring of pulses (one point
per azimuth bin) in every bin. Horizontal distances use ``H * tan(k * d_theta)``.

Histograms hold counts, so they pool over any number of scans by addition
(:meth:`DistanceHistogram.add`); densities are counts / (total * bin width).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .arrays import as_origin, as_points
from .backends import prepare
from .errors import InputValueError
from .io import PointCloud, atomic_path, read_cloud
from .options import Options
from .paper import MIN_GROUND_POINTS, SCANNER_HEIGHT, SECONDARY_RESOLUTION, SWEEP_HEIGHTS
from .pattern import ScanPattern, as_pattern
from .positions import ground_labels, select_positions
from .progress import bar as progress_bar

__all__ = ["pulse_sized_bins", "DistanceHistogram", "distance_histogram", "height_sweep", "DistanceStudy",
           "StudyOptions", "distance_study", "study_files"]

KINDS = ("all", "ground", "non_ground")


def pulse_sized_bins(height: float = SCANNER_HEIGHT, zenith_resolution: float = SECONDARY_RESOLUTION, max_range: float = 120.0,
                     horizontal: bool = False, from_zero: bool = False) -> np.ndarray:
    """Distance-bin edges of pulse-sized bins (metres, increasing).

    Parameters
    ----------
    height : float
        Scanner height above the ground plane.
    zenith_resolution : float
        Degrees.
    max_range : float
        The last edge (a narrower last bin ends exactly there).
    horizontal : bool
        Edges of horizontal distance ``H tan(k d_theta)`` (starting at 0)
        instead of range ``H / cos(k d_theta)`` (starting at ``H``).
    from_zero : bool
        Prepend 0 to range edges (a first bin [0, H) for points nearer than
        the ground, e.g. from a lower scanner).
    """
    if height <= 0 or zenith_resolution <= 0 or max_range <= 0:
        raise InputValueError("height, zenith_resolution and max_range must be > 0")
    d = math.radians(zenith_resolution)
    k_max = int(math.floor((math.pi / 2) / d))
    k = np.arange(0, k_max + 1)
    k = k[k * d < math.pi / 2]
    edges = height * (np.tan(k * d) if horizontal else 1.0 / np.cos(k * d))
    edges = edges[edges < max_range]
    edges = np.append(edges, max_range)
    if from_zero and not horizontal:
        edges = np.insert(edges, 0, 0.0)
    if len(edges) < 2:
        raise InputValueError(f"max_range {max_range} leaves no bin above height {height}")
    return edges


@dataclass
class DistanceHistogram:
    """Counts of distances in bins, for all, ground and non-ground points.

    Attributes
    ----------
    edges : (b + 1,) float64
    counts : dict kind -> (b,) int64
    below, above : dict kind -> int
        Points nearer than the first edge / beyond the last (kept, not lost).
    n_scans : int
    ground_fractions : list of float
        Fraction of ground points of each scan added.
    horizontal : bool
    """

    edges: np.ndarray
    counts: dict = field(default_factory=dict)
    below: dict = field(default_factory=dict)
    above: dict = field(default_factory=dict)
    n_scans: int = 0
    ground_fractions: list = field(default_factory=list)
    horizontal: bool = False

    def __post_init__(self):
        self.edges = np.asarray(self.edges, dtype=np.float64)
        if self.edges.ndim != 1 or len(self.edges) < 2 or np.any(np.diff(self.edges) <= 0):
            raise InputValueError("edges must be at least two increasing values")
        for kind in KINDS:
            self.counts.setdefault(kind, np.zeros(len(self.edges) - 1, np.int64))
            self.below.setdefault(kind, 0)
            self.above.setdefault(kind, 0)

    def add(self, points, origin, is_ground=None) -> "DistanceHistogram":
        """Add one scan (its points, its scanner origin, optional ground labels)."""
        pts = as_points(points).astype(np.float64, copy=False)
        o = as_origin(origin)
        d = pts - o
        dist = np.hypot(d[:, 0], d[:, 1]) if self.horizontal else np.sqrt((d * d).sum(axis=1))
        if is_ground is None:
            g = np.zeros(len(pts), bool)
        else:
            g = np.asarray(is_ground, dtype=bool)
            if g.shape != (len(pts),):
                raise InputValueError(f"is_ground must have shape ({len(pts)},), got {g.shape}")
        for kind, sel in (("all", slice(None)), ("ground", g), ("non_ground", ~g)):
            x = dist[sel]
            self.counts[kind] += np.histogram(x, self.edges)[0]
            self.below[kind] += int((x < self.edges[0]).sum())
            self.above[kind] += int((x > self.edges[-1]).sum())
        self.n_scans += 1
        if is_ground is not None and len(pts):
            self.ground_fractions.append(float(g.mean()))
        return self

    def __iadd__(self, other: "DistanceHistogram") -> "DistanceHistogram":
        if not np.array_equal(self.edges, other.edges) or self.horizontal != other.horizontal:
            raise InputValueError("only histograms with the same bins pool")
        for kind in KINDS:
            self.counts[kind] += other.counts[kind]
            self.below[kind] += other.below[kind]
            self.above[kind] += other.above[kind]
        self.n_scans += other.n_scans
        self.ground_fractions += other.ground_fractions
        return self

    @property
    def centres(self) -> np.ndarray:
        return 0.5 * (self.edges[1:] + self.edges[:-1])

    def density(self, kind: str = "all") -> np.ndarray:
        """Probability density per metre: counts / (counts in bins * bin width)."""
        c = self.counts[kind]
        total = c.sum()
        return c / (total * np.diff(self.edges)) if total else np.zeros(len(c))

    def peak(self, kind: str = "all", min_relative_width: float = 0.02) -> float:
        """Distance of highest density (nan when empty).

        Pulse-sized bins near the nadir are micrometres wide, so a single
        non-ground point there makes a spike; the peak is taken on bins merged
        until each is at least ``min_relative_width`` of its distance wide (2 %
        by default; 0 uses the raw bins). Returns the merged bin's centre.
        """
        c = self.counts[kind]
        if not c.any():
            return float("nan")
        keep = [0]
        for i in range(1, len(self.edges) - 1):
            lo = self.edges[keep[-1]]
            if self.edges[i] - lo >= min_relative_width * max(lo, 1e-9):
                keep.append(i)
        keep.append(len(self.edges) - 1)
        e = self.edges[keep]
        merged = np.add.reduceat(c, keep[:-1])
        dens = merged / np.diff(e)
        j = int(np.argmax(dens))
        return float(0.5 * (e[j] + e[j + 1]))

    def to_csv(self, path) -> Path:
        path = Path(path)
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["lo_m", "hi_m"] + [f"count_{k}" for k in KINDS] + [f"density_{k}" for k in KINDS])
            dens = [self.density(k) for k in KINDS]
            for i in range(len(self.edges) - 1):
                w.writerow([self.edges[i], self.edges[i + 1]] + [int(self.counts[k][i]) for k in KINDS]
                           + [float(d[i]) for d in dens])
        return path

    def summary(self) -> dict:
        gf = np.array(self.ground_fractions)
        return {"n_scans": self.n_scans, "points": int(self.counts["all"].sum()),
                "below_first_edge": self.below, "beyond_last_edge": self.above,
                "peak_m": {k: self.peak(k) for k in KINDS},
                "ground_fraction_mean": float(gf.mean()) if len(gf) else None,
                "ground_fraction_sd": float(gf.std(ddof=1)) if len(gf) > 1 else None}


def distance_histogram(points, origin, is_ground=None, bins=None, horizontal: bool = False) -> DistanceHistogram:
    """Histogram of one scan's distances (range by default; horizontal as an option).

    ``bins``: edges (default :func:`pulse_sized_bins` with 0 prepended for
    ranges). Pool scans with ``h.add(...)`` or ``h += other``.
    """
    if bins is None:
        bins = pulse_sized_bins(horizontal=horizontal, from_zero=not horizontal)
    return DistanceHistogram(bins, horizontal=horizontal).add(points, origin, is_ground)


def height_sweep(points, is_ground, positions, heights=SWEEP_HEIGHTS, pattern=None,
                 scanner_height: float = SCANNER_HEIGHT, bins=None, horizontal: bool = False, progress: bool = False):
    """SLR scans from the same positions at several heights, pooled per height.

    ``positions`` (n, 3) are scanner positions ``scanner_height`` above the
    local ground (as :func:`slr_ray.select_positions` returns them); each is
    moved to ``ground + h`` for every ``h`` in ``heights``. Returns
    ``{h: DistanceHistogram}``; nothing but the histograms is kept. By default
    each height gets its own pulse-sized bins (those of a scanner at that
    height, with a first bin from 0), so that a pure ground plane stays flat
    in counts at every height.
    """
    pts = as_points(points).astype(np.float64, copy=False)
    g = np.asarray(is_ground, bool)
    pattern = as_pattern(pattern or ScanPattern(SECONDARY_RESOLUTION))
    scanner = prepare(pts)
    pos = np.atleast_2d(np.asarray(positions, np.float64))
    if any(h <= 0 for h in heights):
        raise InputValueError(f"heights must be > 0, got {heights}")

    def bins_for(h):
        if bins is not None:
            return bins
        return pulse_sized_bins(h, pattern.zenith_resolution, horizontal=horizontal, from_zero=not horizontal)

    out = {float(h): DistanceHistogram(bins_for(h), horizontal=horizontal) for h in heights}
    bar = None
    if progress:
        bar = progress_bar(total=len(pos) * len(heights), desc="height sweep", unit="scan")
    for p in pos:
        ground_z = p[2] - scanner_height
        for h in heights:
            o = np.array([p[0], p[1], ground_z + h])
            scan = scanner.scan(o, pattern)
            out[float(h)].add(pts[scan.indices], o, g[scan.indices])
            if bar is not None:
                bar.update()
    if bar is not None:
        bar.close()
    return out


@dataclass
class DistanceStudy:
    """The paper's Experiment 2 over some input scans (:func:`distance_study`).

    Attributes
    ----------
    original : DistanceHistogram
        The input scans from their own origins.
    slr : DistanceHistogram
        SLR scans at the scanner height, on the same bins.
    sweep : dict
        Scanner height -> DistanceHistogram of SLR scans at that height.
    inputs : list of dict
        Per input: path, positions drawn, ground fraction.
    """

    original: DistanceHistogram
    slr: DistanceHistogram
    sweep: dict
    inputs: list

    def tables(self) -> dict:
        """File name -> histogram, as :meth:`write` names them (:func:`study_files`)."""
        return dict(zip(study_files(self.sweep)[:-1], [self.original, self.slr, *self.sweep.values()]))

    def write(self, outdir) -> list:
        """The CSV tables into ``outdir``; returns their names, sorted. The paper's Figure 4,
        ``distances.png``, is drawn by the figures' layer, as the ``distances`` command does:
        ``save_figure(distances_figure(study.original, study.slr, study.sweep), outdir / "distances.png")``
        (:mod:`slr_ray.plotting`)."""
        out = Path(outdir)
        out.mkdir(parents=True, exist_ok=True)
        for name, hist in self.tables().items():
            with atomic_path(out / name) as tmp:
                hist.to_csv(tmp)
        return sorted(self.tables())

    def summary(self) -> dict:
        return {"inputs": self.inputs, "original": self.original.summary(), "slr": self.slr.summary(),
                "heights": {f"{h:g}": {"peak_ground_m": v.peak("ground"), "peak_non_ground_m": v.peak("non_ground")}
                            for h, v in self.sweep.items()}}


def study_files(heights) -> list:
    """The files of the ``distances`` command for a sweep over ``heights``: the tables
    :meth:`DistanceStudy.write` writes, and its figure ``distances.png`` (last)."""
    return ["original.csv", "slr.csv", *(f"height_{float(h):g}m.csv" for h in heights), "distances.png"]


@dataclass(frozen=True)
class StudyOptions(Options):
    """The settings of :func:`distance_study`.

    Attributes
    ----------
    heights : sequence of float
        The heights of the sweep (m above the ground).
    positions : int
        Secondary positions drawn in each input.
    seed : int
        Seed of the positions.
    resolution : float
        The SLR scans' angular resolution (degrees).
    max_range : float
        Their maximum range (m).
    scanner_height : float
        Metres above the ground the SLR scanner stands.
    min_ground_points : int
        The candidate cells' ground support (:class:`~slr_ray.positions.CellOptions`).
    ground : dict or None
        Keywords of :func:`~slr_ray.positions.ground_labels` (``attribute``,
        ``value``, ``csf``, ``cloth_resolution``).
    """

    heights: tuple = SWEEP_HEIGHTS
    positions: int = 20
    seed: int = 0
    resolution: float = SECONDARY_RESOLUTION
    max_range: float = 120.0
    scanner_height: float = SCANNER_HEIGHT
    min_ground_points: int = MIN_GROUND_POINTS
    ground: dict | None = None


def distance_study(inputs, options: StudyOptions | None = None, *, origin=None, progress: bool = False,
                   **keywords) -> DistanceStudy:
    """The paper's Experiment 2: distance distributions of real scans and of their SLR scans.

    For each input scan: its own distances from its origin; ``positions``
    secondary positions by the grid method; SLR scans from them at
    ``scanner_height`` and at every height of ``heights``. Everything is
    pooled over inputs into histograms with pulse-sized bins.

    Parameters
    ----------
    inputs : sequence of path or PointCloud
        One scan each.
    origin : (3,) float, optional
        The scanner origin of inputs that record none. An explicit origin is
        used for every input, over any the files record (a file's recorded
        origin may be a format default, e.g. PCD's ``VIEWPOINT 0 0 0``).
    options : StudyOptions or dict, optional
        The heights, positions, seed, resolution, range, scanner height,
        ground support and ground labels (:class:`StudyOptions`); each field
        may also be given as a keyword (``positions=5``).
    """
    opts = StudyOptions.of(options, **keywords)
    heights, positions, seed, resolution = opts.heights, opts.positions, opts.seed, opts.resolution
    max_range, scanner_height, min_ground_points, ground = (opts.max_range, opts.scanner_height,
                                                            opts.min_ground_points, opts.ground)
    bins = pulse_sized_bins(scanner_height, resolution, max_range, from_zero=True)
    original, slr, sweep, per_input = DistanceHistogram(bins), DistanceHistogram(bins), {}, []
    pattern = ScanPattern(resolution, max_range=max_range)
    for item in inputs:
        cloud = item if isinstance(item, PointCloud) else read_cloud(item, allow_empty=False)
        name = "<PointCloud>" if isinstance(item, PointCloud) else str(item)
        o = origin if origin is not None else cloud.origin
        if o is None:  # before the ground labels: CSF can take a minute
            raise InputValueError(f"{name} records no scanner origin: give one (--origin X Y Z)")
        is_ground = ground_labels(cloud, **(ground or {}), progress=progress)
        original += distance_histogram(cloud.points, o, is_ground, bins)
        pos = select_positions(cloud.points, is_ground, positions, seed=seed, min_ground_points=min_ground_points,
                               allow_fewer=True, scanner_height=scanner_height)
        sw = height_sweep(cloud.points, is_ground, pos, heights, pattern, scanner_height=scanner_height,
                          progress=progress)
        for h, hist in sw.items():
            if h in sweep:
                sweep[h] += hist
            else:
                sweep[h] = hist
        scanner = prepare(cloud.points)
        for p in pos:
            scan = scanner.scan(p, pattern)
            slr.add(cloud.points[scan.indices], p, is_ground[scan.indices])
        per_input.append({"input": name, "positions": len(pos), "ground_fraction": float(is_ground.mean())})
    return DistanceStudy(original, slr, sweep, per_input)

