"""The figures behind evaluate's and fit-drop's checks of a frame (issue #40), on KITTI's frames.

    python benchmarks/scan_checks.py [--pairs]

For each KITTI frame under ../shared/data: the rings its scan order gives, the
median azimuth step within a ring and the median spread of a ring's
elevations (median absolute deviation), for the frame as stored, shuffled,
with a ring field of random integers, and for a random cloud of as many
points (what fit-drop and evaluate refuse). With ``--pairs``, the inlier RMSE
and fitness of registering consecutive frames (evaluate's gates). Prints one
line each and saves results/scan_checks.json.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

from slr_ray.effects import rings_from_scan_order  # noqa: E402
from slr_ray.evaluate import register  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def ring_stats(p, rings):
    r = np.linalg.norm(p, axis=1)
    el = np.degrees(np.arcsin(p[:, 2] / np.maximum(r, 1e-12)))
    phi = np.degrees(np.unwrap(np.arctan2(p[:, 1], p[:, 0])))
    same = rings[1:] == rings[:-1]
    steps = np.abs(np.diff(phi)[same])
    ids, counts = np.unique(rings, return_counts=True)
    order = np.argsort(rings, kind="stable")
    spread = [np.median(np.abs(e - np.median(e))) for e in np.split(el[order], np.cumsum(counts)[:-1])]
    return {"rings": int(len(ids)), "median_step_deg": float(np.median(steps[steps > 0])),
            "median_ring_spread_deg": float(np.median(spread))}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", action="store_true", help="also register consecutive frames")
    args = ap.parse_args()
    frames = sorted(DATA.glob("kitti_hdl64_*.bin"))
    if not frames:
        sys.exit(f"no KITTI frames under {DATA}")
    rng = np.random.default_rng(0)
    out = {"machine": machine(), "frames": {}, "pairs": {}}
    clouds = []
    for f in frames:
        p = np.fromfile(f, np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
        clouds.append(p)
        rows = {"stored": ring_stats(p, rings_from_scan_order(p))}
        q = p[rng.permutation(len(p))]
        rows["shuffled"] = ring_stats(q, rings_from_scan_order(q))
        rows["random ring field"] = ring_stats(p, rng.integers(0, 64, len(p)))
        c = rng.uniform(-40, 40, p.shape)
        rows["random cloud"] = ring_stats(c, rings_from_scan_order(c))
        out["frames"][f.name] = rows
        for k, v in rows.items():
            print(f"{f.name} {k:18s} rings {v['rings']:6d}  step {v['median_step_deg']:7.3f} deg  "
                  f"spread {v['median_ring_spread_deg']:6.3f} deg")
    if args.pairs:
        for i in range(len(clouds) - 1):
            reg = register(clouds[i + 1], clouds[i])
            out["pairs"][f"{frames[i].name}->{frames[i + 1].name}"] = {
                "fitness": reg.fitness, "inlier_rmse_m": reg.inlier_rmse,
                "translation_m": float(np.linalg.norm(reg.transform[:3, 3]))}
            print(f"{frames[i].name} -> {frames[i + 1].name}: fitness {reg.fitness:.3f}, inlier RMSE "
                  f"{reg.inlier_rmse:.4f} m, {np.linalg.norm(reg.transform[:3, 3]):.3f} m")
    save("scan_checks", out)


if __name__ == "__main__":
    main()
