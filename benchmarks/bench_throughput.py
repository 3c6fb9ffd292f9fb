"""End-to-end SLR throughput on the 29 M-point benchmark cloud: how long 13,000 scans take.

    python benchmarks/bench_throughput.py [--n 200] [--formats npy las laz] [--workers 1 2] [--stages 20]

The paper generated 13,000 SLR clouds from SYNS scans of about 29 M points.
This runs what a user runs, :func:`slr_ray.augment`, on the benchmark cloud
(an ``.npy`` file; ground = the points within 5 cm of the ground plane
z = -1.65 m): reading the input, choosing ``--n`` positions by the grid method,
then one binning scan at 0.144 deg per position, the subset of every
attribute and the file written, for each output format and number of worker
processes. The paper's sort method is timed on the same cloud in the same run
as the baseline, and the scan alone (a prepared scanner, no file) beside it.

Reports, per setting, seconds per scan (the steady rate, between the first
and the last scan of the run), scans per hour and the projected wall time of
13,000 scans (input read and positions once, the time to the first scan,
which includes starting the workers, then 12,999 x the steady per-scan
time), and the stage split: CPU seconds per scan (``time.process_time``, every
thread of the process, lazrs' included) of the scan on one thread, the subset,
building the file's records, and the file written, per format, over
``--stages`` positions in one process; the floor of a format on C cores is
their sum / C (the cores busy all the time, nothing else running). Saves
results/bench_throughput.json and docs/figures/throughput.png.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, realistic_cloud, save  # noqa: E402

from slr_ray import ScanPattern, prepare, select_positions  # noqa: E402
from slr_ray.augment import AugmentConfig, augment  # noqa: E402
from slr_ray.io import read_cloud, write_cloud  # noqa: E402

PAPER_SCANS = 13_000


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="positions per run")
    ap.add_argument("--formats", nargs="+", default=["npy", "las", "laz"])
    ap.add_argument("--workers", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--stages", type=int, default=20, help="positions of the CPU stage split (0: skip it)")
    args = ap.parse_args(argv)
    realistic_cloud()  # make sure the cached cloud exists
    src = RESULTS / "cloud_1000_0_0.029.npy"
    pattern = ScanPattern(0.144)

    t0 = time.perf_counter()
    cloud = read_cloud(src)
    t_read = time.perf_counter() - t0
    pts = np.ascontiguousarray(cloud.points)
    ground = np.abs(pts[:, 2] + 1.65) < 0.05
    t0 = time.perf_counter()
    positions = select_positions(pts, ground, args.n, seed=0, allow_fewer=True)
    t_pos = time.perf_counter() - t0
    print(f"{len(pts):,} points read in {t_read:.1f} s; {len(positions)} positions in {t_pos:.1f} s", flush=True)

    from sort_baseline import sort_based_scan

    t0 = time.perf_counter()
    sort_based_scan(pts, positions[0], pattern)
    t_sort = time.perf_counter() - t0
    scanner = prepare(pts)
    scanner.scan(positions[0], pattern)  # compile, allocate the tables
    scan_s = []
    for p in positions[: min(len(positions), 50)]:
        t0 = time.perf_counter()
        scanner.scan(p, pattern)
        scan_s.append(time.perf_counter() - t0)
    t_scan = float(np.median(scan_s))
    del scanner
    print(f"sort baseline {t_sort:.2f} s per scan; prepared binning scan {t_scan:.3f} s "
          f"({t_sort / t_scan:.1f}x)", flush=True)

    stages = _stages(cloud, positions[: args.stages], pattern, args.formats) if args.stages else None
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for workers in args.workers:
            for fmt in args.formats:
                out = Path(tmp) / f"{fmt}_{workers}"
                t0 = time.perf_counter()
                manifest = augment(src, out, AugmentConfig(n=args.n, fmt=f".{fmt}", workers=workers),
                                   ground=ground, progress=False)
                wall = time.perf_counter() - t0
                n_scans = len(manifest["scans"])
                # the steady rate: between the first and the last scan recorded (worker
                # start-up, i.e. spawning and sending the cloud, is paid once, before the first)
                done = sorted(e["done"] for e in manifest["scans"])
                per = (done[-1] - done[0]) / (n_scans - 1)
                first = done[0]
                in_worker = float(np.median([s["seconds"] for s in manifest["scans"]]))
                size = sum(f.stat().st_size for f in out.glob(f"scan_*.{fmt}")) / n_scans
                setup = wall - manifest["seconds"]  # read + ground + positions inside augment
                projected = (setup + first + (PAPER_SCANS - 1) * per) / 3600
                cpu = sum(stages[k] for k in ("scan", "subset", f"write_{fmt}")) if stages else None
                rows.append({"format": fmt, "workers": workers, "scans": n_scans, "wall_seconds": wall,
                             "cpu_seconds_per_scan": cpu,
                             "floor_seconds_per_scan": cpu and cpu / (os.cpu_count() or 1),
                             "setup_seconds": setup, "first_scan_seconds": first, "seconds_per_scan": per,
                             "median_seconds_in_worker": in_worker, "bytes_per_file": size,
                             "scans_per_hour": 3600 / per, "projected_13000_hours": projected})
                print(f"{fmt:>4} x {workers} worker(s): {n_scans} scans in {wall:.1f} s (setup {setup:.1f} s, "
                      f"first scan after {first:.1f} s): "
                      f"{per:.3f} s/scan -> {3600 / per:,.0f} scans/h, 13,000 in {projected:.2f} h "
                      f"({size / 2**20:.1f} MiB per file)"
                      + (f"; CPU {cpu:.3f} s/scan, floor on {os.cpu_count()} cores "
                         f"{rows[-1]['floor_seconds_per_scan']:.3f} s" if cpu else ""), flush=True)
    best = min(rows, key=lambda r: r["projected_13000_hours"])
    print(f"\nbest: {best['format']} with {best['workers']} worker(s): 13,000 scans in "
          f"{best['projected_13000_hours'] * 60:.0f} min (sort baseline alone: "
          f"{PAPER_SCANS * t_sort / 3600:.1f} h)")
    _figure(rows, t_sort)
    save("bench_throughput", {"machine": machine(), "inputs": {**vars(args), "points": len(pts), "input": src.name,
                                                               "pattern": pattern.to_dict()},
                              "read_seconds": t_read, "positions_seconds": t_pos,
                              "sort_baseline_seconds": t_sort, "prepared_scan_seconds": t_scan,
                              "scan_speedup_vs_sort": t_sort / t_scan, "cpu_seconds_per_scan": stages,
                              "rows": rows})


def _stages(cloud, positions, pattern, formats) -> dict:
    """Median CPU seconds per scan of each stage, one process, the scan on one thread."""
    import laspy

    scanner = prepare(np.ascontiguousarray(cloud.points), "binning", {"n_threads": 1})
    scanner.scan(positions[0], pattern)
    cpu = {}

    def timed(name, fn):
        t0 = time.process_time()
        out = fn()
        cpu.setdefault(name, []).append(time.process_time() - t0)
        return out

    with tempfile.TemporaryDirectory() as tmp:
        for p in positions:
            scan = timed("scan", lambda: scanner.scan(p, pattern))
            sub = timed("subset", lambda: cloud.subset(scan.indices))
            cpu.setdefault("points", []).append(len(scan))
            for fmt in formats:
                timed(f"write_{fmt}", lambda: write_cloud(Path(tmp) / f"s.{fmt}", sub))
            if "laz" in formats:  # compression alone: the records built, laspy/lazrs writing them to memory
                las = laspy.read(str(Path(tmp) / "s.laz"))
                timed("compress_laz", lambda: las.write(io.BytesIO(), do_compress=True))
    out = {k: float(np.median(v)) for k, v in cpu.items()}
    print("CPU seconds per scan (median of %d, one thread): " % len(positions)
          + ", ".join(f"{k} {v:.4f}" for k, v in out.items() if k != "points")
          + f"; {out['points']:,.0f} points a scan", flush=True)
    return out


def _figure(rows, t_sort):
    from matplotlib.figure import Figure

    from slr_ray.plotting import save_figure

    fig = Figure(figsize=(6.5, 3.6), layout="constrained")
    ax = fig.add_subplot()
    labels = [f"{r['format']}\n{r['workers']} worker{'s' if r['workers'] > 1 else ''}" for r in rows]
    hours = [r["projected_13000_hours"] for r in rows]
    ax.bar(labels, hours, color=["tab:green" if h < 0.5 else "tab:orange" for h in hours])
    ax.axhline(0.5, color="k", lw=0.8, ls="--", label="goal: 0.5 h")
    ax.set_ylabel("projected hours for 13,000 scans")
    ax.set_title(f"augment, 29 M points, 0.144 deg (sort baseline alone: {PAPER_SCANS * t_sort / 3600:.0f} h)",
                 fontsize=9)
    ax.legend()
    path = Path(__file__).resolve().parent.parent / "docs" / "figures" / "throughput.png"
    save_figure(fig, path)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
