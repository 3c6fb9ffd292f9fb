"""Ctrl-C of ``sequence convert --scheduler`` (issue #48 item 3): a synthetic VLP-16 drive converted on a
local Dask cluster (worker processes) by the command line in a child process, interrupted (SIGINT) once
the journal lists its first frame; then, at once and again after the 30 s a running task may be waited
for (plus 10 s): the exit status and stderr, whether the run's staging directory is gone, whether every
frame under velodyne/ is one the journal lists, and whether velodyne/ changed after the exit (a late task
writing a frame no manifest claims). Repeated ``--runs`` times.

    python benchmarks/convert_scheduler_interrupt.py [--frames 16] [--runs 2]

Prints and saves results/convert_scheduler_interrupt.json.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import machine, save  # puts this checkout first on the path

from slr_ray.sequence.convert import JOURNAL
from slr_ray.sequence.synthetic import synthetic_drive

CHECKOUT = Path(__file__).resolve().parents[1]


def _journal_frames(out: Path) -> set:
    j = out / JOURNAL
    if not j.exists():
        return set()
    names = {}
    for line in j.read_text().splitlines():  # as the run reads it: a withdrawn frame is no longer listed
        try:
            e = json.loads(line)
        except ValueError:
            continue  # a last line cut short
        if isinstance(e, dict) and e.get("withdrawn"):
            names.pop(e.get("frame"), None)
        elif isinstance(e, dict) and e.get("file"):
            names[e.get("frame")] = Path(e["file"]).name
    return set(names.values())


def _state(out: Path) -> dict:
    frames = sorted(p.name for p in (out / "velodyne").glob("*.bin")) if (out / "velodyne").is_dir() else []
    listed = _journal_frames(out)
    return {"frames": frames, "journal": sorted(listed), "unlisted": sorted(set(frames) - listed),
            "staging": sorted(p.name for p in out.glob(".convert-*"))}


def run_once(drive: Path, out: Path, address: str, timeout: float = 600.0) -> dict:
    env = {**os.environ, "PYTHONPATH": str(CHECKOUT)}
    argv = [sys.executable, "-m", "slr_ray.cli", "sequence", "convert", str(drive), "--target-sensor",
            "velodyne_vlp16", "--half", "1", "--scheduler", address, "--quiet", "-o", str(out)]
    # SIGINT as a terminal gives it: a shell's background job starts with SIGINT ignored, and a Python
    # started so never raises KeyboardInterrupt
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    t0 = time.monotonic()
    while not _journal_frames(out) and p.poll() is None and time.monotonic() - t0 < timeout:
        time.sleep(0.2)
    if p.poll() is not None:
        return {"interrupted": False, "why": "the run ended before its first frame was listed",
                "returncode": p.returncode, "stderr": p.communicate()[1]}
    p.send_signal(signal.SIGINT)
    t_sig = time.monotonic()
    _, err = p.communicate(timeout=120)
    at_exit = _state(out)
    time.sleep(40)  # a running task may be waited for up to 30 s: anything later would show
    later = _state(out)
    return {"interrupted": True, "returncode": p.returncode, "seconds_to_exit": round(time.monotonic() - t_sig, 2),
            "stderr_lines": [line for line in err.splitlines() if line.strip()], "at_exit": at_exit,
            "after_40_s": later, "changed_after_exit": later != at_exit,
            "ok": (p.returncode != 0 and not at_exit["staging"] and not at_exit["unlisted"] and later == at_exit)}


def main() -> None:
    from dask.distributed import LocalCluster

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--runs", type=int, default=2)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp, LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                            dashboard_address=None) as cluster:
        tmp = Path(tmp)
        drive = tmp / "drive"
        synthetic_drive(drive, n_frames=args.frames, sensor="velodyne_vlp16", step=0.8)
        for run in range(args.runs):
            row = run_once(drive, tmp / f"out{run}", cluster.scheduler_address)
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if k not in ("at_exit", "after_40_s")}))
            if row["interrupted"]:
                print(f"  at exit: {len(row['at_exit']['frames'])} frames, journal {len(row['at_exit']['journal'])}, "
                      f"unlisted {row['at_exit']['unlisted']}, staging {row['at_exit']['staging']}; "
                      f"changed after 40 s: {row['changed_after_exit']}")
    save("convert_scheduler_interrupt", {"machine": machine(), "frames": args.frames, "workers": 2, "rows": rows,
                                         "all_ok": all(r.get("ok") for r in rows)})


if __name__ == "__main__":
    main()
