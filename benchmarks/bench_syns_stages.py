"""Where a prepared SYNS (0.036 deg) binning scan spends its time, stage by stage.

    python benchmarks/bench_syns_stages.py [--resolution 0.029] [--threads 2] [--rounds 9]

On the 29 M-point benchmark cloud (``--resolution 0.055``: the 8 M one), from
14 m away, the stages of what ``BinningScanner.scan`` runs on reused tables:
``reset`` (clearing the last scan's bins), ``add`` (keys and the per-pulse
minimum in the threads' own slot tables), ``read-out`` (the bins two tables
hold: which record loses), ``order`` (the winners in index order into pooled
arrays). Wall and CPU seconds, medians of the rounds after two warm-up rounds.
Saves results/bench_syns_stages.json (``_<resolution>_<threads>threads`` for
other settings).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, realistic_cloud, save  # noqa: E402

import slr_ray  # noqa: E402
from slr_ray.core import BinTables  # noqa: E402
from slr_ray.core.order import OutputPool  # noqa: E402

ORIGIN = np.array([12.3, -7.1, 0.0])
STAGES = ("reset", "add", "read-out", "order")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=float, default=0.029, help="primary scan resolution of the cloud")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=9)
    args = ap.parse_args(argv)
    pts = realistic_cloud(args.resolution)
    float(np.asarray(pts[:, 2]).sum())  # the mapped cloud read once before any timing
    tables = BinTables(ORIGIN, slr_ray.preset("syns"), n_threads=args.threads)
    pool = OutputPool()
    times = {k: [] for k in (*STAGES, "total")}
    for i in range(args.rounds + 2):
        c, w = [time.process_time()], [time.perf_counter()]
        for step in (lambda: tables.reset(ORIGIN), lambda: tables.add(pts, finite=True),
                     lambda: tables.n_bins, lambda: tables.winners(pts, as_pulses=True, pool=pool)):
            out = step()
            c.append(time.process_time())
            w.append(time.perf_counter())
        del out
        if i < 2:
            continue
        for j, k in enumerate(STAGES):
            times[k].append((w[j + 1] - w[j], c[j + 1] - c[j]))
        times["total"].append((w[-1] - w[0], c[-1] - c[0]))
    rows = [{"stage": k, "median_wall_seconds": float(np.median([t[0] for t in v])),
             "median_cpu_seconds": float(np.median([t[1] for t in v])), "all": v} for k, v in times.items()]
    print(f"{len(pts):,} points, {args.threads} threads, {tables.kind} tables, load {os.getloadavg()[0]:.2f}")
    for r in rows:
        print(f"{r['stage']:<9} wall {r['median_wall_seconds']:.3f} s  cpu {r['median_cpu_seconds']:.3f} s")
    name = "bench_syns_stages"
    if args.resolution != 0.029 or args.threads != 2:
        name += f"_{args.resolution}_{args.threads}threads"
    save(name, {"machine": machine(), "inputs": {"points": len(pts), "resolution": args.resolution,
                                                "threads": args.threads, "rounds": args.rounds,
                                                "origin": ORIGIN.tolist()}, "rows": rows})


if __name__ == "__main__":
    main()
