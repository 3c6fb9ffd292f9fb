"""Reproducing the paper's validation (Experiment 1), and going past it.

For each scene of a config: the scene's primary scan from the origin, the
candidate secondary positions on that primary cloud (the grid method), N
positions drawn, and at each one the true scan of the scene (one row per
truth semantics: pulse centre, nearest in pulse) and the SLR scan of the
primary cloud (one row per backend), compared by similarity (fraction of true
points within 10 cm of the SLR scan).

Rows go to a CSV as they are made, so an interrupted run picks up where it
stopped (a rerun skips the rows already there); the same config and seed give
the same numbers.
"""

from __future__ import annotations

import csv
import math
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputValueError

__all__ = ["ValidationConfig", "load_config", "run_validation", "plot_validation", "series_stats",
           "paper_report", "paper_report_markdown", "plot_paper_figure", "miss_breakdown",
           "hidden_from"]

COLUMNS = ["scene", "n_rectangles", "scene_seed", "primary_resolution", "position", "x", "y", "z",
           "distance_m", "backend", "truth", "similarity", "true_points", "slr_points", "seconds"]


@dataclass
class ValidationConfig:
    """What :func:`run_validation` runs (a ``[validate]`` table in TOML).

    ``scenes``: scene specs (names in ``scenes/`` or paths), each either a
    string or a table ``{scene = "rect-1000", primary_resolutions = [0.0144,
    0.00576], backends = ["binning"]}`` overriding ``primary_resolutions``
    and/or ``backends`` for that scene.
    ``primary_resolutions``: one or more (the paper: 0.0144 and 0.00576). The
    secondary positions are drawn on the *first* primary of a scene and the
    true scans are shared by all its primaries, as in the paper (question 3
    reuses question 2's positions and true scans).
    ``positions_resolution``: the primary the positions are drawn on
    (default: a scene's first; scanned for that alone if it is not among the
    scene's primaries).
    ``primary_semantics``: 'dense' (the paper's 5 mm grid) or 'center'.
    ``nearest_every`` / ``embree_every``: the nearest-in-pulse truth and the
    embree backend (both ~10x dearer than the rest) only at positions
    0, k, 2k, ... (1 = every position). ``embree_primary_resolutions``: the
    primaries embree is run on (default: all; a 0.00576 deg dense primary of
    2e8 points does not fit a disc BVH in 24 GB).
    """

    name: str = "validation"
    scenes: list = field(default_factory=lambda: ["rect-1000"])
    primary_resolutions: list = field(default_factory=lambda: [0.0144])
    primary_semantics: str = "dense"
    dense_spacing: float = 0.005
    positions: int = 100
    seed: int = 0
    secondary_resolution: float = 0.144
    backends: list = field(default_factory=lambda: ["binning"])
    truths: list = field(default_factory=lambda: ["center"])
    nearest_supersample: int = 3
    nearest_every: int = 1
    embree_every: int = 1
    embree_primary_resolutions: list | None = None
    positions_resolution: float | None = None
    min_ground_points: int = 50_000
    threshold: float = 0.10
    embree_options: dict = field(default_factory=dict)

    def check(self) -> "ValidationConfig":
        if self.primary_semantics not in ("dense", "center"):
            raise InputValueError(f"primary_semantics must be 'dense' or 'center', got {self.primary_semantics!r}")
        for b in self.backends:
            if b not in ("binning", "embree"):
                raise InputValueError(f"unknown backend {b!r} in config")
        for t in self.truths:
            if t not in ("center", "nearest"):
                raise InputValueError(f"unknown truth semantics {t!r} in config")
        if self.positions < 1 or self.threshold <= 0:
            raise InputValueError("positions must be >= 1 and threshold > 0")
        if self.nearest_every < 1 or self.embree_every < 1:
            raise InputValueError("nearest_every and embree_every must be >= 1")
        for entry in self.scenes:
            spec, res = self.scene_entry(entry)
            for b in self.scene_backends(entry):
                if b not in ("binning", "embree"):
                    raise InputValueError(f"unknown backend {b!r} for scene {spec!r}")
            if not res or any(not (float(r) > 0) for r in res):
                raise InputValueError(f"scene {spec!r}: primary_resolutions must be positive numbers")
        return self

    def scene_entry(self, entry) -> tuple[str, list]:
        """``(spec, primary resolutions)`` of one ``scenes`` entry."""
        if isinstance(entry, str):
            spec, res = entry, self.primary_resolutions
        elif isinstance(entry, dict) and isinstance(entry.get("scene"), str) \
                and set(entry) <= {"scene", "primary_resolutions", "backends"}:
            spec, res = entry["scene"], entry.get("primary_resolutions", self.primary_resolutions)
        else:
            raise InputValueError("a scenes entry is a name or {scene = NAME, primary_resolutions = [...], "
                                  f"backends = [...]}}, got {entry!r}")
        try:
            return spec, [float(r) for r in res]
        except (TypeError, ValueError):
            raise InputValueError(f"scene {spec!r}: primary_resolutions must be numbers, got {res!r}") from None

    def scene_backends(self, entry) -> list:
        """The backends run on one ``scenes`` entry."""
        return list(entry.get("backends", self.backends)) if isinstance(entry, dict) else list(self.backends)

    def wanted(self, resolution, position: int, backends=None):
        """The (backend, truth) rows wanted at one primary and position."""
        emb_res = self.embree_primary_resolutions
        return [(b, t) for b in (self.backends if backends is None else backends) for t in self.truths
                if (t != "nearest" or position % self.nearest_every == 0)
                and (b != "embree" or (position % self.embree_every == 0
                                       and (emb_res is None or float(resolution) in map(float, emb_res))))]


