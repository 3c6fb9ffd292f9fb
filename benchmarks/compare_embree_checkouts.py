"""Embree pulse-grid prepare and cast of this checkout against another's, alternated in fresh processes.

    python benchmarks/compare_embree_checkouts.py OTHER_CHECKOUT [--resolution 0.029] [--pairs 3]

The benchmark cloud (``common.realistic_cloud``: rect-1000 scanned from the origin at
``--resolution``, zenith 0-135, 120 m; 29 M points at 0.029 deg) is made once and cached. Each pair
runs one process of ``OTHER_CHECKOUT`` (e.g. ``git worktree add /tmp/main main``) and one of this
checkout, in turn (after one uncounted pair that fills numba's caches): ``prepare(cloud, "embree",
primary_origin=0, primary_resolution=RES)`` (the pulse-grid default), then two 0.144 deg scans from
(12.3, -7.1, 0) (the second timed). Reports medians of prepare and cast seconds, peak RSS above the
loaded cloud, and the ratios this / other; also the CPU seconds of each (all threads: steadier than
wall seconds on a shared machine). Saves results/compare_embree_checkouts.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
# wall seconds move with the load on a shared machine; the process's CPU seconds (all threads) much less
METRICS = ("prepare_s", "cast_s", "prepare_cpu_s", "cast_cpu_s", "peak_above_cloud_gib")


def measure(resolution: float) -> dict:
    import resource

    import numpy as np

    import slr_ray  # before common, which puts this checkout's root on sys.path

    from common import realistic_cloud

    pts = np.ascontiguousarray(realistic_cloud(resolution))
    grid = {"primary_origin": [0.0, 0.0, 0.0], "primary_resolution": resolution}
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # the cloud loaded
    t0, c0 = time.perf_counter(), time.process_time()
    sc = slr_ray.prepare(pts, "embree", **grid)
    prep, prep_cpu = time.perf_counter() - t0, time.process_time() - c0
    sc.scan([12.3, -7.1, 0.0], 0.144)
    t0, c0 = time.perf_counter(), time.process_time()
    s = sc.scan([12.3, -7.1, 0.0], 0.144)
    cast, cast_cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return {"checkout": str(Path(slr_ray.__file__).resolve().parents[1]), "points": len(pts),
            "prepare_s": prep, "cast_s": cast, "prepare_cpu_s": prep_cpu, "cast_cpu_s": cast_cpu,
            "peak_above_cloud_gib": peak - base, "points_out": len(s)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", nargs="?")
    ap.add_argument("--resolution", type=float, default=0.029)
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    if args.measure:
        print(json.dumps(measure(args.resolution)))
        return
    from common import machine, save

    # made and cached once, in a process of its own: a child forked from a parent that made it would
    # start from the parent's peak RSS (Linux keeps the high-water mark across fork and exec), and
    # its peak above the cloud read 0
    subprocess.run([sys.executable, "-c", f"import sys; sys.path.insert(0, {str(HERE)!r}); "
                    f"from common import realistic_cloud; realistic_cloud({args.resolution!r})"], check=True)
    runs = {"other": [], "this": []}
    for i in range(args.pairs + 1):  # the first pair fills numba's caches (compiles): not counted
        for label, root in (("other", Path(args.other).resolve()), ("this", HERE.parent)):
            env = {**os.environ, "PYTHONPATH": str(root)}
            res = subprocess.run([sys.executable, __file__, "--measure", "--resolution", str(args.resolution)],
                                 capture_output=True, text=True, env=env, cwd=str(root))
            if res.returncode:
                raise SystemExit(res.stderr[-3000:])
            row = json.loads(res.stdout.strip().splitlines()[-1])
            print(label, row, "(warm-up)" if i == 0 else "", flush=True)
            if i:
                runs[label].append(row)
    med = {k: {m: statistics.median(r[m] for r in v) for m in METRICS}
           for k, v in runs.items()}
    ratio = {m: med["this"][m] / med["other"][m] if med["other"][m] else None for m in med["this"]}
    print(json.dumps({"median": med, "this_over_other": ratio}))
    save("compare_embree_checkouts", {"machine": machine(), "inputs": vars(args), "runs": runs, "median": med,
                                      "this_over_other": ratio})


if __name__ == "__main__":
    main()
