"""How much of a dense-grid primary scan lies behind surfaces (see-through).

    python benchmarks/primary_see_through.py [--scene rect-1000] [--resolutions 0.0144,0.00576]
        [--spacing 0.005] [--sample 2000000]

The paper's primary scan keeps the nearest sample of its 5 mm dense grid in
each pulse. Where a pulse is narrower than the grid (0.00576 deg is 5 mm wide
at 50 m, 2.5 mm at 25 m), many pulses through a surface hold no sample of it
and keep a sample of what lies behind: the primary sees through objects. For
each primary this casts a ray from the scanner to a random sample of its
points on the scene's mesh and counts those hidden behind another surface,
overall and per range band. Prints a table; saves results/primary_see_through.json
(``--mode center``: the ray-cast primaries of benchmarks/fair_q3.py, which
should have none; ``--zenith-range`` limits the rows for the largest ones).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

from slr_ray import ScanPattern, scan_mesh  # noqa: E402
from slr_ray.scenes import scene_from_spec  # noqa: E402
from slr_ray.validation import hidden_from  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="rect-1000")
    ap.add_argument("--resolutions", default="0.0144,0.00576")
    ap.add_argument("--spacing", type=float, default=0.005)
    ap.add_argument("--sample", type=int, default=2_000_000)
    ap.add_argument("--mode", default="dense", choices=["dense", "center"],
                    help="dense: the paper's 5 mm grid; center: ray cast through pulse centres (fair_q3.py)")
    ap.add_argument("--zenith-range", nargs=2, type=float, default=(0.0, 180.0),
                    help="only these zenith rows (a ray-cast 0.00576 deg primary has 1.2e9 points)")
    ap.add_argument("--name", default="primary_see_through", help="results/<name>.json")
    args = ap.parse_args(argv)
    scene = scene_from_spec(args.scene)
    edges = (0, 10, 20, 30, 50, 100, np.inf)
    out = []
    for res in map(float, args.resolutions.split(",")):
        t0 = time.perf_counter()
        primary = scan_mesh(scene, [0, 0, 0], ScanPattern(res, zenith_range=tuple(args.zenith_range)),
                            mode=args.mode, spacing=args.spacing)
        n = len(primary)
        pick = np.sort(np.random.default_rng(0).choice(n, size=min(args.sample, n), replace=False))
        p = primary.points[pick]
        del primary
        d = np.linalg.norm(p, axis=1)
        hidden = hidden_from(scene, p)
        row = {"resolution": res, "mode": args.mode, "zenith_range": list(args.zenith_range), "points": n, "sampled": len(p), "hidden_share": float(hidden.mean()),
               "by_range": {}, "seconds": round(time.perf_counter() - t0, 1)}
        for lo, hi in zip(edges[:-1], edges[1:]):
            m = (d >= lo) & (d < hi)
            row["by_range"][f"{lo:g}-{hi:g}"] = {"share_of_points": float(m.mean()),
                                                 "hidden_share": float(hidden[m].mean()) if m.any() else None}
        out.append(row)
        bands = "  ".join(f"{k} m: {100 * v['hidden_share']:.1f} %" for k, v in row["by_range"].items()
                          if v["hidden_share"] is not None)
        print(f"{args.scene} {res:g} deg: {n:,} points, {100 * row['hidden_share']:.1f} % behind a surface  ({bands})",
              flush=True)
    save(args.name, {"inputs": vars(args), "machine": machine(), "rows": out})


if __name__ == "__main__":
    main()