def load_config(spec) -> ValidationConfig:
    """A config by path or by name (``scenes/validate-<name>.toml``)."""
    from .scenes import load_toml_spec

    data, path = load_toml_spec(spec, "validate", "validation config", prefix="validate-")
    try:
        return ValidationConfig(**data["validate"]).check()
    except TypeError as exc:
        raise InputValueError(f"{path}: {exc}") from None


def _done_rows(path: Path) -> dict:
    if not path.exists():
        return {}
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {(r["scene"], r["primary_resolution"], r["position"], r["backend"], r["truth"]): r for r in rows}


def peak_rss_gib() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


class _Stages:
    """``stages.csv``: wall time, size and peak memory of each stage of a run."""

    columns = ["scene", "primary_resolution", "stage", "seconds", "count", "peak_rss_gib"]

    def __init__(self, path: Path):
        self.path = path
        new = not path.exists()
        self.f = open(path, "a", newline="")
        self.w = csv.DictWriter(self.f, self.columns)
        if new:
            self.w.writeheader()

    def add(self, scene, res, stage, seconds, count):
        self.w.writerow({"scene": scene, "primary_resolution": res, "stage": stage,
                         "seconds": round(seconds, 2), "count": count,
                         "peak_rss_gib": round(peak_rss_gib(), 2)})
        self.f.flush()

    def close(self):
        self.f.close()


def _positions_file(out: Path, spec: str) -> Path:
    return out / "positions" / (Path(spec).stem + ".csv")


def _positions_tag(config: ValidationConfig, n: int) -> str:
    return f"# positions={n} seed={config.seed} min_ground_points={config.min_ground_points}"


def _load_positions(path: Path, config: ValidationConfig):
    """Positions saved by an earlier run of the same draw, or None (draw again).

    Draws are prefix-consistent (the first N of a draw of M > N are a draw of
    N), so a file drawn for at least ``config.positions`` serves."""
    if not path.exists():
        return None
    head = path.read_text().split("\n", 1)[0]
    try:
        n = int(head.split()[1].split("=")[1])
    except (IndexError, ValueError):
        return None
    if head != _positions_tag(config, n) or n < config.positions:
        return None
    return np.loadtxt(path, delimiter=",", ndmin=2)[: config.positions]


