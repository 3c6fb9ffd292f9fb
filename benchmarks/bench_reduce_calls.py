"""What one call of the beam-table reduction costs on one frame, outside and inside numba's
thread pool: ``BeamPattern.reduce`` (one thread's share runs outside the pool:
``beam_reduce_serial``), ``reduce_posed`` (the same, each point moved into the sensor's frame in
the kernel) and the pooled kernel ``beam_reduce`` with one thread's tables (what ``reduce`` called
for every frame before). A frame of the synthetic drive (HDL-64E S2, about 130,000 points) as a
VLP-16 sees it; median wall and CPU milliseconds of 30 calls each. docs/sequences.md (Speed)
quotes it; writes benchmarks/results/bench_reduce_calls.json.

    python benchmarks/bench_reduce_calls.py
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from common import machine, save

from slr_ray.core.beams import beam_reduce
from slr_ray.sensors import sensor
from slr_ray.sequence import read_sequence
from slr_ray.sequence.synthetic import synthetic_drive


def timed(f, n=30):
    f()  # compiled and warm
    wall, cpu = [], []
    for _ in range(n):
        t0, c0 = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return {"wall_ms": round(1e3 * statistics.median(wall), 3), "cpu_ms": round(1e3 * statistics.median(cpu), 3)}


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_drive(Path(tmp) / "drive", n_frames=2, sensor="velodyne_hdl64e_s2")
        seq = read_sequence(Path(tmp) / "drive")
        pts = np.ascontiguousarray(seq.read(1).points)
    pat = sensor("velodyne_vlp16")
    rmin, rmax = pat.range_limits

    def pooled():
        br = np.full((1, pat.n_pulses), np.inf)
        bi = np.full((1, pat.n_pulses), -1, np.int64)
        beam_reduce(pts, 0.0, 0.0, 0.0, pat._cos_edges, pat.row_offsets, pat.columns, rmin, rmax, br, bi)

    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 0.5]
    rows = {"reduce (outside the pool)": timed(lambda: pat.reduce(pts, np.zeros(3))),
            "reduce_posed (outside the pool, moved in the kernel)": timed(lambda: pat.reduce_posed(pts, pose)),
            "beam_reduce, one thread's tables (inside the pool)": timed(pooled)}
    for k, v in rows.items():
        print(f"{k}: {v}")
    save("bench_reduce_calls", {"machine": machine(), "points": len(pts), "calls": rows})


if __name__ == "__main__":
    main()
