"""Neighbour search for the disc radii and normals: kd-trees against the pulse grid.

    python benchmarks/bench_knn.py [--points 5000000] [--repeat 2]

On the first N points of the 29 M-point benchmark cloud (a primary scan from
(0, 0, 0) at 0.029 deg, stored row by row), the k = 6 nearest neighbours of
every point (k + 1 with itself) by scipy's cKDTree (the embree backend's kNN,
all cores) and, when it is installed, by pykdtree (a candidate dependency,
OpenMP on all cores; not required by slr_ray), beside the pulse grid's one
pass that computes spacing and normals together
(``slr_ray.backends.embree.pulse_grid_spacing_normals``). Times are the best
of ``--repeat``; kd-tree times are build + query of all points, without the
PCA the backend runs after them. Saves results/bench_knn.json.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, realistic_cloud, save, timed  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=5_000_000)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--k", type=int, default=6)
    args = ap.parse_args(argv)

    from scipy.spatial import cKDTree

    from slr_ray.backends.embree import pulse_grid_spacing_normals

    pts = np.ascontiguousarray(realistic_cloud()[:args.points], np.float64)
    centred = pts - 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    k = args.k + 1
    rows = []

    def ckdtree():
        tree = cKDTree(centred, balanced_tree=False, compact_nodes=False)
        return tree.query(centred, k=k, workers=-1)

    sec, _, (d_ref, _) = timed(ckdtree, args.repeat)
    rows.append({"method": "scipy cKDTree, build + query", "seconds": sec})
    try:
        from pykdtree.kdtree import KDTree
    except ImportError:
        rows.append({"method": "pykdtree, build + query", "error": "not installed (pip install pykdtree)"})
    else:
        sec, _, (d, _) = timed(lambda: KDTree(centred, leafsize=16).query(centred, k=k), args.repeat)
        rows.append({"method": "pykdtree, build + query", "seconds": sec,
                     "same_distances": bool(np.allclose(d, d_ref, rtol=0, atol=1e-9))})
    pulse_grid_spacing_normals(pts[:2000], [0, 0, 0], 0.029)  # compile outside the timing
    sec, _, _ = timed(lambda: pulse_grid_spacing_normals(pts, [0, 0, 0], 0.029, dtype=np.float32), args.repeat)
    rows.append({"method": "pulse grid: spacing and normals in one pass", "seconds": sec})
    for r in rows:
        print(f"{r['method']:<46} " + (f"{r['seconds']:7.2f} s" if "seconds" in r else r["error"]))
    save("bench_knn", {"machine": machine(), "inputs": {**vars(args), "cloud": "first N points of the 29 M-point "
                                                         "rect-1000 scan (benchmarks/common.py)"}, "rows": rows})


if __name__ == "__main__":
    main()
