"""Augment a 1 M-point real scan to 20 positions: serial vs 2 local worker
processes vs a 2-process Dask LocalCluster (the same outputs each time).

    python benchmarks/bench_augment.py [--input ../shared/data/forest_tls_riegl.laz] [--n 20]

Ground labels by CSF, computed once outside the timings. Prints a table;
saves results/bench_augment.json.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "forest_tls_riegl.laz"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", default=str(DEFAULT))
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--min-ground-points", type=int, default=2000)
    args = ap.parse_args(argv)

    from slr_ray.augment import AugmentConfig, augment
    from slr_ray.io import read_cloud
    from slr_ray.positions import label_ground

    t0 = time.perf_counter()
    ground = label_ground(read_cloud(args.input).points)
    t_csf = time.perf_counter() - t0
    rows = []
    tmp = Path(tempfile.mkdtemp(dir=Path(__file__).resolve().parent / "results"))
    try:
        config = AugmentConfig(n=args.n, min_ground_points=args.min_ground_points)
        for name, kw in (("serial", {"workers": 1}), ("2 local processes", {"workers": 2})):
            t0 = time.perf_counter()
            m = augment(args.input, tmp / name.replace(" ", "_"), config.with_(**kw), ground=ground, progress=False)
            rows.append({"mode": name, "seconds": time.perf_counter() - t0, "scans": len(m["scans"]),
                         "points_out": sum(s["points"] for s in m["scans"])})
        from dask.distributed import LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
            t0 = time.perf_counter()
            m = augment(args.input, tmp / "dask", config.with_(scheduler=cl.scheduler_address), ground=ground,
                        progress=False)
            rows.append({"mode": "dask LocalCluster, 2 processes", "seconds": time.perf_counter() - t0,
                         "scans": len(m["scans"]), "points_out": sum(s["points"] for s in m["scans"])})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"input {args.input}: CSF {t_csf:.1f} s")
    print(f"{'mode':<32} {'seconds':>8} {'scans':>6} {'points out':>12}")
    for r in rows:
        print(f"{r['mode']:<32} {r['seconds']:>8.1f} {r['scans']:>6} {r['points_out']:>12,}")
    save("bench_augment", {"machine": machine(), "inputs": {"input": args.input, "n": args.n,
                                                            "csf_seconds": t_csf}, "rows": rows})


if __name__ == "__main__":
    main()
