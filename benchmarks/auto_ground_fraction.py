"""Where ``min_ground_points="auto"``'s fraction comes from (docs/positions.md, AUTO_GROUND_FRACTION):
the demo's scene (200 rectangles, seed 0) scanned from its centre (120 m) at 0.3 and 0.2 deg; the
most ground points any 2 m cell has within 5 m of its centre (``candidate_cells``' counts), against the
paper's 50,000 scaled by the pulse density as the demo scales it, ``50,000 x (0.036 / resolution)^2``.

    python benchmarks/auto_ground_fraction.py [--resolutions 0.3 0.2]

Prints and saves results/auto_ground_fraction.json.
"""

from __future__ import annotations

import argparse

import numpy as np
from common import machine, save  # puts this checkout first on the path

from slr_ray import ScanPattern, paper
from slr_ray.meshscan import scan_mesh
from slr_ray.positions import AUTO_GROUND_FRACTION, candidate_cells
from slr_ray.scenes import rectangle_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolutions", type=float, nargs="+", default=[0.3, 0.2])
    args = ap.parse_args()
    scene = rectangle_scene(200, seed=0)
    rows = []
    for res in args.resolutions:
        scan = scan_mesh(scene, np.zeros(3), ScanPattern(res, max_range=120.0))
        cells = candidate_cells(scan.points, scan.labels == 0, min_ground_points=0, profile=None)
        best = int(cells.ground_counts.max())
        paper_scaled = paper.MIN_GROUND_POINTS * (paper.SYNS_RESOLUTION / res) ** 2
        rows.append({"resolution_deg": res, "points": len(scan), "best_cell_ground_points": best,
                     "paper_threshold_scaled": paper_scaled, "fraction": paper_scaled / best})
        print(f"{res} deg: {len(scan):,} points, best cell {best:,} ground points, the paper's threshold scaled "
              f"{paper_scaled:,.0f}: fraction {paper_scaled / best:.6f} ({100 * paper_scaled / best:.4f} %)")
    print(f"shipped AUTO_GROUND_FRACTION {AUTO_GROUND_FRACTION} ({100 * AUTO_GROUND_FRACTION:.4f} %)")
    save("auto_ground_fraction", {"machine": machine(), "scene": {"n_rectangles": 200, "seed": 0, "origin": [0, 0, 0],
                                                                  "max_range_m": 120.0},
                                  "cell_size_m": 2.0, "ground_count_radius_m": 5.0, "rows": rows,
                                  "shipped_fraction": AUTO_GROUND_FRACTION})


if __name__ == "__main__":
    main()
