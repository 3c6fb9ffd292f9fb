"""What ``pulse_cells`` costs on a uniform primary (issue #46 item 2: should it be the default?).

    PYTHONPATH=. nice python benchmarks/bench_pulse_cells_cost.py [--resolution 0.2] [--repeats 3]

The benchmark cloud (``common.realistic_cloud``: rect-1000 scanned from the origin at ``--resolution``)
prepared with pulse-grid discs (``primary_origin=0``, ``primary_resolution=RES``, the defaults) with and
without ``pulse_cells``, alternated, then 0.144 deg scans from the primary's origin, from 1 m aside and
from (12.3, -7.1, 0), alternated; one uncounted round first (numba's compiles). CPU seconds of all
threads (steadier than wall seconds on a shared machine), medians, ratios, points out.
Saves results/bench_pulse_cells_cost.json.
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

POSITIONS = {"primary's origin": [0.0, 0.0, 0.0], "1 m aside": [0.0, 1.0, 0.0], "14 m aside": [12.3, -7.1, 0.0]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=float, default=0.2)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    pts = np.ascontiguousarray(realistic_cloud(args.resolution))
    grid = {"primary_origin": [0.0, 0.0, 0.0], "primary_resolution": args.resolution}
    cpu = {s: {"prepare": [], **{p: [] for p in POSITIONS}} for s in ("off", "pulse_cells")}
    out = {s: {} for s in cpu}
    load = [os.getloadavg()[0]]
    for i in range(args.repeats + 1):
        for s in cpu:
            c0 = time.process_time()
            sc = slr_ray.prepare(pts, "embree", pulse_cells=s == "pulse_cells", **grid)
            if i:
                cpu[s]["prepare"].append(time.process_time() - c0)
            for p, o in POSITIONS.items():
                c0 = time.process_time()
                scan = sc.scan(o, 0.144)
                if i:
                    cpu[s][p].append(time.process_time() - c0)
                out[s][p] = len(scan)
            del sc
        load.append(os.getloadavg()[0])
    med = {s: {k: statistics.median(v) for k, v in d.items()} for s, d in cpu.items()}
    ratio = {k: med["pulse_cells"][k] / med["off"][k] for k in med["off"]}
    print(f"{len(pts):,} points, load {min(load):.1f}-{max(load):.1f}: CPU s medians of {args.repeats}")
    for k in ratio:
        print(f"  {k}: {med['pulse_cells'][k]:.3f} / {med['off'][k]:.3f} = {ratio[k]:.2f}x"
              + (f"; points {out['pulse_cells'][k]:,} / {out['off'][k]:,}" if k in POSITIONS else ""))
    save("bench_pulse_cells_cost", {"machine": machine(), "inputs": vars(args), "points": len(pts), "cpu_s": cpu,
                                    "median_cpu_s": med, "pulse_cells_over_off": ratio, "points_out": out,
                                    "load": load})


if __name__ == "__main__":
    main()
