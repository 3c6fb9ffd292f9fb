"""End-to-end SLR throughput on the 29 M-point benchmark cloud: how long 13,000 scans take.

    python benchmarks/bench_throughput.py [--n 40] [--formats npy laz]

The paper generated 13,000 SLR clouds from SYNS scans of about 29 M points.
This measures the stages of doing that here, on the benchmark cloud (ground =
the points within 5 cm of the ground plane z = -1.65 m): choosing positions
once (the grid method), then per position the binning scan (0.144 deg), the
subset of every attribute and the file written (each format in ``--formats``),
with the paper's sort method timed on the same cloud in the same run as the
baseline. Reports seconds per stage, scans per hour and the projected wall
time of 13,000 scans (positions once + 13,000 x (scan + write)), single
process (each scan already uses both cores). Saves results/bench_throughput.json.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, realistic_cloud, save  # noqa: E402

from slr_ray import ScanPattern, prepare, select_positions  # noqa: E402
from slr_ray.io import PointCloud, write_cloud  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40, help="positions timed")
    ap.add_argument("--formats", nargs="+", default=["npy", "npz", "laz"])
    args = ap.parse_args(argv)
    pts = np.ascontiguousarray(realistic_cloud())
    ground = np.abs(pts[:, 2] + 1.65) < 0.05
    cloud = PointCloud(pts, {"is_ground": ground.astype(np.uint8)})
    pattern = ScanPattern(0.144)
    t0 = time.perf_counter()
    positions = select_positions(pts, ground, args.n, seed=0, allow_fewer=True)
    t_pos = time.perf_counter() - t0
    print(f"positions: {len(positions)} in {t_pos:.1f} s", flush=True)
    from sort_baseline import sort_based_scan

    t0 = time.perf_counter()
    sort_based_scan(pts, positions[0], pattern)
    t_sort = time.perf_counter() - t0
    scanner = prepare(pts)
    scanner.scan(positions[0], pattern)  # compile
    scan_s, subset_s, write_s, sizes = [], [], {f: [] for f in args.formats}, []
    with tempfile.TemporaryDirectory() as tmp:
        for i, p in enumerate(positions):
            t0 = time.perf_counter()
            scan = scanner.scan(p, pattern)
            scan_s.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            sub = cloud.subset(scan.indices)
            subset_s.append(time.perf_counter() - t0)
            sizes.append(len(scan))
            for f in args.formats:
                t0 = time.perf_counter()
                write_cloud(Path(tmp) / f"s{i}.{f}", sub)
                write_s[f].append(time.perf_counter() - t0)
    per = {"scan": float(np.median(scan_s)), "subset": float(np.median(subset_s))}
    rows = {}
    for f in args.formats:
        total = per["scan"] + per["subset"] + float(np.median(write_s[f]))
        rows[f] = {"write_seconds": float(np.median(write_s[f])), "seconds_per_scan": total,
                   "scans_per_hour": 3600 / total, "projected_13000_hours": (t_pos + 13000 * total) / 3600}
        print(f"{f:>4}: scan {per['scan']:.3f} + subset {per['subset']:.3f} + write {rows[f]['write_seconds']:.3f} "
              f"= {total:.3f} s/scan -> {3600 / total:,.0f} scans/h, 13,000 in {rows[f]['projected_13000_hours']:.2f} h",
              flush=True)
    print(f"sort baseline {t_sort:.2f} s per scan: binning {t_sort / per['scan']:.1f}x faster", flush=True)
    save("bench_throughput", {"machine": machine(), "inputs": vars(args), "points": len(pts),
                              "positions_seconds": t_pos, "sort_baseline_seconds": t_sort,
                              "median_stage_seconds": per, "points_out_median": float(np.median(sizes)),
                              "formats": rows})


if __name__ == "__main__":
    main()
