"""Default ground labelling (CSF) of a real terrestrial scan: time and what it labels.

    python benchmarks/bench_ground.py [--runs 3] [--input ../shared/data/forest_tls_riegl.laz]

A cloud without ground labels is labelled by Cloth Simulation Filtering
(``slr_ray.label_ground``, the paper's choice) before positions are drawn.
This times it on the RIEGL forest scan (1,046,843 points, flat ground near
z = -1.3, scanner at the origin), checks that every run labels the same
points (the labelling is deterministic), and says where the ground points
lie (their z quantiles) and how many non-ground points lie below z = -1.0.
Prints a table and saves results/bench_ground.json.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

from slr_ray.io import read_cloud  # noqa: E402
from slr_ray.positions import label_ground  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "forest_tls_riegl.laz"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--input", default=str(DATA if DATA.exists() else "/work/shared/data/forest_tls_riegl.laz"))
    ap.add_argument("--cloth-resolution", type=float, default=0.5)
    args = ap.parse_args()
    pts = read_cloud(args.input).points
    times, first = [], None
    for _ in range(args.runs):
        t0 = time.perf_counter()
        g = label_ground(pts, cloth_resolution=args.cloth_resolution)
        times.append(time.perf_counter() - t0)
        if first is None:
            first = g
        elif not np.array_equal(g, first):
            raise SystemExit("CSF labelled different points on two runs")
    z = pts[first, 2]
    res = {"input": args.input, "points": len(pts), "cloth_resolution": args.cloth_resolution,
           "runs": args.runs, "seconds_median": round(statistics.median(times), 2),
           "seconds": [round(t, 2) for t in times], "ground_points": int(first.sum()),
           "ground_share": round(float(first.mean()), 4),
           "ground_z_quantiles_5_50_95": [round(float(q), 3) for q in np.quantile(z, [0.05, 0.5, 0.95])],
           "non_ground_below_minus_1": int(np.count_nonzero(~first & (pts[:, 2] < -1.0))),
           "deterministic": True, "load_average_1_5_15": [round(x, 1) for x in os.getloadavg()],
           "machine": machine()}
    for k, v in res.items():
        if k != "machine":
            print(f"{k:28s} {v}")
    save("bench_ground", res)


if __name__ == "__main__":
    main()
