"""CSF's cloth resolution on an airborne tile: time and agreement with its own ground class.

    python benchmarks/bench_cloth.py [--runs 1] [--resolutions 0.5 2.4]

``label_ground``'s default cloth is 0.5 m, sized for a terrestrial scan. An
airborne tile (``autzen_als_classified.las``: 110,000 points, 1.2 km wide,
LAS class 2 = ground, 26,107 points) has ~1.2 m between neighbours, and a
0.5 m cloth is ~11 times the nodes a 2 m cloth has. For each resolution this
times CSF (in its own interpreter, as ``ground_labels`` runs it) and scores
its labels against class 2: precision, recall, and the points where they
disagree. It also prints the median xy spacing of each cloud (a rule such as
``max(0.5, 2 x spacing)`` would read it). Prints a table and saves
results/bench_cloth.json.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

from slr_ray.io import read_cloud  # noqa: E402
from slr_ray.positions import label_ground  # noqa: E402

DATA = Path("/work/shared/data")


def spacing(points, sample: int = 20_000, seed: int = 0) -> float:
    """Median distance in xy from a point to its nearest neighbour (a sample of points)."""
    xy = points[:, :2]
    at = np.random.default_rng(seed).choice(len(xy), min(sample, len(xy)), replace=False)
    d, _ = cKDTree(xy).query(xy[at], k=2)
    return float(np.median(d[:, 1]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--resolutions", type=float, nargs="+", default=[0.5, 2.4])
    ap.add_argument("--input", default=str(DATA / "autzen_als_classified.las"))
    args = ap.parse_args()
    cloud = read_cloud(args.input)
    pts, truth = cloud.points, np.asarray(cloud.attributes["classification"]) == 2
    res = {"input": args.input, "points": len(pts), "ground_class_2": int(truth.sum()),
           "spacing_xy_median": {name: round(spacing(read_cloud(DATA / name).points), 4)
                                 for name in ("autzen_als_classified.las", "forest_tls_riegl.laz",
                                              "csf_als_sample.ply") if (DATA / name).exists()},
           "rows": []}
    for r in args.resolutions:
        times = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            g = label_ground(pts, cloth_resolution=r)
            times.append(time.perf_counter() - t0)
        tp = int(np.count_nonzero(g & truth))
        row = {"cloth_resolution": r, "seconds_median": round(statistics.median(times), 2),
               "seconds": [round(t, 2) for t in times], "ground": int(g.sum()),
               "precision": round(tp / max(1, int(g.sum())), 4), "recall": round(tp / max(1, int(truth.sum())), 4),
               "disagree": int(np.count_nonzero(g != truth))}
        res["rows"].append(row)
        print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    res["load_average_1_5_15"] = [round(x, 1) for x in os.getloadavg()]
    res["machine"] = machine()
    print("spacing_xy_median", res["spacing_xy_median"])
    save("bench_cloth", res)


if __name__ == "__main__":
    main()
