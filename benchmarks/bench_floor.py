"""How far the binning scans are from the floor, on the 29 M-point cloud.

    python benchmarks/bench_floor.py [--rounds 7] [--threads 2]

Times, in rounds taken in turn (medians; the machine may be shared, so read
the ratios of one run), with ``--threads`` threads, wall and CPU time of the
process (with ``--threads 1`` on a shared machine the CPU time is the
steadier figure: it does not count the time other jobs hold the core):

- **read**: one parallel pass summing the coordinates (0.7 GB of float64):
  the memory-bandwidth floor of anything that looks at every point;
- **angles**: the exact angle kernel alone (``slr_ray.core.grid.block_keys``:
  origin subtracted, both angles, range, the pulse key of every point, into
  the L1-resident block scratch, no reduction), 0.144 deg;
- **scans**: a prepared binning scanner's 0.144 deg scan, SYNS (0.036 deg),
  an HDL-64E S2 and a VLP-16 frame, from a position 14 m away;
- **SYNS stages**: ``BinTables.add`` (keys and the per-pulse minimum, fused),
  ``winners`` (folding the threads' tables, the winners in index order) into
  pooled output arrays, as a prepared scan does, and into fresh ones (the
  difference: faulting in 177 MB of new pages).

Saves results/bench_floor.json (bench_floor_<n>threads.json for other thread counts)
and draws docs/figures/floor.png from the saved one- and two-thread results
(``--figure-only`` draws it without measuring).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, realistic_cloud, save  # noqa: E402

import slr_ray  # noqa: E402
from slr_ray import ScanPattern, prepare  # noqa: E402
from slr_ray.core import BinTables  # noqa: E402
from slr_ray.core.grid import BLOCK, block_keys, kernel_params, scratch  # noqa: E402
from slr_ray.core.order import OutputPool  # noqa: E402

ORIGIN = np.array([12.3, -7.1, 0.0])


@njit(nogil=True, cache=True)
def _read(points, start, stop):
    s = 0.0
    for i in range(start, stop):
        s += points[i, 0] + points[i, 1] + points[i, 2]
    return s


@njit(nogil=True, cache=True, error_model="numpy")
def _angles(points, start, stop, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax):
    x, y, z, th, ph, keys, ranges = scratch()
    seen = 0
    for s in range(start, stop, BLOCK):
        e = min(stop, s + BLOCK)
        block_keys(points, s, e, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                   x, y, z, th, ph, keys, ranges)
        for i in range(e - s):
            seen += keys[i] >= 0
    return seen


def _split(fn, points, threads, *args):
    n = len(points)
    cuts = [n * i // threads for i in range(threads + 1)]
    with ThreadPoolExecutor(threads) as pool:
        return sum(pool.map(lambda i: fn(points, cuts[i], cuts[i + 1], *args), range(threads)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--resolution", type=float, default=0.029, help="primary scan resolution of the cloud")
    ap.add_argument("--figure-only", action="store_true", help="draw the figure from the saved results")
    args = ap.parse_args(argv)
    if args.figure_only:
        return _figure()
    T = args.threads
    pts = np.ascontiguousarray(realistic_cloud(args.resolution))
    scanner = prepare(pts, n_threads=T)
    syns = slr_ray.preset("syns")
    patterns = {"0.144": ScanPattern(0.144), "syns 0.036": syns,
                "hdl64e_s2": slr_ray.sensor("velodyne_hdl64e_s2"), "vlp16": slr_ray.sensor("velodyne_vlp16")}
    params = kernel_params(ORIGIN, patterns["0.144"])
    tables = BinTables(ORIGIN, syns, n_threads=T)

    pool = OutputPool()

    def syns_stages():
        t0 = time.perf_counter()
        tables.reset(ORIGIN)
        tables.add(pts, finite=True)
        t1 = time.perf_counter()
        tables.winners(pts, as_pulses=True, pool=pool)
        t2 = time.perf_counter()
        tables.winners(pts, as_pulses=True)
        return t1 - t0, t2 - t1, time.perf_counter() - t2

    jobs = {"read": lambda: _split(_read, pts, T), "angles": lambda: _split(_angles, pts, T, *params)}
    jobs |= {f"scan {k}": (lambda p=p: scanner.scan(ORIGIN, p)) for k, p in patterns.items()}
    for f in jobs.values():  # compile, fault the tables in
        f()
    syns_stages()
    times = {k: [] for k in jobs}
    cpu = {k: [] for k in jobs}
    stages = {"add (keys + minimum)": [], "winners (fold + index order)": [],
              "winners into fresh arrays": []}
    for _ in range(args.rounds):
        for k, f in jobs.items():
            c0, t0 = time.process_time(), time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
        for k, v in zip(stages, syns_stages()):
            stages[k].append(v)
    med = {k: float(np.median(v)) for k, v in times.items()}
    mcpu = {k: float(np.median(v)) for k, v in cpu.items()}
    rows = [{"what": k, "median_seconds": med[k], "all_seconds": v, "x_read": med[k] / med["read"],
             "x_angles": med[k] / med["angles"], "median_cpu_seconds": mcpu[k], "all_cpu_seconds": cpu[k],
             "cpu_x_angles": mcpu[k] / mcpu["angles"]} for k, v in times.items()]
    rows += [{"what": f"syns stage: {k}", "median_seconds": float(np.median(v)), "all_seconds": v}
             for k, v in stages.items()]
    gbps = pts.nbytes / med["read"] / 1e9
    print(f"{len(pts):,} points, {T} threads, medians of {args.rounds} rounds taken in turn")
    print(f"{'what':<42} {'seconds':>8} {'x read':>7} {'x angles':>9} {'cpu s':>7} {'cpu x angles':>13}")
    for r in rows:
        extra = (f" {r['x_read']:>7.1f} {r['x_angles']:>9.2f} {r['median_cpu_seconds']:>7.3f}"
                 f" {r['cpu_x_angles']:>13.2f}") if "x_read" in r else ""
        print(f"{r['what']:<42} {r['median_seconds']:>8.3f}{extra}")
    print(f"read: {pts.nbytes / 2**30:.2f} GiB at {gbps:.1f} GB/s")
    save("bench_floor" if T == 2 else f"bench_floor_{T}threads", {"machine": machine(), "inputs": {"points": len(pts), "threads": T, "rounds": args.rounds,
                                                         "origin": ORIGIN.tolist(), "bytes": pts.nbytes},
                         "read_gb_per_s": gbps, "rows": rows})
    _figure()


def _figure():
    """Each pass's seconds beside the angle kernel's: one thread (CPU) and two (wall)."""
    from matplotlib.figure import Figure

    from slr_ray.plotting import save_figure

    runs = {label: RESULTS / name for label, name in
            (("1 thread, CPU s", "bench_floor_1threads.json"), ("2 threads, wall s", "bench_floor.json"))}
    runs = {k: json.loads(v.read_text()) for k, v in runs.items() if v.exists()}
    if not runs:
        print("no saved results to draw")
        return
    names = {"read": "read the coordinates", "angles": "angle kernel alone", "scan 0.144": "0.144 deg scan",
             "scan syns 0.036": "SYNS 0.036 deg scan", "scan hdl64e_s2": "HDL-64E S2 frame",
             "scan vlp16": "VLP-16 frame"}
    fig = Figure(figsize=(6.5, 3.4), layout="constrained")
    ax = fig.add_subplot()
    ys = np.arange(len(names))
    height = 0.8 / len(runs)
    for j, (label, run) in enumerate(runs.items()):
        key = "median_cpu_seconds" if label.endswith("CPU s") else "median_seconds"
        by = {r["what"]: r.get(key, r["median_seconds"]) for r in run["rows"]}
        vals = [by.get(k, np.nan) for k in names]
        ax.barh(ys + (j - (len(runs) - 1) / 2) * height, vals, height, label=f"{label} ({run['machine']['date'][:10]})")
        ax.axvline(by["angles"], color=f"C{j}", lw=0.8, ls="--")
    ax.set_yticks(ys, list(names.values()))
    ax.invert_yaxis()
    ax.set_xlabel("seconds (dashed: the angle kernel alone)")
    pts = next(iter(runs.values()))["inputs"]["points"]
    ax.set_title(f"binning passes on {pts / 1e6:.0f} M points, prepared scanner, medians", fontsize=9)
    ax.legend(fontsize=8)
    path = Path(__file__).resolve().parent.parent / "docs" / "figures" / "floor.png"
    save_figure(fig, path)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