def run_validation(config: ValidationConfig, outdir, progress: bool = True) -> dict:
    """Run (or resume) a validation; returns a summary.

    Writes ``outdir/results.csv`` (a row per pair, appended as made),
    ``outdir/positions/<scene>.csv`` (the drawn positions, so a resumed run
    need not rescan the primary they were drawn on) and ``outdir/stages.csv``
    (seconds and peak memory of every primary scan, position draw and
    position loop).
    """
    from .io import atomic_path
    from .meshscan import scan_mesh
    from .pattern import ScanPattern
    from .positions import select_positions
    from .backends import prepare
    from .scenes import scene_from_spec
    from .similarity import similarity

    config.check()
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "results.csv"
    done = _done_rows(csv_path)
    new_file = not csv_path.exists()
    secondary = ScanPattern(config.secondary_resolution)
    t_all = time.perf_counter()
    n_new = 0
    entries = [(*config.scene_entry(e), config.scene_backends(e)) for e in config.scenes]
    bar = None
    if progress:
        from tqdm import tqdm

        total = sum(len(res) for _, res, _ in entries) * config.positions
        bar = tqdm(total=total, unit="position", desc=config.name, file=sys.stderr)
    stages = _Stages(out / "stages.csv")

    def key(spec, res, i, b, t):
        return (spec, str(res), str(i), b, t)

    try:
        f = open(csv_path, "a", newline="")
        w = csv.DictWriter(f, COLUMNS)
        if new_file:
            w.writeheader()
        for spec, resolutions, backends in entries:
            todo_all = {float(res): [i for i in range(config.positions)
                              if any(key(spec, res, i, b, t) not in done
                                     for b, t in config.wanted(res, i, backends))]
                        for res in resolutions}
            if not any(todo_all.values()):
                if bar is not None:
                    bar.update(config.positions * len(resolutions))
                continue
            scene = scene_from_spec(spec)
            pos_path = _positions_file(out, spec)
            positions = _load_positions(pos_path, config)
            pos_res = float(config.positions_resolution or resolutions[0])
            passes = [pos_res] + [r for r in resolutions if float(r) != pos_res]
            # True scans are shared by the primaries of a scene. 100 of them are ~5 GB, too much to hold
            # next to a 0.00576 deg primary: with more than one primary they wait on disk (and serve a resume).
            spill = out / ".truths" / Path(spec).stem if len(resolutions) > 1 else None

            def true_points(i, pos, t):
                path = spill / f"{i}-{t}.npy" if spill is not None else None
                if path is not None and path.exists():
                    return np.load(path)
                pts = scan_mesh(scene, pos, secondary, mode=t, supersample=config.nearest_supersample).points
                if path is not None:
                    path.parent.mkdir(parents=True, exist_ok=True)
                    with atomic_path(path) as tmp:
                        np.save(tmp, pts)
                return pts

            for r_index, res in enumerate(passes):
                wanted_here = float(res) in map(float, resolutions)
                todo = todo_all.get(float(res), [])
                if not todo and (positions is not None or r_index > 0):
                    if bar is not None and wanted_here:
                        bar.update(config.positions)
                    continue
                t0 = time.perf_counter()
                primary = scan_mesh(scene, [0, 0, 0], ScanPattern(res), mode=config.primary_semantics,
                                    spacing=config.dense_spacing)
                stages.add(spec, res, "primary scan", time.perf_counter() - t0, len(primary))
                if positions is None:
                    t0 = time.perf_counter()
                    positions = select_positions(primary.points, primary.labels == 0, config.positions,
                                                 seed=config.seed, min_ground_points=config.min_ground_points,
                                                 allow_fewer=True)
                    pos_path.parent.mkdir(exist_ok=True)
                    if spill is not None and spill.exists():
                        shutil.rmtree(spill)  # true scans of other positions
                    with atomic_path(pos_path) as tmp:
                        np.savetxt(tmp, positions, delimiter=",", fmt="%.17g",
                                   header=_positions_tag(config, config.positions)[2:])
                    stages.add(spec, res, "positions", time.perf_counter() - t0, len(positions))
                if not wanted_here:
                    del primary
                    continue
                t_loop = time.perf_counter()
                discs = None
                binning = prepare(primary.points)
                for i, pos in enumerate(positions):
                    rows = [(b, t) for b, t in config.wanted(res, i, backends)
                            if key(spec, res, i, b, t) not in done]
                    if rows:
                        truths = {t: true_points(i, pos, t) for t in sorted({t for _, t in rows})}
                        for b in sorted({b for b, _ in rows}):
                            t0 = time.perf_counter()
                            if b == "embree":
                                if discs is None:
                                    t1 = time.perf_counter()
                                    discs = prepare(primary.points, "embree", config.embree_options)
                                    stages.add(spec, res, "embree discs", time.perf_counter() - t1,
                                               len(primary))
                                    t0 = time.perf_counter()
                                scan = discs.scan(pos, secondary)
                            else:
                                scan = binning.scan(pos, secondary)
                            sec = time.perf_counter() - t0
                            slr = primary.points[scan.indices]
                            for t in [t for bb, t in rows if bb == b]:
                                truth = truths[t]
                                w.writerow({"scene": spec, "n_rectangles": scene.n_rectangles,
                                            "scene_seed": scene.params["seed"], "primary_resolution": res,
                                            "position": i, "x": pos[0], "y": pos[1], "z": pos[2],
                                            "distance_m": float(math.hypot(pos[0], pos[1])), "backend": b,
                                            "truth": t, "similarity": similarity(truth, slr, config.threshold),
                                            "true_points": len(truth), "slr_points": len(scan),
                                            "seconds": sec})
                                n_new += 1
                        f.flush()
                    if bar is not None:
                        bar.update(1)
                stages.add(spec, res, "pairs", time.perf_counter() - t_loop, len(positions))
                if bar is not None and len(positions) < config.positions:
                    bar.update(config.positions - len(positions))
                del primary, discs, binning
            if spill is not None and spill.exists():
                shutil.rmtree(spill)
    finally:
        if bar is not None:
            bar.close()
        stages.close()
        if "f" in locals():
            f.close()
    rows = list(_done_rows(csv_path).values())
    return {"config": asdict(config), "csv": str(csv_path), "rows": len(rows), "new_rows": n_new,
            "seconds": round(time.perf_counter() - t_all, 2), "peak_rss_gib": round(peak_rss_gib(), 2),
            **_headline(rows)}


