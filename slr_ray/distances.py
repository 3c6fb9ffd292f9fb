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
from .errors import InputValueError

__all__ = ["pulse_sized_bins", "DistanceHistogram", "distance_histogram", "height_sweep", "plot_distances"]

KINDS = ("all", "ground", "non_ground")


def pulse_sized_bins(height: float = 1.65, zenith_resolution: float = 0.144, max_range: float = 120.0,
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


def height_sweep(points, is_ground, positions, heights=(0.5, 1.0, 1.65, 2.5, 4.0), pattern=None,
                 scanner_height: float = 1.65, bins=None, horizontal: bool = False, progress: bool = False):
    """SLR scans from the same positions at several heights, pooled per height.

    ``positions`` (n, 3) are scanner positions ``scanner_height`` above the
    local ground (as :func:`slr_ray.select_positions` returns them); each is
    moved to ``ground + h`` for every ``h`` in ``heights``. Returns
    ``{h: DistanceHistogram}``; nothing but the histograms is kept. By default
    each height gets its own pulse-sized bins (those of a scanner at that
    height, with a first bin from 0), so that a pure ground plane stays flat
    in counts at every height.
    """
    from .backends import prepare
    from .pattern import ScanPattern, as_pattern

    pts = as_points(points).astype(np.float64, copy=False)
    g = np.asarray(is_ground, bool)
    pattern = as_pattern(pattern or ScanPattern(0.144))
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
        from tqdm import tqdm

        bar = tqdm(total=len(pos) * len(heights), unit="scan", desc="height sweep", leave=False)
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


def plot_distances(original: DistanceHistogram | None, slr: DistanceHistogram | None, sweep: dict | None,
                   path, max_distance: float = 40.0) -> None:
    """The paper's Figure 4 panels: (a) original clouds, (b) SLR clouds, (c) ground
    by scanner height, (d) non-ground by scanner height."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    for a, h, title in ((ax[0, 0], original, "(a) original clouds"), (ax[0, 1], slr, "(b) SLR clouds")):
        if h is None:
            a.set_visible(False)
            continue
        for kind in KINDS:
            a.stairs(h.density(kind), h.edges, label=f"{kind.replace('_', '-')} (peak {h.peak(kind):.1f} m)")
        a.set(title=f"{title}, {h.n_scans} scans", xlim=(0.3, max_distance), xscale="log")
    if sweep:
        cmap = plt.get_cmap("viridis")
        for i, (height, h) in enumerate(sorted(sweep.items())):
            c = cmap(i / max(1, len(sweep) - 1))
            for a, kind in ((ax[1, 0], "ground"), (ax[1, 1], "non_ground")):
                a.stairs(h.density(kind), h.edges, color=c, label=f"{height:g} m (peak {h.peak(kind):.1f} m)")
        ax[1, 0].set(title="(c) ground, by scanner height", xlim=(0.3, max_distance), xscale="log")
        ax[1, 1].set(title="(d) non-ground, by scanner height", xlim=(0.3, max_distance), xscale="log")
    else:
        ax[1, 0].set_visible(False)
        ax[1, 1].set_visible(False)
    for a in ax.ravel():
        a.set(xlabel="distance (m, log)", ylabel="probability density (1/m)", yscale="log")
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
