"""Speed and memory of `slr-ray sequence convert` (docs/sequences.md): a 100-frame synthetic drive
(HDL-64E S2, 0.8 m a frame) converted as a VLP-16 with a +-30-frame window (61 frames, about
6 M points a union), binning's rule (nearest), 2 worker processes; three runs, each into a fresh
directory, in a fresh process. Reports the median seconds a frame (the conversion loop: reading,
accumulating, reducing, writing) and the largest resident peak of any one process (the command or
a worker: ru_maxrss of the children) and the CPU seconds a frame of all its processes (process
start included: on a shared machine, CPU seconds / workers is what 2 free cores would take);
writes benchmarks/results/bench_sequence.json.

    python benchmarks/bench_sequence.py [--frames 100] [--half 30] [--workers 2] [--runs 3] [--drive DIR]
                                        [--estimator nearest [embree-sources ...]] [--target NAME] [--dask]
                                        (each in turn on the same drive; another than nearest is saved as
                                        bench_sequence_NAME.json; a method that needs the frames' sensor,
                                        embree-sources or embree-rays, gets --source-sensor, the drive's
                                        HDL-64E S2; --dask: on a local dask.distributed cluster of --workers
                                        worker processes, --scheduler, saved as bench_sequence_NAME_dask.json)

The command's progress bar (stderr) is kept: its last line goes into the results. Each run also
records its wall seconds a frame of the whole command (its start included) and of the conversion
loop, the start (wall less the loop: imports, the inputs' digests, a pool's start), the load average
before and after, and a digest of what it wrote (``outputs_sha256``: every frame's files, poses.txt and
calib.txt, by name; the same for the same inputs and settings, whatever the workers).

``--stages``: before the runs, one conversion in this process, one worker, timed stage by stage
(``convert_stages.py``: reading, meshing, union, cast, writing...; wall and CPU seconds, each
exclusive of the stages it calls), saved under ``stages``; ``--runs 0 --stages``: the profile alone.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import machine, save

from slr_ray.sequence.methods import REGISTRY
from slr_ray.sequence.synthetic import synthetic_drive


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--half", type=int, default=30)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--drive", help="an existing drive (KITTI layout) instead of making one")
    ap.add_argument("--estimator", nargs="+", default=["nearest"], help="convert's --estimator (default nearest)")
    ap.add_argument("--target", default="velodyne_vlp16", help="the target sensor (default velodyne_vlp16)")
    ap.add_argument("--dask", action="store_true", help="on a local dask.distributed cluster of --workers workers")
    ap.add_argument("--suffix", default="", help="appended to the results' names (bench_sequence_NAME_SUFFIX.json)")
    ap.add_argument("--stages", action="store_true", help="first a conversion in this process timed stage by stage")
    a = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        drive = Path(a.drive) if a.drive else Path(tmp) / "drive"
        if not a.drive:
            synthetic_drive(drive, n_frames=a.frames, sensor="velodyne_hdl64e_s2")
        made = time.perf_counter() - t0
        cluster = None
        if a.dask:
            from dask.distributed import LocalCluster
            cluster = LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True, dashboard_address=None)
        try:
            for est in a.estimator:
                one(a, est, drive, tmp, env, made, cluster)
        finally:
            if cluster is not None:
                cluster.close()


def _rss_gib(pid) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM")) / 2**20
    except (OSError, StopIteration):
        return float("nan")


def _digest(out: Path) -> str:
    """sha256 over the output's frames (velodyne/, labels/), poses.txt and calib.txt, by name."""
    h = hashlib.sha256()
    for p in sorted(q for q in out.rglob("*") if q.is_file() and q.parent.name in ("velodyne", "labels")
                    or q.name in ("poses.txt", "calib.txt")):
        h.update(str(p.relative_to(out)).encode() + b"\0" + hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()


def one(a, estimator, drive, tmp, env, made, cluster=None) -> None:
    """`--runs` runs of one estimator. Its peak is the largest of any child so far (the estimators run
    before it included): run the one of larger memory last, or alone. On a Dask cluster the workers'
    peaks (VmHWM) and CPU seconds are read from the workers' processes."""
    runs = []
    extra = ["--source-sensor", "velodyne_hdl64e_s2"] if REGISTRY[estimator].needs_source_sensor else []
    stages = None
    if a.stages:
        from convert_stages import profile

        out = Path(tmp) / f"stages_{estimator}"
        stages = profile(drive, out, a.target, estimator, a.half, {"source_sensor": "velodyne_hdl64e_s2"} if extra else {})
        stages["outputs_sha256"] = _digest(out)
        print(estimator, "stages", json.dumps(stages), flush=True)
        shutil.rmtree(out)
    if cluster is not None:
        extra += ["--scheduler", cluster.scheduler_address]
    for k in range(a.runs):
        out = Path(tmp) / f"out_{estimator}_{k}"
        cmd = [sys.executable, "-m", "slr_ray.cli", "sequence", "convert", str(drive),
               "--target-sensor", a.target, "--estimator", estimator, "--half", str(a.half),
               *(["--workers", str(a.workers)] if cluster is None else []), *extra, "-o", str(out)]
        workers_cpu0 = _workers_cpu(cluster)
        load0 = os.getloadavg()[0]
        t0, ru0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
        res = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall, ru = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (ru.ru_utime + ru.ru_stime) - (ru0.ru_utime + ru0.ru_stime) + _workers_cpu(cluster) - workers_cpu0
        if res.returncode:
            sys.exit(res.stderr)
        doc = json.loads(res.stdout)
        runs.append({"wall_s": round(wall, 2), "seconds_per_frame": doc["seconds_per_frame"],
                     "wall_seconds_per_frame": round(wall / a.frames, 4),
                     "start_s": round(wall - doc["seconds"], 2),
                     "cpu_seconds": round(cpu, 1), "cpu_seconds_per_frame": round(cpu / a.frames, 4),
                     "load_average": os.getloadavg()[0], "load_average_before": load0, "points": doc["points"],
                     "outputs_sha256": _digest(out),
                     "progress_tail": res.stderr.replace("\r", "\n").strip().splitlines()[-1:]})
        if cluster is not None:
            runs[-1]["workers_peak_gib"] = _workers_peak(cluster)
            runs[-1]["workers_memory_limit_gib"] = _workers_memory_limit(cluster)
        print(estimator, runs[-1], flush=True)
        shutil.rmtree(out)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20  # KiB -> GiB
    if cluster is not None:
        peak = max([peak, *_workers_peak(cluster)])
    out = {"machine": machine(), "frames": a.frames, "half": a.half, "workers": a.workers, "estimator": estimator,
           "target": a.target, "dask": cluster is not None,
           "drive_seconds": round(made, 1), "runs": runs,
           "median_seconds_per_frame": _median(r["seconds_per_frame"] for r in runs),
           "median_wall_seconds_per_frame": _median(r["wall_seconds_per_frame"] for r in runs),
           "median_cpu_seconds_per_frame": _median(r["cpu_seconds_per_frame"] for r in runs),
           "largest_process_peak_gib": round(peak, 3), "peak_of": "every process so far, earlier estimators included",
           "stages": stages}
    print(json.dumps({k: v for k, v in out.items() if k != "machine"}))
    name = "bench_sequence" if estimator == "nearest" else f"bench_sequence_{estimator}"
    save(name + ("_dask" if cluster is not None else "") + (f"_{a.suffix}" if a.suffix else ""), out)


def _median(values):
    values = list(values)
    return statistics.median(values) if values else None


def _worker_pids(cluster) -> list:
    if cluster is None:
        return []
    from dask.distributed import Client
    with Client(cluster) as c:
        return list(c.run(os.getpid).values())


def _workers_cpu(cluster) -> float:
    """CPU seconds so far of the cluster's worker processes (0 without one)."""
    total = 0.0
    for pid in _worker_pids(cluster):
        try:
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except OSError:
            pass
    return total


def _workers_memory_limit(cluster) -> list:
    """Each worker's memory limit (GiB; None: none)."""
    from dask.distributed import Client
    with Client(cluster) as c:
        info = c.scheduler_info()["workers"].values()
    return [round(w["memory_limit"] / 2**30, 2) if w.get("memory_limit") else None for w in info]


def _workers_peak(cluster) -> list:
    return [round(_rss_gib(pid), 3) for pid in _worker_pids(cluster)]




if __name__ == "__main__":
    main()