def _headline(rows) -> dict:
    """The paper's two headline figures, per backend and truth semantics."""
    out = {}
    for b in sorted({r["backend"] for r in rows}):
        for t in sorted({r["truth"] for r in rows}):
            rr = [r for r in rows if r["backend"] == b and r["truth"] == t]
            sim = np.array([float(r["similarity"]) for r in rr])
            dist = np.array([float(r["distance_m"]) for r in rr])
            near = sim[dist < 17.5]
            out[f"{b}/{t}"] = {
                "pairs": len(rr),
                "mean_similarity_below_17.5m": float(near.mean()) if len(near) else None,
                "min_similarity_below_17.5m": float(near.min()) if len(near) else None,
                "fraction_pairs_above_0.8": float((sim > 0.8).mean()) if len(sim) else None,
            }
    return {"headline": out}


def _binned_means(d, s, edges):
    """Bin centres and mean of ``s`` in each non-empty bin of ``d``."""
    mids, means = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (d >= lo) & (d < hi)
        if m.any():
            mids.append((lo + hi) / 2)
            means.append(float(s[m].mean()))
    return mids, means


def plot_validation(csv_path, png_path) -> None:
    """Figures like the paper's Figure 3: (a) similarity against scanner
    distance, (b) by number of rectangles, (c) by primary resolution; one
    series per backend and truth semantics."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(_done_rows(Path(csv_path)).values())
    if not rows:
        raise InputValueError(f"{csv_path}: no rows to plot")
    series = sorted({(r["backend"], r["truth"]) for r in rows})
    fig, ax = plt.subplots(1, 3, figsize=(16, 4.6))
    edges = np.arange(0, 105, 5.0)
    for b, t in series:
        rr = [r for r in rows if r["backend"] == b and r["truth"] == t]
        d = np.array([float(r["distance_m"]) for r in rr])
        s = 100 * np.array([float(r["similarity"]) for r in rr])
        label = f"{b} vs {t} truth"
        ax[0].scatter(d, s, s=6, alpha=0.4)
        ax[0].plot(*_binned_means(d, s, edges), "-", label=label)
        for k, key in ((1, "n_rectangles"), (2, "primary_resolution")):
            groups = sorted({float(r[key]) for r in rr})
            for g in groups:
                m = np.array([float(r[key]) == g for r in rr])
                ax[k].plot(*_binned_means(d[m], s[m], edges), "o-", ms=3,
                           label=f"{label}, {key.replace('_', ' ')} {g:g}")
    ax[0].axvline(17.5, ls=":", c="gray")
    ax[0].axhline(90, ls=":", c="gray")
    titles = ["(a) similarity vs scanner distance", "(b) by number of rectangles", "(c) by primary resolution"]
    for a, title in zip(ax, titles):
        a.set(xlabel="distance from primary scanner (m)", ylabel="similarity (%)", ylim=(0, 101), title=title)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------
# The paper's questions, side by side

PAPER_Q1_SCENES = ("distance-1", "distance-2", "distance-3", "distance-4", "distance-5")
PAPER_Q2_SCENES = ("ground-only", "rect-0500", "rect-1000", "rect-2000")
DISTANCE_BANDS = ((0.0, 10.0), (10.0, 17.5), (17.5, 25.0), (25.0, 35.0), (35.0, math.inf))


def _series(rows, scenes=None, resolution=None, backend="binning", truth="center", positions=None):
    out = [r for r in rows if r["backend"] == backend and r["truth"] == truth
           and (scenes is None or r["scene"] in scenes)
           and (resolution is None or float(r["primary_resolution"]) == float(resolution))
           and (positions is None or (r["scene"], r["position"]) in positions)]
    d = np.array([float(r["distance_m"]) for r in out])
    s = np.array([float(r["similarity"]) for r in out])
    return d, s


def series_stats(distance, similarity) -> dict:
    """The paper's figures for one series of pairs: the mean (and min) similarity
    below 17.5 m, the share of those above 90 %, the share of all pairs above
    80 %, the mean per distance band and the least-squares slope per 10 m."""
    d, s = np.asarray(distance, float), np.asarray(similarity, float)
    near = s[d < 17.5]
    bands = {}
    for lo, hi in DISTANCE_BANDS:
        m = (d >= lo) & (d < hi)
        if m.any():
            bands[f"{lo:g}-{hi:g}"] = {"pairs": int(m.sum()), "mean": float(s[m].mean())}
    slope = float(np.polyfit(d, s, 1)[0] * 10) if len(d) > 2 and np.ptp(d) > 0 else None
    return {"pairs": int(len(s)), "mean": float(s.mean()) if len(s) else None,
            "below_17.5m": {"pairs": int(len(near)), "mean": float(near.mean()) if len(near) else None,
                            "min": float(near.min()) if len(near) else None,
                            "share_above_0.9": float((near > 0.9).mean()) if len(near) else None},
            "share_above_0.8": float((s > 0.8).mean()) if len(s) else None,
            "bands": bands, "slope_per_10m": slope}


def paper_report(csv_path) -> dict:
    """The figures behind the README's "Reproducing the paper", from a
    ``results.csv`` of ``validate-paper`` (or of the single-question configs).

    ``q1[res]``: the five 1000-rectangle scenes (``all`` and ``by_scene``);
    ``occlusion[res]``: the 0/500/1000/2000-rectangle scenes (questions 2 and
    3: 0.0144 and 0.00576 deg); ``semantics[res]``: the positions where
    every backend and truth was run, each series on the same pairs, pooled
    over scenes. ``res`` is a primary resolution as text ('0.0144'). Every
    entry is :func:`series_stats` of binning vs pulse-centre truth unless
    named otherwise.
    """
    rows = list(_done_rows(Path(csv_path)).values())
    if not rows:
        raise InputValueError(f"{csv_path}: no rows")
    out: dict = {"rows": len(rows), "q1": {}, "occlusion": {}, "semantics": {}}
    resolutions = sorted({float(r["primary_resolution"]) for r in rows}, reverse=True)
    for res in resolutions:
        by = {sc: series_stats(*_series(rows, [sc], res)) for sc in PAPER_Q1_SCENES}
        by = {k: v for k, v in by.items() if v["pairs"]}
        if by:
            out["q1"][f"{res:g}"] = {"all": series_stats(*_series(rows, PAPER_Q1_SCENES, res)), "by_scene": by}
        occ = {sc: series_stats(*_series(rows, [sc], res)) for sc in PAPER_Q2_SCENES}
        occ = {k: v for k, v in occ.items() if v["pairs"]}
        if occ:
            out["occlusion"][f"{res:g}"] = occ
    series = sorted({(r["backend"], r["truth"]) for r in rows})
    out["semantics"] = {}
    for res in resolutions:
        full = _full_pairs(rows, res, series)
        if full and len(series) > 1:
            out["semantics"][f"{res:g}"] = {f"{b}/{t}": series_stats(*_series(rows, None, res, b, t, full))
                                           for b, t in series}
    return out


def _full_pairs(rows, resolution, series) -> set:
    """The (scene, position) pairs at one primary that have a row for every series."""
    have: dict = {}
    for r in rows:
        if float(r["primary_resolution"]) == float(resolution):
            have.setdefault((r["scene"], r["position"]), set()).add((r["backend"], r["truth"]))
    return {k for k, v in have.items() if v == set(series)}


def _pct(x):
    return "–" if x is None else f"{100 * x:.1f} %"


def paper_report_markdown(report: dict) -> str:
    """:func:`paper_report` as Markdown tables."""
    lines = []
    bands = [f"{lo:g}–{hi:g} m" if math.isfinite(hi) else f"≥ {lo:g} m" for lo, hi in DISTANCE_BANDS]
    keys = [f"{lo:g}-{hi:g}" for lo, hi in DISTANCE_BANDS]
    head = ("| series | pairs | mean < 17.5 m (min) | pairs < 17.5 m > 90 % | pairs > 80 % | "
            + " | ".join(bands) + " | slope /10 m |")
    sep = "|" + "---|" * (6 + len(bands))

    def row(name, st):
        b = st["below_17.5m"]
        cells = [_pct(st["bands"][k]["mean"]) if k in st["bands"] else "–" for k in keys]
        slope = "–" if st["slope_per_10m"] is None else f"{100 * st['slope_per_10m']:+.1f}"
        near = f"{_pct(b['mean'])} ({_pct(b['min'])})" if b["pairs"] else "–"
        return (f"| {name} | {st['pairs']} | {near} | {_pct(b['share_above_0.9'])} of {b['pairs']} | "
                f"{_pct(st['share_above_0.8'])} | " + " | ".join(cells) + f" | {slope} |")

    def table(title, items):
        if items:
            lines.extend([f"**{title}**", "", head, sep] + [row(n, st) for n, st in items] + [""])

    for res, q in report["q1"].items():
        table(f"Question 1 (distance): 1000-rectangle scenes, {res}° primaries, binning vs pulse-centre truth",
              list(q["by_scene"].items()) + [(f"all {len(q['by_scene'])}", q["all"])])
    for res, q in report["occlusion"].items():
        table(f"Questions 2 and 3 (occlusion, resolution): {res}° primaries, binning vs pulse-centre truth",
              list(q.items()))
    for res, ser in report["semantics"].items():
        table(f"Backends and truth semantics on the same pairs ({res}° primaries, all scenes)", list(ser.items()))
    return "\n".join(lines)


def plot_paper_figure(csv_path, png_path, backend: str = "binning", truth: str = "center") -> None:
    """The paper's Figure 3 from a ``validate-paper`` run, for one backend and
    truth semantics: (a) question 1, similarity against scanner distance over
    the five 1000-rectangle scenes; (b) question 2, one line per number of
    rectangles; (c) question 3, the same with the 0.00576 deg primaries (solid)
    over the 0.0144 deg ones (dashed); (d) every backend and truth semantics
    on the positions where all were run. Lines are means in 5 m bins."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(_done_rows(Path(csv_path)).values())
    if not rows:
        raise InputValueError(f"{csv_path}: no rows to plot")
    edges = np.arange(0, 50, 5.0)

    def binned(d, s):
        return _binned_means(d, 100 * s, edges)

    fig, ax = plt.subplots(1, 4, figsize=(20, 4.6))
    d, s = _series(rows, PAPER_Q1_SCENES, 0.0144, backend, truth)
    ax[0].scatter(d, 100 * s, s=7, alpha=0.5, c="C0", label=f"{len(d)} pairs")
    ax[0].plot(*binned(d, s), "k-", label="mean in 5 m bins")
    for k, sc in enumerate(PAPER_Q2_SCENES):
        n_rect = next((r["n_rectangles"] for r in rows if r["scene"] == sc), sc)
        for a, res, ls in ((ax[1], 0.0144, "o-"), (ax[2], 0.0144, ":"), (ax[2], 0.00576, "o-")):
            d, s = _series(rows, [sc], res, backend, truth)
            if len(d):
                lab = f"{n_rect} rectangles" + (f", {res:g}°" if a is ax[2] else "")
                a.plot(*binned(d, s), ls, ms=3, c=f"C{k}", label=lab)
    rep = paper_report(csv_path)["semantics"].get("0.0144", {})
    if rep:
        full = _full_pairs(rows, 0.0144, {tuple(k.split("/")) for k in rep})
        for k, name in enumerate(sorted(rep)):
            b, t = name.split("/")
            d, s = _series(rows, None, 0.0144, b, t, full)
            ax[3].plot(*binned(d, s), "o-", ms=3, c=f"C{k}", label=f"{b} vs {t} truth ({len(d)} pairs)")
    for a in ax[:3]:
        a.axvline(17.5, ls=":", c="gray")
        a.axhline(90, ls=":", c="gray")
    titles = ["(a) distance: five 1000-rectangle scenes", "(b) occlusion (0.0144° primaries)",
              "(c) primary resolution", "(d) backends and truths, same pairs (0.0144°)"]
    for a, title in zip(ax, titles):
        a.set(xlabel="distance from primary scanner (m)", ylabel="similarity (%)", title=title,
              ylim=(60, 101) if a is not ax[0] else (0, 101), xlim=(0, edges[-1]))
        if a.get_legend_handles_labels()[0]:
            a.legend(fontsize=7, loc="lower left")
    fig.suptitle(f"SLR validation: {backend} SLR scans vs {truth} truth" if backend else "")
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)
    plt.close(fig)


