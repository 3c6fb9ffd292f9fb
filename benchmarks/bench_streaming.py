"""`slr-ray scan` and `slr-ray augment` on a LAZ file larger than memory would comfortably hold: time and peak memory.

    python benchmarks/bench_streaming.py [--points 100000000] [--chunk-size 2000000] [--augment 8]
        [--baseline CHECKOUT] [--repeat 1]

Generates (once, cached under results/, not committed) a LAZ of N points: a
200 m x 200 m ground with 4000 box-shaped objects, point format 6 with GPS
time, intensity and classification, written in chunks. Then runs
``slr-ray scan BIG.laz --origin ... --resolution 0.144 -o out.laz`` in a child
process (the binning backend reads LAS/LAZ in one pass of chunks) and reports
its wall time and peak RSS (getrusage of the child), the points kept, and the
size the whole cloud would take as float64 coordinates alone. Then
``slr-ray augment BIG.laz --n N --chunk-size ... --per-pass N`` (positions
from the streamed ground points in two passes, then N scans in one pass) the
same way. ``--baseline CHECKOUT`` runs both commands with another checkout of
slr_ray too (e.g. ``git archive`` of an older commit unpacked somewhere),
alternating with this one, ``--repeat`` times each: medians and ratios of one
run on one machine. Saves results/bench_streaming.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, save  # noqa: E402

CHECKOUT = str(Path(__file__).resolve().parents[1])


def make(path: Path, n: int, chunk: int = 5_000_000, seed: int = 0):
    import laspy

    rng = np.random.default_rng(seed)
    boxes = np.column_stack([rng.uniform(-95, 95, (4000, 2)), rng.uniform(0.5, 3, (4000, 2)),
                             rng.uniform(1, 6, 4000)])
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = [0.001, 0.001, 0.001]
    header.offsets = [500000.0, 4000000.0, 0.0]
    tmp = path.with_suffix(".tmp.laz")
    t0 = time.perf_counter()
    with laspy.open(str(tmp), mode="w", header=header, do_compress=True) as w:
        done = 0
        while done < n:
            k = min(chunk, n - done)
            on_box = rng.random(k) < 0.3
            xy = rng.uniform(-100, 100, (k, 2))
            z = rng.normal(0, 0.02, k)
            b = boxes[rng.integers(0, len(boxes), k)]
            xy[on_box] = b[on_box, :2] + rng.uniform(-0.5, 0.5, (on_box.sum(), 2)) * b[on_box, 2:4]
            z[on_box] = rng.uniform(0, 1, on_box.sum()) * b[on_box, 4]
            rec = laspy.ScaleAwarePointRecord.zeros(k, header=header)
            rec.x = xy[:, 0] + 500000.0
            rec.y = xy[:, 1] + 4000000.0
            rec.z = z
            rec.gps_time = rng.uniform(0, 1e5, k)
            rec.intensity = rng.integers(0, 65535, k)
            rec.classification = np.where(on_box, 1, 2).astype(np.uint8)
            w.write_points(rec)
            done += k
            print(f"  wrote {done:,} of {n:,}", file=sys.stderr, flush=True)
    tmp.rename(path)
    return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=100_000_000)
    ap.add_argument("--chunk-size", type=int, default=2_000_000)
    ap.add_argument("--augment", type=int, default=8, help="positions of the streamed augment (0: skip it)")
    ap.add_argument("--baseline", help="another checkout of slr_ray to time the same commands with")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each command per checkout (median)")
    args = ap.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    big = RESULTS / f"big_{args.points}.laz"
    gen = None
    if not big.exists():
        print(f"generating {big} ...", file=sys.stderr)
        gen = make(big, args.points)
    out = RESULTS / "big_scan.laz.tmp-out.laz"
    checkouts = {"this": CHECKOUT}
    if args.baseline:
        checkouts["baseline"] = str(Path(args.baseline).resolve())
    scan_cmd = ["-m", "slr_ray.cli", "scan", str(big), "--origin", "500001.3", "4000002.7", "1.65",
                "--resolution", "0.144", "--chunk-size", str(args.chunk_size), "--quiet", "-o", str(out)]
    outdir = RESULTS / "tmp_big_augment"
    aug_cmd = ["-m", "slr_ray.cli", "augment", str(big), "--n", str(args.augment), "--chunk-size",
               str(args.chunk_size), "--per-pass", str(args.augment), "--quiet", "-o", str(outdir)]
    runs = {name: {"scan": [], "augment": []} for name in checkouts}
    for _ in range(args.repeat):
        for name, checkout in checkouts.items():  # alternating: the machine's load falls on both alike
            out.unlink(missing_ok=True)
            runs[name]["scan"].append(_child([sys.executable, *scan_cmd], "scan", checkout))
            out.unlink()
            if args.augment:
                shutil.rmtree(outdir, ignore_errors=True)
                runs[name]["augment"].append(_child([sys.executable, *aug_cmd], "augment", checkout))
                shutil.rmtree(outdir, ignore_errors=True)
            print(f"{name}: scan {runs[name]['scan'][-1][0]:.1f} s"
                  + (f", augment {runs[name]['augment'][-1][0]:.1f} s" if args.augment else ""), flush=True)
    rows = {}
    for name, checkout in checkouts.items():
        wall, peak, res = _median(runs[name]["scan"])
        row = {"checkout": checkout, "points": args.points, "file_bytes": big.stat().st_size,
               "chunk_size": args.chunk_size, "generate_seconds": gen, "scan_wall_seconds": round(wall, 2),
               "scan_wall_seconds_all": [round(r[0], 2) for r in runs[name]["scan"]],
               "peak_rss_gib": peak, "points_out": res["points_out"],
               "float64_coordinates_gib": round(args.points * 24 / 2**30, 2), "command": " ".join(scan_cmd)}
        if args.augment:
            wall, peak, res = _median(runs[name]["augment"])
            row["augment"] = {"positions": args.augment, "wall_seconds": round(wall, 2),
                              "wall_seconds_all": [round(r[0], 2) for r in runs[name]["augment"]],
                              "peak_rss_gib": peak, "points_out": res["points_out"], "scans": res["scans"],
                              "command": " ".join(aug_cmd)}
        rows[name] = row
        print(json.dumps({name: row}, indent=1), flush=True)
    ratios = None
    if "baseline" in rows:
        b, t = rows["baseline"], rows["this"]
        ratios = {"scan": round(b["scan_wall_seconds"] / t["scan_wall_seconds"], 2)}
        if args.augment:
            ratios["augment"] = round(b["augment"]["wall_seconds"] / t["augment"]["wall_seconds"], 2)
        print(f"baseline / this: {ratios}")
    save("bench_streaming", {"machine": machine(), "inputs": vars(args), "result": rows["this"],
                             "augment": rows["this"].get("augment"), "baseline": rows.get("baseline"),
                             "speedup_vs_baseline": ratios})


def _median(results):
    """The run of median wall time (its peak RSS and output with it)."""
    return sorted(results, key=lambda r: r[0])[(len(results) - 1) // 2]


def _child(cmd, what, checkout):
    """(wall seconds, peak RSS GiB, last stdout line as JSON) of a child process
    that imports slr_ray from ``checkout``."""
    env = {**os.environ, "PYTHONPATH": checkout}
    t0 = time.perf_counter()
    # output to files, so that waiting on the child (for its own peak RSS) cannot block on a full pipe
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, env=env, cwd=checkout)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if os.waitstatus_to_exitcode(status):
        sys.exit(f"{what} failed: {stderr.strip().splitlines()[-1:]}")
    return wall, round(usage.ru_maxrss / 2**20, 3), json.loads(stdout.strip().splitlines()[-1])

if __name__ == "__main__":
    main()
