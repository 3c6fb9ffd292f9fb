"""The fit-quality gate of ``primary_pattern='fit'`` (issue #38): real scans pass, clouds that are no
scan from the origin fail.

    PYTHONPATH=. nice python benchmarks/bench_fit_gate.py [--data ../shared/data]

For each cloud, the pattern ``fit_primary_pattern`` fits from its origin and the fit's quality (the
share of the fitted grid's occupied pulses that hold exactly one point,
``slr_ray.backends.embree.fit.fit_quality``; the gate is ``FIT_MIN_SINGLE``): the KITTI frames (beam
table by scan order; shuffled, a uniform grid), the forest LAZ and the pump E57 from their origins,
and clouds that are no scan from the origin: 100,000 uniform random points (a cube, a spherical
shell), the forest seen from 1 m aside, the forest merged with a copy of itself 10 m aside, the forest
thinned to one point a 5 cm voxel, and an airborne tile seen from 50 m above its centre. Saves
results/bench_fit_gate.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save  # noqa: E402

from slr_ray.backends.embree import fit  # noqa: E402
from slr_ray.io import read_cloud  # noqa: E402


def _quality(p):
    """(pattern, quality) of the fit to ``p`` seen from 0, the gate aside."""
    return fit.fit_primary_pattern(p, np.zeros(3), min_quality=0.0)  # every cloud, those the gate refuses too


def clouds(data: Path):
    rng = np.random.default_rng(1)
    for i in range(4):
        c = read_cloud(data / f"kitti_hdl64_00000{i}.bin")
        yield f"kitti_hdl64_00000{i}.bin", True, np.asarray(c.points, np.float64)
    c = np.asarray(read_cloud(data / "kitti_hdl64_000000.bin").points, np.float64)
    yield "kitti_hdl64_000000.bin shuffled (uniform fit)", True, c[rng.permutation(len(c))]
    forest = np.asarray(read_cloud(data / "forest_tls_riegl.laz").points, np.float64)
    yield "forest_tls_riegl.laz", True, forest
    yield "pump_tls.e57", True, np.asarray(read_cloud(data / "pump_tls.e57").points, np.float64)
    yield "random: 100,000 in a 20 m cube", False, rng.uniform(-10, 10, (100_000, 3))
    d = rng.normal(size=(100_000, 3))
    yield "random: 100,000 in a shell 5-20 m", False, d / np.linalg.norm(d, axis=1)[:, None] * rng.uniform(
        5, 20, (100_000, 1))
    yield "forest seen from 1 m aside", False, forest - [1.0, 0.0, 0.0]
    yield "forest merged with its copy 10 m aside", False, np.concatenate([forest, forest + [10.0, 0.0, 0.0]])
    keep = np.unique(np.floor(forest / 0.05).astype(np.int64), axis=0, return_index=True)[1]
    yield "forest thinned to one point a 5 cm voxel", False, forest[np.sort(keep)]
    als = np.asarray(read_cloud(data / "autzen_als_classified.las").points, np.float64)
    yield "airborne tile seen from 50 m above its centre", False, als - (als.mean(axis=0) + [0.0, 0.0, 50.0])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    args = ap.parse_args(argv)
    rows = []
    print(f"gate: quality >= {fit.FIT_MIN_SINGLE}")
    print("| cloud | a scan from the origin | points | fitted | quality | passes |")
    print("|---|---|---|---|---|---|")
    for name, scan, p in clouds(args.data):
        t0 = time.perf_counter()
        pattern, how, q = _quality(p)
        seconds = time.perf_counter() - t0
        fitted = (how.split(";")[0] if getattr(pattern, "has_beams", False)
                  else f"{pattern.zenith_resolution:.4g} x {pattern.azimuth_resolution:.4g} deg")
        row = {"cloud": name, "scan": scan, "points": len(p), "fitted": fitted, "quality": q,
               "passes": q >= fit.FIT_MIN_SINGLE, "seconds": seconds}
        rows.append(row)
        print(f"| {name} | {'yes' if scan else 'no'} | {len(p):,} | {fitted} | {q:.3f} | "
              f"{'yes' if row['passes'] else 'no'} |", flush=True)
    ok = all(r["passes"] == r["scan"] for r in rows)
    print(f"every scan passes and every other cloud fails: {ok}")
    save("bench_fit_gate", {"machine": machine(), "gate": fit.FIT_MIN_SINGLE, "rows": rows, "separates": ok})


if __name__ == "__main__":
    main()
