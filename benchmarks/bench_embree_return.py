"""How much of what binning returns the embree backend returns on sparse clouds,
and the cost of the neighbour query and PCA normals per million points.

    python benchmarks/bench_embree_return.py

Cases: 20,000 random points of an open plane scanned at 1 deg from 1.65 m above
it; a 0.5 deg scan of a 30 x 24 x 8 m room (3 mm range noise) re-scanned from
its own origin at 0.5, 1 and 2 deg; each with kNN discs (k = 6, the default
without a primary, and k = 12) and, for the room, pulse-grid discs (the
default when the primary's origin and resolution are given).
Prints a table and saves results/bench_embree_return.json.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, realistic_cloud, save  # noqa: E402

from slr_ray import ScanPattern, prepare, scan_mesh  # noqa: E402
from slr_ray.backends.embree import estimate_normals, neighbourhoods  # noqa: E402


def cases():
    import trimesh

    rng = np.random.default_rng(1)
    xy = rng.uniform(-20, 20, (20_000, 2))
    yield "random plane, 1 deg", np.column_stack([xy, np.full(len(xy), -1.65)]), np.zeros(3), 1.0, None
    o = np.array([1.0, -2.0, 0.5])
    room = scan_mesh(trimesh.creation.box(extents=[30, 24, 8]), o, ScanPattern(0.5)).points
    room = room + np.random.default_rng(0).normal(scale=0.003, size=room.shape)
    yield "room 0.5 deg scan, 0.5 deg", room, o, 0.5, 0.5
    yield "room 0.5 deg scan, 1 deg", room, o, 1.0, 0.5
    yield "room 0.5 deg scan, 2 deg", room, o, 2.0, 0.5


def main():
    rows = []
    for name, pts, origin, res, primary_res in cases():
        b = prepare(pts).scan(origin, ScanPattern(res))
        settings = [("knn k=6", {"k": 6}), ("knn k=12", {"k": 12})]
        if primary_res is not None:  # the cloud is a scan of known origin and resolution
            settings.append(("pulse-grid", {"neighbours": "pulse-grid", "primary_origin": origin,
                                            "primary_resolution": primary_res}))
        for label, opts in settings:
            e = prepare(pts, "embree", **opts).scan(origin, ScanPattern(res))
            rows.append({"case": name, "discs": label, "binning": len(b), "embree": len(e),
                         "ratio": len(e) / len(b)})
            print(f"{name:<28} {label:<11} binning {len(b):>7,} embree {len(e):>7,} ratio {len(e) / len(b):.3f}")
    pts = np.ascontiguousarray(realistic_cloud()[:1_000_000])
    estimate_normals(pts[:1000], k=6)  # compile outside the timing
    t0 = time.perf_counter()
    for _ in neighbourhoods(pts, 6):
        pass
    t_knn = time.perf_counter() - t0
    t0 = time.perf_counter()
    estimate_normals(pts, k=6)
    t_both = time.perf_counter() - t0
    timing = {"points": len(pts), "neighbour_query_seconds": t_knn,
              "normals_seconds_excluding_query": t_both - t_knn}
    print(f"1 M points of the 29 M cloud: neighbour query {t_knn:.2f} s, PCA normals {t_both - t_knn:.2f} s")
    save("bench_embree_return", {"machine": machine(), "rows": rows, "timing": timing})


if __name__ == "__main__":
    main()
