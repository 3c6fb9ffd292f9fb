"""Prepared binning scans of this checkout against another's, in CPU time on one thread.

    python benchmarks/compare_checkouts.py OTHER_CHECKOUT [--resolutions 0.055 0.029] [--pairs 2]
    python benchmarks/compare_checkouts.py OTHER_CHECKOUT --sequence [--pairs 3]

On a machine shared with other jobs, wall-clock ratios to a baseline move
with the load; the CPU time of a one-thread process does not count the time
other jobs hold the core. Each pair runs one process of ``OTHER_CHECKOUT``
(e.g. ``git worktree add /tmp/main main``) and one of this checkout, in turn:
a prepared scanner (``n_threads=1``) scans the benchmark cloud from 14 m away
with 0.144 deg, SYNS and an HDL-64E S2 table, medians of 5. This
checkout's first process also times the paper's sort method (numpy, one
thread) on the same cloud and checks that the indices are identical.
Saves results/compare_checkouts.json.

``--sequence``: the sequence commands instead, through each checkout's own
command line in its process (one thread: NUMBA_NUM_THREADS=1): ``sequence
evaluate`` of the four KITTI frames of the shared data (--poses
docs/sequence_kitti/poses.txt, frame 1 held out, nearest fpa rays) and
``sequence convert`` of them (rays, an HDL-64E S2, --half 1); a warm-up run of
each, then the median of 3 in process CPU time. Saves
results/compare_checkouts_sequence.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def measure(resolution: float, with_sort: bool) -> dict:
    """One process's figures (run with this script's checkout first on sys.path)."""
    import numba
    import numpy as np

    from common import realistic_cloud

    import slr_ray

    numba.set_num_threads(1)
    pts = np.ascontiguousarray(realistic_cloud(resolution))
    origin = np.array([12.3, -7.1, 0.0])
    scanner = slr_ray.prepare(pts, n_threads=1)
    patterns = {"0.144": slr_ray.ScanPattern(0.144), "syns": slr_ray.preset("syns"),
                "hdl64e_s2": slr_ray.sensor("velodyne_hdl64e_s2")}
    for p in patterns.values():
        scanner.scan(origin, p)
    took = {k: [] for k in patterns}
    for _ in range(5):
        for k, p in patterns.items():
            t0 = time.process_time()
            scanner.scan(origin, p)
            took[k].append(time.process_time() - t0)
    out = {"slr_ray": slr_ray.__file__, "points": len(pts),
           "cpu_seconds": {k: float(np.median(v)) for k, v in took.items()}}
    if with_sort:
        from sort_baseline import sort_based_scan

        out["sort_cpu_seconds"], out["identical"] = {}, {}
        for k in ("0.144", "syns"):
            t0 = time.process_time()
            ref = sort_based_scan(pts, origin, patterns[k])
            out["sort_cpu_seconds"][k] = time.process_time() - t0
            out["identical"][k] = bool(np.array_equal(ref, scanner.scan(origin, patterns[k]).indices))
    return out


DATA = Path("/work/shared/data")
KITTI = [f"kitti_hdl64_00000{i}.bin" for i in range(4)]


def sequence_commands(data: Path, poses: Path, out: Path) -> dict:
    """The two commands timed (argument lists of the command line; both checkouts spell them alike)."""
    frames = [str(data / f) for f in KITTI]
    common = [*frames, "--poses", str(poses), "--quiet", "-o"]
    return {"sequence evaluate": ["sequence", "evaluate", *common, str(out / "evaluate"), "--holdout", "1",
                                  "--methods", "nearest", "fpa", "rays"],
            "sequence convert": ["sequence", "convert", *common, str(out / "convert"), "--sensor",
                                 "velodyne_hdl64e_s2", "--estimator", "rays", "--half", "1"]}


def measure_sequence(data: Path, poses: Path, repeats: int = 3) -> dict:
    """One process's CPU seconds of each sequence command (its checkout first on sys.path)."""
    import tempfile

    import numpy as np

    import slr_ray
    from slr_ray.cli import main as cli

    took = {}
    for run in range(repeats + 1):  # the first run compiles and warms the caches: not counted
        with tempfile.TemporaryDirectory() as tmp:
            for name, argv in sequence_commands(data, poses, Path(tmp)).items():
                t0 = time.process_time()
                if cli(argv) != 0:
                    raise SystemExit(f"{name} failed")
                if run:
                    took.setdefault(name, []).append(time.process_time() - t0)
    return {"slr_ray": slr_ray.__file__, "cpu_seconds": {k: float(np.median(v)) for k, v in took.items()},
            "all_cpu_seconds": took}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", nargs="?", help="the other checkout (its root)")
    ap.add_argument("--resolutions", type=float, nargs="+", default=[0.055, 0.029])
    ap.add_argument("--pairs", type=int, default=2)
    ap.add_argument("--sequence", action="store_true", help="the sequence commands on KITTI (above)")
    ap.add_argument("--data", type=Path, default=DATA, help="the shared data (its four KITTI frames)")
    ap.add_argument("--worker", nargs=2, metavar=("RESOLUTION", "SORT"), help=argparse.SUPPRESS)
    ap.add_argument("--sequence-worker", nargs=2, metavar=("DATA", "POSES"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker or args.sequence_worker:  # one measuring process: its checkout first on sys.path
        sys.path.insert(0, str(HERE))
        sys.path.insert(0, str(HERE.parent))
        if args.sequence_worker:
            print(json.dumps(measure_sequence(*map(Path, args.sequence_worker))))
        else:
            print(json.dumps(measure(float(args.worker[0]), args.worker[1] == "1")))
        return
    if not args.other:
        ap.error("name the other checkout")
    other = Path(args.other).resolve()
    if not (other / "slr_ray").is_dir():
        ap.error(f"{other} has no slr_ray package")
    import shutil

    # the other checkout runs this script from a copy inside it, on its own cloud cache (linked)
    script = other / "benchmarks" / "_compare_checkouts_worker.py"
    shutil.copy(__file__, script)
    (other / "benchmarks" / "results").mkdir(exist_ok=True)
    for cloud in (HERE / "results").glob("cloud_*.npy"):
        link = other / "benchmarks" / "results" / cloud.name
        if not link.exists():
            link.symlink_to(cloud)
    rows = []
    if args.sequence:
        try:
            _sequence_pairs(script, args, rows)
        finally:
            script.unlink(missing_ok=True)
        sys.path.insert(0, str(HERE))
        from common import machine, save

        save("compare_checkouts_sequence", {"machine": machine(), "load": os.getloadavg(), "other": str(other),
                                            "commands": sequence_commands(args.data, HERE.parent / POSES, Path("OUT")),
                                            "rows": rows, "ratio_this_to_other": _ratios(rows)})
        return
    try:
        for res in args.resolutions:
            for pair in range(args.pairs):
                for name, path in (("other", script), ("this", Path(__file__).resolve())):
                    sort = "1" if (name == "this" and pair == 0) else "0"
                    r = subprocess.run([sys.executable, str(path), "--worker", str(res), sort],
                                       capture_output=True, text=True, check=True)
                    row = {"checkout": name, "resolution": res, "pair": pair,
                           **json.loads(r.stdout.strip().splitlines()[-1])}
                    rows.append(row)
                    print(f"{res} {name}: " + ", ".join(f"{k} {v:.3f} s" for k, v in row["cpu_seconds"].items())
                          + (f"; sort {row['sort_cpu_seconds']}" if "sort_cpu_seconds" in row else ""),
                          flush=True)
    finally:
        script.unlink(missing_ok=True)
    sys.path.insert(0, str(HERE))
    from common import machine, save

    save("compare_checkouts", {"machine": machine(), "other": str(other), "rows": rows})


POSES = Path("docs/sequence_kitti/poses.txt")


def _sequence_pairs(script: Path, args, rows: list) -> None:
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    for pair in range(args.pairs):
        for name, path in (("other", script), ("this", Path(__file__).resolve())):
            env.pop("PYTHONPATH", None)
            r = subprocess.run([sys.executable, str(path), "--sequence-worker", str(args.data),
                                str(HERE.parent / POSES)], capture_output=True, text=True, check=True, env=env)
            row = {"checkout": name, "pair": pair, "load": os.getloadavg(),
                   **json.loads(r.stdout.strip().splitlines()[-1])}
            rows.append(row)
            print(f"{name}: " + ", ".join(f"{k} {v:.2f} s" for k, v in row["cpu_seconds"].items())
                  + f" (load {row['load'][0]:.2f})", flush=True)
    ratios = _ratios(rows)
    print("this / other, medians of the pairs: " + ", ".join(f"{k} {v:.3f}" for k, v in ratios.items()))


def _ratios(rows: list) -> dict:
    import statistics

    side = {c: [r["cpu_seconds"] for r in rows if r["checkout"] == c] for c in ("this", "other")}
    return {k: statistics.median(t[k] for t in side["this"]) / statistics.median(o[k] for o in side["other"])
            for k in side["this"][0]}


if __name__ == "__main__":
    main()
