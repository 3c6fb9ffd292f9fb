"""Peak memory and time of the embree backend on a 5 M-point cloud.

    python benchmarks/bench_embree_memory.py [--points 5000000]

The cloud is the first N points of the realistic 29 M-point scene scan of
bench_binning (cached under results/). Each setting runs in its own process
(peak RSS via getrusage); one scan at 0.144 deg from a position 14 m away.
Prints a table and saves results/bench_embree_memory.json.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, realistic_cloud, run_isolated, save  # noqa: E402

SETTINGS = {
    "normal s5": {"orientation": "normal", "segments": 5},
    "billboard s5": {"orientation": "billboard", "segments": 5},
    "normal s3": {"orientation": "normal", "segments": 3},
    "normal s5 open3d": {"orientation": "normal", "segments": 5, "engine": "open3d"},
}


def run_one(name, n):
    import numpy as np

    from slr_ray import ScanPattern
    from slr_ray.backends.embree import DiscScene

    pts = np.ascontiguousarray(realistic_cloud()[:n])
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    t0 = time.perf_counter()
    scene = DiscScene(pts, **SETTINGS[name])
    prep = time.perf_counter() - t0
    scan = scene.scan([12.3, -7.1, 0.0], ScanPattern(0.144))
    print(json.dumps({"setting": name, "points": n, "prepare_and_build_seconds": prep,
                      "scan_seconds": scan.seconds, "build_seconds_in_scan": scan.info["build_seconds"],
                      "cast_seconds": scan.info["cast_seconds"], "points_out": len(scan),
                      "embree_input_bytes_per_point": scene.nbytes / n,
                      "cloud_gib": pts.nbytes / 2**30, "rss_before_gib": base,
                      "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=5_000_000)
    ap.add_argument("--setting", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.setting:
        return run_one(args.setting, args.points)
    realistic_cloud()  # build the cache once, outside the measured processes
    rows = []
    for name in SETTINGS:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        rows.append(run_isolated(__file__, ["--setting", name, "--points", str(args.points)], "setting", name))
    print(f"{'setting':<18} {'points':>10} {'prep+build s':>12} {'scan s':>7} {'B/pt to embree':>14} {'peak GiB':>9}")
    for r in rows:
        if "error" in r:
            print(f"{r['setting']:<18} failed: {r['error']}")
            continue
        print(f"{r['setting']:<18} {r['points']:>10,} {r['prepare_and_build_seconds']:>12.1f} "
              f"{r['scan_seconds']:>7.1f} {r['embree_input_bytes_per_point']:>14.0f} {r['peak_rss_gib']:>9.2f}")
    save("bench_embree_memory", {"machine": machine(), "inputs": {"points": args.points, "settings": SETTINGS,
                                                                  "pattern": "0.144 deg", "origin": [12.3, -7.1, 0.0]},
                                 "rows": rows})


if __name__ == "__main__":
    main()