def hidden_from(scene, points, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Which ``points`` (on the surfaces of ``scene``) a scanner at ``origin``
    cannot see: the segment to the point meets another surface first (ray cast
    on the scene's mesh, 1 mm tolerance)."""
    from .raycast import RayScene

    o = np.asarray(origin, np.float64)
    v = np.asarray(points, np.float64) - o
    dist = np.linalg.norm(v, axis=1)
    if not len(v):
        return np.zeros(0, bool)
    ok = dist > 0
    dirs = np.zeros_like(v)
    dirs[ok] = v[ok] / dist[ok, None]
    caster = RayScene.triangles(np.asarray(scene.mesh.vertices, np.float64), np.asarray(scene.mesh.faces), o)
    t = caster.intersect(o, dirs, exact=True).distances
    return ok & (t < dist - np.maximum(1e-3, 1e-6 * dist))


def miss_breakdown(scene, true_scan, slr_points, primary_origin=(0.0, 0.0, 0.0), threshold: float = 0.10,
                   range_edges=(0.0, 5.0, 10.0, 20.0, 40.0, math.inf)) -> dict:
    """Why true points have no SLR point within ``threshold``.

    A true point of ``true_scan`` (a :class:`~slr_ray.meshscan.MeshScan` of
    ``scene`` from a secondary position) that the SLR scan misses is either
    **hidden** from the primary scanner (the segment from ``primary_origin``
    to the point crosses the scene first: no primary resolution can recover
    it) or **visible** to it (the primary saw that surface, but too coarsely,
    or the SLR scan picked another of its points: resolution and binning).
    Counts are split by label (ground, objects) and by range from the
    secondary position; ``hidden + visible == missed``.
    """
    from .similarity import nearest_distances

    true_pts = np.asarray(true_scan.points, np.float64)
    missed = ~(nearest_distances(true_pts, slr_points, upper_bound=threshold) < threshold)
    idx = np.flatnonzero(missed)
    hidden = np.zeros(len(true_pts), bool)
    if len(idx):
        hidden[idx] = hidden_from(scene, true_pts[idx], primary_origin)
    ground = np.asarray(true_scan.labels) == 0
    rng = np.linalg.norm(true_pts - np.asarray(true_scan.origin, np.float64), axis=1)

    def counts(mask):
        return {"true": int(mask.sum()), "missed": int((missed & mask).sum()),
                "hidden": int((hidden & mask).sum()), "visible": int((missed & ~hidden & mask).sum())}

    out = {"threshold": threshold, "all": counts(np.ones(len(true_pts), bool)), "ground": counts(ground),
           "objects": counts(~ground), "by_range": {}}
    for lo, hi in zip(range_edges[:-1], range_edges[1:]):
        out["by_range"][f"{lo:g}-{hi:g}"] = counts((rng >= lo) & (rng < hi))
    return out
