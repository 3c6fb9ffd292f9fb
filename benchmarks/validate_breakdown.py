"""Why SLR scans miss true points: occlusion from the primary scanner or resolution.

    python benchmarks/validate_breakdown.py RUN_DIR [--scenes distance-2,rect-2000]
        [--resolutions 0.0144,0.00576] [--every 10] [--positions 3,17] [--semantics dense]
        [--truth center]

RUN_DIR is the output directory of ``slr-ray validate paper`` (or of any
validate config): its ``positions/<scene>.csv`` gives the positions. For each
scene, primary resolution and position (every ``--every``-th, or those listed
in ``--positions``): the true scan (pulse-centre, or nearest-in-pulse), the binning SLR scan of the
dense primary, the similarity (checked against RUN_DIR/results.csv) and
:func:`slr_ray.validation.miss_breakdown`: of the true points with no SLR point
within 10 cm, how many are hidden from the primary scanner (occlusion: no
primary resolution recovers them) and how many it saw (resolution and
binning). Prints a table, saves results/validate_breakdown.json and
results/validate_breakdown.png (missed share, hidden vs visible, by scanner
distance).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, save  # noqa: E402

from slr_ray import ScanPattern, scan_mesh, simulate_scan  # noqa: E402
from slr_ray.positions import azimuth_histogram  # noqa: E402
from slr_ray.scenes import scene_from_spec  # noqa: E402
from slr_ray.similarity import similarity  # noqa: E402
from slr_ray.validation import peak_rss_gib, miss_breakdown  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--scenes", default="distance-2,ground-only,rect-0500,rect-1000,rect-2000")
    ap.add_argument("--resolutions", default="0.0144")
    ap.add_argument("--semantics", default="dense", help="primary semantics: dense (the paper's) or center")
    ap.add_argument("--truth", default="center", help="truth semantics: center or nearest (k = 3)")
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--positions", help="comma-separated position numbers (default: every --every-th)")
    ap.add_argument("--range-edges", default="0,5,10,20,40,inf",
                    help="edges of the range bands (m from the secondary position) of the breakdown")
    ap.add_argument("--name", default="validate_breakdown")
    args = ap.parse_args(argv)
    done = {}
    if (args.run / "results.csv").exists():
        with open(args.run / "results.csv", newline="") as f:
            for r in csv.DictReader(f):
                if r["backend"] == "binning" and r["truth"] == args.truth:
                    done[(r["scene"], float(r["primary_resolution"]), int(r["position"]))] = float(r["similarity"])
    secondary = ScanPattern(0.144)
    rows = []
    t_all = time.perf_counter()
    for spec in args.scenes.split(","):
        scene = scene_from_spec(spec)
        positions = np.loadtxt(args.run / "positions" / f"{spec}.csv", delimiter=",", ndmin=2)
        which = ([int(i) for i in args.positions.split(",")] if args.positions
                 else list(range(0, len(positions), args.every)))
        truths = {}
        for res in map(float, args.resolutions.split(",")):
            t0 = time.perf_counter()
            primary = scan_mesh(scene, [0, 0, 0], ScanPattern(res), mode=args.semantics)
            print(f"{spec} {res:g}: primary {len(primary):,} points in {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr, flush=True)
            for i in which:
                pos = positions[i]
                if i not in truths:
                    truths[i] = scan_mesh(scene, pos, secondary, mode=args.truth, supersample=3)
                truth = truths[i]
                slr = primary.points[simulate_scan(primary.points, pos, secondary).indices]
                sim = similarity(truth.points, slr)
                b = miss_breakdown(scene, truth, slr,
                                   range_edges=tuple(float(x) for x in args.range_edges.split(",")))
                ref = done.get((spec, res, i))
                row = {"scene": spec, "n_rectangles": scene.n_rectangles, "primary_resolution": res,
                       "truth": args.truth, "position": i, "distance_m": float(math.hypot(pos[0], pos[1])),
                       "similarity": sim, "similarity_in_run": ref, "breakdown": b,
                       # sorted per-degree counts (0th, 5th, 10th, 36th, 180th smallest): a shadow of the
                       # primary shows as near-empty sectors of the SLR scan, which the paper's azimuth test rejects
                       "slr_azimuth_sorted": azimuth_histogram(slr, pos)[[0, 4, 9, 35, 179]].tolist(),
                       "true_azimuth_sorted": azimuth_histogram(truth.points, pos)[[0, 4, 9, 35, 179]].tolist()}
                rows.append(row)
                a = b["all"]
                print(f"{spec:12s} {res:<8g} {i:3d} {row['distance_m']:6.1f} m  sim {100 * sim:5.1f} %  "
                      f"missed {100 * a['missed'] / a['true']:5.1f} %: hidden {100 * a['hidden'] / a['true']:5.1f} %"
                      f" visible {100 * a['visible'] / a['true']:5.1f} %  (objects: hidden "
                      f"{100 * b['objects']['hidden'] / max(1, a['true']):.1f} %)", flush=True)
            del primary
    mismatched = [(r["scene"], r["position"]) for r in rows
                  if r["similarity_in_run"] is not None and abs(r["similarity"] - r["similarity_in_run"]) > 1e-12]
    payload = {"inputs": vars(args) | {"run": str(args.run)}, "machine": machine(),
               "seconds": round(time.perf_counter() - t_all, 1), "peak_rss_gib": round(peak_rss_gib(), 2),
               "similarity_differs_from_run": mismatched, "rows": rows}
    save(args.name, payload)
    plot(rows, RESULTS / f"{args.name}.png")


def plot(rows, png):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = sorted({(r["scene"], r["primary_resolution"]) for r in rows})
    fig, ax = plt.subplots(1, len(groups), figsize=(3.6 * len(groups), 3.8), sharey=True, squeeze=False)
    for a, (spec, res) in zip(ax[0], groups):
        rr = sorted((r for r in rows if r["scene"] == spec and r["primary_resolution"] == res),
                    key=lambda r: r["distance_m"])
        d = np.array([r["distance_m"] for r in rr])
        hid = np.array([100 * r["breakdown"]["all"]["hidden"] / r["breakdown"]["all"]["true"] for r in rr])
        vis = np.array([100 * r["breakdown"]["all"]["visible"] / r["breakdown"]["all"]["true"] for r in rr])
        a.bar(d, hid, width=1.2, color="C3", label="hidden from the primary")
        a.bar(d, vis, width=1.2, bottom=hid, color="C0", label="seen by the primary")
        a.set(title=f"{spec}, {res:g}° primary", xlabel="distance from primary scanner (m)")
    ax[0][0].set_ylabel("true points missed (%)")
    ax[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
    print(f"saved {png}", file=sys.stderr)


if __name__ == "__main__":
    main()
