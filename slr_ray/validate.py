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
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputValueError

__all__ = ["ValidationConfig", "load_config", "run_validation", "plot_validation"]

COLUMNS = ["scene", "n_rectangles", "scene_seed", "primary_resolution", "position", "x", "y", "z",
           "distance_m", "backend", "truth", "similarity", "true_points", "slr_points", "seconds"]


@dataclass
class ValidationConfig:
    """What :func:`run_validation` runs (a ``[validate]`` table in TOML).

    ``scenes`` are scene specs (names in ``scenes/`` or paths);
    ``primary_resolutions`` one or more (the paper: 0.0144 and 0.00576);
    ``primary_semantics`` 'dense' (the paper's 5 mm grid) or 'center'.
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
        return self


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


def run_validation(config: ValidationConfig, outdir, progress: bool = True) -> dict:
    """Run (or resume) a validation; returns a summary. Writes ``outdir/results.csv``."""
    from .meshscan import scan_mesh
    from .pattern import ScanPattern
    from .positions import select_positions
    from .scan import simulate_scan
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
    bar = None
    total = len(config.scenes) * len(config.primary_resolutions) * config.positions
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="position", desc=config.name, file=sys.stderr)
    with open(csv_path, "a", newline="") as f:
        w = csv.DictWriter(f, COLUMNS)
        if new_file:
            w.writeheader()
        for spec in config.scenes:
            scene = scene_from_spec(spec)
            for res in config.primary_resolutions:
                wanted = [(str(i), b, t) for i in range(config.positions)
                          for b in config.backends for t in config.truths]
                key = lambda i, b, t: (spec, str(res), i, b, t)  # noqa: E731
                if all(key(*k) in done for k in wanted):
                    if bar is not None:
                        bar.update(config.positions)
                    continue
                primary = scan_mesh(scene, [0, 0, 0], ScanPattern(res), mode=config.primary_semantics,
                                    spacing=config.dense_spacing)
                positions = select_positions(primary.points, primary.labels == 0, config.positions,
                                             seed=config.seed, min_ground_points=config.min_ground_points,
                                             allow_fewer=True)
                discs = None
                for i, pos in enumerate(positions):
                    todo = [(b, t) for b in config.backends for t in config.truths
                            if key(str(i), b, t) not in done]
                    if todo:
                        truths = {t: scan_mesh(scene, pos, secondary, mode=t,
                                               supersample=config.nearest_supersample)
                                  for t in {t for _, t in todo}}
                        for b in sorted({b for b, _ in todo}):
                            t0 = time.perf_counter()
                            if b == "embree":
                                if discs is None:
                                    from .backends.embree import DiscScene

                                    discs = DiscScene(primary.points, **({"orientation": "normal"}
                                                                        | config.embree_options))
                                scan = discs.scan(pos, secondary)
                            else:
                                scan = simulate_scan(primary.points, pos, secondary)
                            sec = time.perf_counter() - t0
                            slr = primary.points[scan.indices]
                            for t in [t for bb, t in todo if bb == b]:
                                row = {"scene": spec, "n_rectangles": scene.n_rectangles,
                                       "scene_seed": scene.params["seed"], "primary_resolution": res,
                                       "position": i, "x": pos[0], "y": pos[1], "z": pos[2],
                                       "distance_m": float(math.hypot(pos[0], pos[1])), "backend": b,
                                       "truth": t, "similarity": similarity(truths[t].points, slr,
                                                                            config.threshold),
                                       "true_points": len(truths[t]), "slr_points": len(scan),
                                       "seconds": sec}
                                w.writerow(row)
                                n_new += 1
                        f.flush()
                    if bar is not None:
                        bar.update(1)
                if bar is not None and len(positions) < config.positions:
                    bar.update(config.positions - len(positions))
    if bar is not None:
        bar.close()
    rows = list(_done_rows(csv_path).values())
    return {"config": asdict(config), "csv": str(csv_path), "rows": len(rows), "new_rows": n_new,
            "seconds": round(time.perf_counter() - t_all, 2), **_headline(rows)}


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
        mids, means = [], []
        for lo, hi in zip(edges[:-1], edges[1:]):
            m = (d >= lo) & (d < hi)
            if m.any():
                mids.append((lo + hi) / 2)
                means.append(s[m].mean())
        ax[0].plot(mids, means, "-", label=label)
        for k, key in ((1, "n_rectangles"), (2, "primary_resolution")):
            groups = sorted({float(r[key]) for r in rr})
            for g in groups:
                m = np.array([float(r[key]) == g for r in rr])
                mids, means = [], []
                for lo, hi in zip(edges[:-1], edges[1:]):
                    mm = m & (d >= lo) & (d < hi)
                    if mm.any():
                        mids.append((lo + hi) / 2)
                        means.append(s[mm].mean())
                ax[k].plot(mids, means, "o-", ms=3, label=f"{label}, {key.replace('_', ' ')} {g:g}")
    ax[0].axvline(17.5, ls=":", c="gray")
    ax[0].axhline(90, ls=":", c="gray")
    titles = ["(a) similarity vs scanner distance", "(b) by number of rectangles", "(c) by primary resolution"]
    for a, title in zip(ax, titles):
        a.set(xlabel="distance from primary scanner (m)", ylabel="similarity (%)", ylim=(0, 101), title=title)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
