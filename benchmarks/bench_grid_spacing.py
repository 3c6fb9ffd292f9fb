"""Prepare time of pulse-grid discs by spacing kind (issue 28's "within 1.5x").

    PYTHONPATH=. python benchmarks/bench_grid_spacing.py [--scenes ground-only,rect-1000] [--repeats 5]

For each scene: the 0.1 deg primary of ``bench_tradeoff.py`` (pulse centres from
the origin), then ``prepare(..., backend="embree")`` with pulse-grid
neighbours and ``grid_spacing="step"`` (the default for a uniform primary)
and ``"mean"`` (the default before it: the baseline), alternated, ``repeats``
times each; medians. Accuracy of the two: ``bench_tradeoff.py``
(docs/backends.md "Grazing ground"). Saves results/bench_grid_spacing.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

from slr_ray import ScanPattern, prepare, scan_mesh  # noqa: E402
from slr_ray.scenes import scene_from_spec  # noqa: E402

KINDS = ("step", "mean")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="ground-only,rect-1000")
    ap.add_argument("--primary-resolution", type=float, default=0.1)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    grid = {"primary_origin": [0.0, 0.0, 0.0], "primary_resolution": args.primary_resolution}
    out = []
    for name in args.scenes.split(","):
        pts = scan_mesh(scene_from_spec(name), [0, 0, 0], ScanPattern(args.primary_resolution, max_range=100.0)).points
        for kind in KINDS:  # compile and warm the caches first
            prepare(pts[:2000], "embree", grid_spacing=kind, **grid)
        times = {k: [] for k in KINDS}
        for _ in range(args.repeats):
            for kind in KINDS:
                t0 = time.perf_counter()
                prepare(pts, "embree", grid_spacing=kind, **grid)
                times[kind].append(time.perf_counter() - t0)
        row = {"scene": name, "points": len(pts), "seconds": times,
               "median_seconds": {k: float(np.median(v)) for k, v in times.items()}}
        row["step_over_mean"] = row["median_seconds"]["step"] / row["median_seconds"]["mean"]
        out.append(row)
        print(f"{name}: {len(pts):,} points  prepare median step {row['median_seconds']['step']:.2f} s, "
              f"mean {row['median_seconds']['mean']:.2f} s  ({row['step_over_mean']:.2f}x)", flush=True)
    save("bench_grid_spacing", {"machine": machine(), "inputs": vars(args), "results": out})


if __name__ == "__main__":
    main()
