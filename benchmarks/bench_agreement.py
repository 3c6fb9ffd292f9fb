"""Coverage and precision of a validation pair: the cell grid against two kd-trees.

    python benchmarks/bench_agreement.py [--positions 5]

Each pair is what the validation compares 1,300 times: the pulse-centre true
scan of rect-1000 at a 0.144 deg secondary position (about 2 M points) and an
SLR-like scan, here the true scan from 30 cm away (a similar cloud, not the
same points). For each pair, ``slr_ray.agreement`` (a CellGrid of cells of
10 cm: no tree, an early exit at the first match) and the same two shares by
scipy's cKDTree (bounded nearest-neighbour queries, all cores), which
``agreement`` used before. The answers must be identical. Prints a table and
saves results/bench_agreement.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

from slr_ray import ScanPattern, agreement, scan_mesh  # noqa: E402
from slr_ray.scenes import scene_from_spec  # noqa: E402
from slr_ray.similarity import nearest_distances  # noqa: E402


def kdtree_shares(true, slr, threshold=0.1):
    cov = float(np.mean(nearest_distances(true, slr, upper_bound=threshold) < threshold))
    prec = float(np.mean(nearest_distances(slr, true, upper_bound=threshold) < threshold))
    return cov, prec


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--positions", type=int, default=5)
    args = ap.parse_args()
    scene = scene_from_spec("rect-1000")
    pattern = ScanPattern(0.144)
    rng = np.random.default_rng(0)
    agreement(np.zeros((10, 3)), np.ones((10, 3)))  # compile outside the timing
    rows = []
    for i in range(args.positions):
        r, a = rng.uniform(2, 30), rng.uniform(0, 2 * np.pi)
        pos = np.array([r * np.cos(a), r * np.sin(a), 0.0])
        true = scan_mesh(scene, pos, pattern).points
        slr = scan_mesh(scene, pos + [0.3, 0.0, 0.0], pattern).points
        t0 = time.perf_counter()
        got = agreement(true, slr)
        t_grid = time.perf_counter() - t0
        t0 = time.perf_counter()
        cov, prec = kdtree_shares(true, slr)
        t_tree = time.perf_counter() - t0
        same = (got.coverage, got.precision) == (cov, prec)
        rows.append({"position": pos.tolist(), "true_points": len(true), "slr_points": len(slr),
                     "coverage": got.coverage, "precision": got.precision, "grid_seconds": t_grid,
                     "kdtree_seconds": t_tree, "speedup": t_tree / t_grid, "identical": same})
        print(f"{len(true):>9,} {len(slr):>9,}  coverage {got.coverage:.4f} precision {got.precision:.4f}  "
              f"grid {t_grid:.3f} s  kd-trees {t_tree:.3f} s  {t_tree / t_grid:.1f}x  identical {same}")
        if not same:
            raise SystemExit("the cell grid and the kd-trees disagree")
    total = {"grid_seconds": sum(r["grid_seconds"] for r in rows),
             "kdtree_seconds": sum(r["kdtree_seconds"] for r in rows)}
    total["speedup"] = total["kdtree_seconds"] / total["grid_seconds"]
    print(f"total: grid {total['grid_seconds']:.2f} s, kd-trees {total['kdtree_seconds']:.2f} s, "
          f"{total['speedup']:.1f}x")
    save("bench_agreement", {"machine": machine(), "inputs": {"scene": "rect-1000", "secondary": 0.144,
                                                              "positions": args.positions, "threshold": 0.1},
                             "rows": rows, "total": total})


if __name__ == "__main__":
    main()
