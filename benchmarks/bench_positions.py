"""Candidate cells of the paper's scenes, and the speed of the grid method.

    python benchmarks/bench_positions.py [--scenes ground-only,rect-0500,rect-1000,rect-2000]
                                         [--semantics dense] [--skip-counts] [--skip-speed]

Counts: each scene's primary scan from the origin at 0.0144 deg (the paper's
validation primary; by default the paper's own semantics, the 5 mm dense grid
streamed through binning), then candidate_cells with the paper's thresholds
(2 m cells, 50,000 ground points within 5 m), labels from the scene. The
azimuth test is left out: the paper's profile came from a dataset we do not
have. Paper: 963 / 763 / 730 / 574 candidates for 0 / 500 / 1000 / 2000
rectangles.

Speed: candidate_cells on the 29 M-point realistic cloud of bench_binning
(ground = the points on z = -1.65).

Prints tables; saves results/bench_positions.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, realistic_cloud, save  # noqa: E402

from slr_ray import ScanPattern, candidate_cells, scan_mesh  # noqa: E402
from slr_ray.scenes import scene_from_spec  # noqa: E402

PAPER = {"ground-only": 963, "rect-0500": 763, "rect-1000": 730, "rect-2000": 574}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="ground-only,rect-0500,rect-1000,rect-2000")
    ap.add_argument("--semantics", default="dense", choices=["dense", "center"])
    ap.add_argument("--resolution", type=float, default=0.0144)
    ap.add_argument("--skip-counts", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    args = ap.parse_args(argv)
    counts, speed = [], {}
    if not args.skip_counts:
        for name in args.scenes.split(","):
            scene = scene_from_spec(name)
            t0 = time.perf_counter()
            ms = scan_mesh(scene, [0, 0, 0], ScanPattern(args.resolution), mode=args.semantics)
            t_scan = time.perf_counter() - t0
            cells = candidate_cells(ms.points, ms.labels == 0)
            counts.append({"scene": name, "primary_points": len(ms), "ground_points": int((ms.labels == 0).sum()),
                           "candidates": len(cells), "paper": PAPER.get(name), "stages": cells.stages,
                           "scan_seconds": t_scan, "cells_seconds": cells.seconds})
            print(f"{name}: {len(ms):,} points, {len(cells)} candidates (paper {PAPER.get(name)}), "
                  f"scan {t_scan:.0f} s, cells {cells.seconds:.1f} s", file=sys.stderr, flush=True)
            del ms
        print(f"\n{'scene':<12} {'primary pts':>12} {'candidates':>10} {'paper':>6}")
        for c in counts:
            print(f"{c['scene']:<12} {c['primary_points']:>12,} {c['candidates']:>10} {c['paper']:>6}")
    if not args.skip_speed:
        pts = realistic_cloud()
        g = np.abs(pts[:, 2] + 1.65) < 1e-6
        t0 = time.perf_counter()
        cells = candidate_cells(pts, g)
        speed = {"points": len(pts), "ground_points": int(g.sum()), "seconds": time.perf_counter() - t0,
                 "candidates": len(cells), "stages": cells.stages}
        print(f"\ncandidate_cells on {len(pts):,} points ({int(g.sum()):,} ground): "
              f"{speed['seconds']:.1f} s, {len(cells)} candidates")
    save("bench_positions", {"machine": machine(), "inputs": {"resolution": args.resolution,
                                                              "semantics": args.semantics},
                             "counts": counts, "speed": speed})


if __name__ == "__main__":
    main()
