"""Paper-size dense scans: the 5 mm "dense cloud" of a scene streamed through the
binning reduction (never in memory), against exact ray casting of the mesh.

    python benchmarks/bench_dense.py [--scene rect-1000] [--spacing 0.005]
                                     [--jobs dense-secondary,center-secondary,dense-primary,center-primary]

Each job runs in its own process so that its peak memory (ru_maxrss) is its own,
and streams its scan into a compact file (slr_ray.meshscan.scan_mesh_to_file).
Prints a table; saves results/bench_dense.json.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, run_isolated, save  # noqa: E402

JOBS = {
    # name: (mode, origin, resolution)
    "dense-secondary": ("dense", [10.0, 5.0, 0.0], 0.144),
    "center-secondary": ("center", [10.0, 5.0, 0.0], 0.144),
    "nearest4-secondary": ("nearest", [10.0, 5.0, 0.0], 0.144),
    "dense-primary": ("dense", [0.0, 0.0, 0.0], 0.0144),
    "center-primary": ("center", [0.0, 0.0, 0.0], 0.0144),
    "dense-primary-fine": ("dense", [0.0, 0.0, 0.0], 0.00576),
}


def run_job(name, scene_name, spacing):
    import tempfile

    from slr_ray import ScanPattern
    from slr_ray.meshscan import scan_mesh_to_file
    from slr_ray.scenes import dense_samples, scene_from_spec

    mode, origin, res = JOBS[name]
    scene = scene_from_spec(scene_name)
    t0 = time.perf_counter()
    opts = {"spacing": spacing} if mode == "dense" else {"supersample": 4} if mode == "nearest" else {}
    with tempfile.TemporaryDirectory(dir=Path(__file__).resolve().parent / "results") as d:
        info = scan_mesh_to_file(scene, origin, ScanPattern(res), Path(d) / "scan.npz", mode=mode, **opts)
    seconds = time.perf_counter() - t0
    out = {"job": name, "mode": mode, "origin": origin, "resolution": res, "points_out": info["points_out"],
           "seconds": seconds, "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
           "compact_bytes": info["bytes"]}  # scan_mesh_to_file: float32 offsets, int32 labels, uint32 pulse ids
    if mode == "dense":
        out["samples"] = int(sum(len(p) for p, _ in dense_samples(scene, spacing, copy=False)))
    print(json.dumps(out))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="rect-1000")
    ap.add_argument("--spacing", type=float, default=0.005)
    ap.add_argument("--jobs", default="dense-secondary,center-secondary,nearest4-secondary,dense-primary,"
                    "center-primary,dense-primary-fine")
    ap.add_argument("--job", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.job:
        return run_job(args.job, args.scene, args.spacing)
    rows = []
    for name in args.jobs.split(","):
        print(f"running {name} ...", file=sys.stderr, flush=True)
        r = run_isolated(__file__, ["--job", name, "--scene", args.scene, "--spacing", str(args.spacing)],
                         "job", name)
        rows.append(r)
        if "error" in r:
            continue
        print(f"  {r['points_out']:,} points, {r['seconds']:.1f} s, peak {r['peak_rss_gib']:.2f} GiB",
              file=sys.stderr, flush=True)
    print(f"\n{'job':<20} {'points out':>12} {'seconds':>8} {'peak GiB':>9} {'compact MB':>11} {'samples':>14}")
    for r in rows:
        if "error" in r:
            print(f"{r['job']:<20} failed: {r['error']}")
            continue
        print(f"{r['job']:<20} {r['points_out']:>12,} {r['seconds']:>8.1f} {r['peak_rss_gib']:>9.2f} "
              f"{r['compact_bytes'] / 1e6:>11.1f} {r.get('samples', 0):>14,}")
    save("bench_dense", {"machine": machine(), "inputs": {"scene": args.scene, "spacing": args.spacing,
                                                          "jobs": {r['job']: JOBS[r['job']] for r in rows}},
                         "rows": rows})


if __name__ == "__main__":
    main()
