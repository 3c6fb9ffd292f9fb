"""Speed/accuracy trade of the two backends against ground truth (synthetic scenes).

    python benchmarks/bench_tradeoff.py [--scenes ground-only,rect-1000] [--positions 6]
                                        [--primary-resolution 0.1] [--quick]

For each scene: a primary scan of the mesh from the origin (pulse centres), then
at each secondary position the true scans of the mesh (both truth semantics:
pulse-centre and nearest-in-pulse with 3 x 3 sub-rays) and the SLR scans of the
primary cloud by every backend setting. Coverage (the paper's similarity) =
fraction of true points within 10 cm of the SLR scan; precision = fraction of
SLR points within 10 cm of a true point (see-through points lower it, not
coverage). Time per position: "build" = preparing the cloud once (neighbours,
radii, normals, the one BVH) amortised over the positions, "cast" = the scan.

Prints a table, saves results/bench_tradeoff.json and results/tradeoff.png
(accuracy against time: the Pareto front).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, save  # noqa: E402

from slr_ray import ScanPattern, prepare, scan_mesh, similarity  # noqa: E402
from slr_ray.scenes import scene_from_spec  # noqa: E402

DISTANCE_BANDS = [(0, 7.5), (7.5, 17.5), (17.5, 40)]


def configs(quick: bool, primary_res: float, cells: bool = False):
    """Backend settings: binning, then embree discs by orientation, radius,
    tie window and engine (exact discs; polygon fans in Embree and in Open3D); with ``cells``, each
    setting that knows the primary (origin and resolution) also with ``pulse_cells=True`` (" cells")."""
    out = [{"name": "binning", "backend": "binning"}]

    def embree(orientation="normal", radius="spacing", scale=1.0, ties=1.0, engine="embree", segments=3, k=6,
               neighbours="knn", grid_spacing=None):
        name = f"embree {orientation} r={radius}x{scale} ties={ties} {engine}" + (
            f" s{segments}" if engine != "embree" else "") + (f" k={k}" if k != 6 else "") + (
            " grid" if neighbours != "knn" else "") + (f" {grid_spacing}" if grid_spacing else "")
        out.append({"name": name, "backend": "embree", "orientation": orientation, "radius": radius,
                     "radius_scale": scale, "ties": ties, "engine": engine, "segments": segments, "k": k,
                     "neighbours": neighbours, **({"grid_spacing": grid_spacing} if grid_spacing else {})})

    for radius in ("spacing", "footprint", 0.02):
        embree("normal", radius)
        embree("billboard", radius)
    embree("primary", "spacing")
    embree("primary", "footprint")        # no neighbour search at all: discs of the primary's own pulses
    embree("primary", "footprint", 0.75)  # just over the half-diagonal of a pulse cell (0.707)
    # normals from the primary's own pulse grid (no kd-tree)
    embree("normal", "footprint", neighbours="pulse-grid")
    embree("normal", "footprint", 0.75, neighbours="pulse-grid")
    embree("normal", "spacing", neighbours="pulse-grid")  # the default: grid_spacing='step'
    embree("normal", "spacing", neighbours="pulse-grid", grid_spacing="mean")  # the default before it
    embree("normal", ties=0.0)
    embree("normal", engine="fan")
    if not quick:
        embree("normal", k=12)
        embree("normal", ties=3.0)
        for scale in (0.5, 2.0):
            embree("normal", "spacing", scale)
        embree("normal", engine="open3d", segments=5)
    for c in out:
        if c.get("radius") == "footprint" or c.get("orientation") == "primary" or c.get("neighbours") == "pulse-grid":
            c["primary_origin"] = [0.0, 0.0, 0.0]
            c["primary_resolution"] = primary_res
    if cells:
        out += [{**c, "name": c["name"] + " cells", "pulse_cells": True} for c in out
                if "primary_origin" in c and c["engine"] != "open3d"]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="ground-only,rect-1000")
    ap.add_argument("--positions", type=int, default=6)
    ap.add_argument("--primary-resolution", type=float, default=0.1)
    ap.add_argument("--resolution", type=float, default=0.144)
    ap.add_argument("--max-range", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--pulse-cells", action="store_true",
                    help="also each setting that knows the primary with pulse_cells=True (names end ' cells')")
    ap.add_argument("--only", nargs="+", help="run only the settings whose name contains one of these")
    ap.add_argument("--name", default="bench_tradeoff",
                    help="results/<name>.json and results/<name>.png (a partial run keeps the full one)")
    args = ap.parse_args(argv)

    secondary = ScanPattern(args.resolution, max_range=args.max_range)
    rng = np.random.default_rng(args.seed)
    dist = np.linspace(3, 30, args.positions)
    ang = rng.uniform(0, 2 * np.pi, args.positions)
    positions = np.column_stack([dist * np.cos(ang), dist * np.sin(ang), np.zeros(args.positions)])
    rows = []
    for scene_name in args.scenes.split(","):
        scene = scene_from_spec(scene_name)
        t0 = time.perf_counter()
        primary = scan_mesh(scene, [0, 0, 0], ScanPattern(args.primary_resolution, max_range=100.0))
        print(f"{scene_name}: primary {len(primary):,} points at {args.primary_resolution} deg "
              f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
        truths = [{"center": scan_mesh(scene, p, secondary),
                   "nearest": scan_mesh(scene, p, secondary, mode="nearest", supersample=3)}
                  for p in positions]
        for cfg in [c for c in configs(args.quick, args.primary_resolution, args.pulse_cells)
                    if not args.only or any(o in c["name"] for o in args.only)]:
            # one prepared scanner per cloud and setting, every position a query
            t0 = time.perf_counter()
            opts = {k: v for k, v in cfg.items() if k not in ("name", "backend")}
            scanner = prepare(primary.points, cfg["backend"], **opts)
            build_once = time.perf_counter() - t0
            for i, pos in enumerate(positions):
                scan = scanner.scan(pos, secondary)
                cast = scan.seconds
                build = build_once / len(positions)
                sim_pts = primary.points[scan.indices]
                row = {"scene": scene_name, "config": cfg["name"], "position": pos.tolist(),
                       "distance_m": float(np.hypot(pos[0], pos[1])), "points": len(scan),
                       "build_seconds": build, "cast_seconds": cast, "seconds": build + cast}
                for sem, truth in truths[i].items():
                    row[f"similarity_{sem}"] = similarity(truth.points, sim_pts)
                    row[f"precision_{sem}"] = similarity(sim_pts, truth.points)
                    row[f"truth_{sem}_points"] = len(truth)
                rows.append(row)
            r = [x for x in rows if x["config"] == cfg["name"] and x["scene"] == scene_name]
            print(f"  {cfg['name']:<36} {np.mean([x['seconds'] for x in r]):7.2f} s/pos  "
                  f"sim centre {np.mean([x['similarity_center'] for x in r]):.3f}  "
                  f"nearest {np.mean([x['similarity_nearest'] for x in r]):.3f}  "
                  f"precision centre {np.mean([x['precision_center'] for x in r]):.3f}", file=sys.stderr, flush=True)
    summary = summarise(rows)
    print_table(summary)
    plot(summary, RESULTS / ("tradeoff.png" if args.name == "bench_tradeoff" else f"{args.name}.png"))
    save(args.name, {"machine": machine(), "inputs": {
        "scenes": args.scenes, "only": args.only, "pulse_cells": args.pulse_cells, "positions": positions.tolist(), "primary_resolution": args.primary_resolution,
        "secondary": secondary.to_dict(), "similarity_threshold_m": 0.10,
        "truth": {"center": "one ray per pulse centre", "nearest": "3 x 3 sub-rays per pulse + centre"}},
        "summary": summary, "rows": rows})


def summarise(rows):
    out = []
    keys = sorted({(r["scene"], r["config"]) for r in rows}, key=lambda k: (k[0], k[1] != "binning", k[1]))
    for scene, cfg in keys:
        r = [x for x in rows if x["scene"] == scene and x["config"] == cfg]
        s = {"scene": scene, "config": cfg, "seconds_per_position": float(np.mean([x["seconds"] for x in r])),
             "build_seconds": float(np.mean([x["build_seconds"] for x in r])),
             "cast_seconds": float(np.mean([x["cast_seconds"] for x in r]))}
        for sem in ("center", "nearest"):
            s[f"similarity_{sem}"] = float(np.mean([x[f"similarity_{sem}"] for x in r]))
            s[f"precision_{sem}"] = float(np.mean([x[f"precision_{sem}"] for x in r]))
            for lo, hi in DISTANCE_BANDS:
                b = [x[f"similarity_{sem}"] for x in r if lo <= x["distance_m"] < hi]
                s[f"similarity_{sem}_{lo}-{hi}m"] = float(np.mean(b)) if b else None
        out.append(s)
    return out


def print_table(summary):
    head = (f"{'scene':<12} {'config':<46} {'s/pos':>7} {'build':>7} {'cast':>6} {'cov ctr':>8} {'cov nrst':>8} "
            f"{'prec ctr':>8} {'prec nrst':>9}")
    bands = "  ".join(f"ctr {lo}-{hi}m" for lo, hi in DISTANCE_BANDS)
    print(head + "  " + bands)
    for s in summary:
        b = "  ".join(f"{s[f'similarity_center_{lo}-{hi}m']:>11.3f}" if s[f"similarity_center_{lo}-{hi}m"] is not None
                      else f"{'-':>11}" for lo, hi in DISTANCE_BANDS)
        print(f"{s['scene']:<12} {s['config']:<46} {s['seconds_per_position']:>7.2f} {s['build_seconds']:>7.2f} "
              f"{s['cast_seconds']:>6.2f} {s['similarity_center']:>8.3f} {s['similarity_nearest']:>8.3f} "
              f"{s['precision_center']:>8.3f} {s['precision_nearest']:>9.3f}  {b}")


def plot(summary, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = sorted({s["scene"] for s in summary})
    panels = [("similarity", "center"), ("similarity", "nearest"), ("precision", "center")]
    fig, axes = plt.subplots(len(scenes), len(panels), figsize=(18, 4.8 * len(scenes)), squeeze=False)
    for row, scene in enumerate(scenes):
        ss = [s for s in summary if s["scene"] == scene]
        for col, (metric, sem) in enumerate(panels):
            ax = axes[row, col]
            x = np.array([s["seconds_per_position"] for s in ss])
            y = np.array([100 * s[f"{metric}_{sem}"] for s in ss])
            for s, xi, yi in zip(ss, x, y):
                marker = "*" if s["config"] == "binning" else ("o" if "normal" in s["config"] else "s")
                ax.scatter(xi, yi, marker=marker, s=90 if marker == "*" else 40)
                ax.annotate(s["config"].replace("embree ", ""), (xi, yi), fontsize=6,
                            xytext=(4, 2), textcoords="offset points")
            order = np.argsort(x)
            front, best = [], -np.inf
            for i in order:  # Pareto front: faster and not less accurate
                if y[i] > best:
                    front.append(i)
                    best = y[i]
            ax.plot(x[front], y[front], "k--", lw=1, label="Pareto front")
            ax.set_xscale("log")
            ax.set(xlabel="seconds per position (log)",
                   ylabel=("coverage of the truth" if metric == "similarity" else "precision") + " (%)",
                   title=f"{scene}: {'coverage' if metric == 'similarity' else 'precision'}, truth = "
                         f"{'pulse centre' if sem == 'center' else 'nearest in pulse'}")
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"figure {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
