"""What the silhouette rule adds to an embree cast: the same discs cast with and without it.

    PYTHONPATH=. nice python benchmarks/bench_silhouette_cost.py [--resolution 0.1] [--repeats 5]

The benchmark cloud (``common.realistic_cloud``: rect-1000 scanned from the origin at
``--resolution``; 2.4 M points at 0.1 deg, 7.2 M at 0.058) prepared once with pulse-grid discs
(``primary_origin=0``, ``primary_resolution=RES``), then 0.144 deg scans from (12.3, -7.1, 0) with the
rule (the scanner's silhouette bits) and without it (no bits: the same discs), alternated; one
uncounted scan of each first (numba's compiles). Reports the CPU seconds of each cast (all threads:
steadier than wall seconds on a shared machine), their medians and ratio, and the points out.
Saves results/bench_silhouette_cost.json.
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
from common import machine, realistic_cloud, save  # noqa: E402

import slr_ray  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=float, default=0.1)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    pts = np.ascontiguousarray(realistic_cloud(args.resolution))
    sc = slr_ray.prepare(pts, "embree", primary_origin=[0.0, 0.0, 0.0], primary_resolution=args.resolution)
    clip = sc._clip  # the silhouette bits and the primary's grid (None: no rule)
    cpu = {"rule": [], "no rule": []}
    out = {}
    for i in range(args.repeats + 1):
        for name in cpu:
            sc._clip = clip if name == "rule" else None
            c0 = time.process_time()
            s = sc.scan([12.3, -7.1, 0.0], 0.144)
            if i:
                cpu[name].append(time.process_time() - c0)
            out[name] = len(s)
    sc._clip = clip
    med = {k: statistics.median(v) for k, v in cpu.items()}
    ratio = med["rule"] / med["no rule"]
    print(f"{len(pts):,} points, load {os.getloadavg()[0]:.1f}: cast CPU s, rule {np.round(cpu['rule'], 2).tolist()}, "
          f"no rule {np.round(cpu['no rule'], 2).tolist()}; medians {med['rule']:.2f} / {med['no rule']:.2f} = "
          f"{ratio:.3f}; points out {out['rule']:,} / {out['no rule']:,}")
    save("bench_silhouette_cost", {"machine": machine(), "inputs": vars(args), "points": len(pts), "cpu_s": cpu,
                                   "median_cpu_s": med, "ratio": ratio, "points_out": out,
                                   "load": os.getloadavg()})


if __name__ == "__main__":
    main()
