"""Embree's compact BVH against its default for the disc scenes of large primaries.

    python benchmarks/bench_compact_bvh.py [--cloud results/primary_rect-1000_0.0144_dense.npy]
                                           [--resolution 0.0144] [--points N]

Footprint discs facing the primary (no neighbour search) on a cached dense
primary (bench_embree_primary.py makes it), built with and without
``RTC_SCENE_FLAG_COMPACT``, each in its own process: build seconds, the cast
of one 0.144 deg pattern from 14 m (3.1 M rays), rays hit (they must be
equal) and peak RSS. Saves results/bench_compact_bvh.json.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, run_isolated, save  # noqa: E402


def run(cloud, res, n, compact):
    from slr_ray import ScanPattern
    from slr_ray.backends.embree import disc_radii
    from slr_ray.backends.embree.discs import fallback_directions as _fallback_directions
    from slr_ray.pattern import pulse_rays
    from slr_ray.raycast import RayScene

    pts = np.asarray(np.load(cloud, mmap_mode="r")[:n])
    r = disc_radii(pts, "footprint", primary_origin=[0, 0, 0], primary_resolution=res)
    nrm = _fallback_directions(pts, [0, 0, 0], np.float32)
    dirs, _, _ = pulse_rays(ScanPattern(0.144))
    t0 = time.perf_counter()
    scene = RayScene.discs(pts, r, nrm, compact=compact)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    hits = scene.intersect(np.array([12.3, -7.1, 0.0]), dirs)
    cast = time.perf_counter() - t0
    print(json.dumps({"compact": compact, "points": len(pts), "build_seconds": build, "cast_seconds": cast,
                      "rays_hit": int((hits.owners >= 0).sum()),
                      "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cloud", type=Path, default=RESULTS / "primary_rect-1000_0.0144_dense.npy")
    ap.add_argument("--resolution", type=float, default=0.0144)
    ap.add_argument("--points", type=int, default=None)
    ap.add_argument("--compact", choices=["0", "1"], help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.compact is not None:
        return run(args.cloud, args.resolution, args.points, args.compact == "1")
    if not args.cloud.exists():
        sys.exit(f"{args.cloud} is missing: run benchmarks/bench_embree_primary.py first")
    extra = ["--cloud", str(args.cloud), "--resolution", str(args.resolution)] + (
        ["--points", str(args.points)] if args.points else [])
    rows = [run_isolated(__file__, extra + ["--compact", c], "compact", c) for c in ("0", "1")]
    for r in rows:
        print(r)
    save("bench_compact_bvh", {"machine": machine(), "inputs": {k: str(v) for k, v in vars(args).items()},
                               "rows": rows})


if __name__ == "__main__":
    main()
