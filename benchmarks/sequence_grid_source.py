"""Is ``slr-ray sequence evaluate`` leak-free? Its held-out frame's scoring grid (each row's elevation,
the column count) is fitted from the frame's own points by default (``--grid-from target``, as
``slr-ray evaluate`` fits a pair's); ``--grid-from others`` fits it from the other frames of its window
instead, so nothing of the held-out frame but its pose and its score reaches any method.

Every method on the four KITTI frames (poses by registration), each frame held out in turn, scored
both ways; means over frames 1 and 2 (where ``rays``' hyper-parameters were chosen) and over frames
0 and 3 (the sequence's ends: the check of those choices), side by side. The figures are deterministic
(the same on every run); the timings are each method's seconds a held-out frame (its scoring included),
the median of the 8 frame runs.

    PYTHONPATH=. python benchmarks/sequence_grid_source.py

Writes benchmarks/results/sequence_grid_source.json (docs/sequences.md quotes it)."""

from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

from common import RESULTS, machine  # noqa: F401  (puts this checkout first on the path)

from slr_ray.sequence import evaluate_sequence, read_sequence, register_chain
from slr_ray.sequence.holdout import GRID_SOURCES, METHODS, mean_rows

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
KEYS = ("F@5cm", "F@10cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2")
SPLITS = {"frames 1 and 2": ["000001", "000002"], "frames 0 and 3": ["000000", "000003"]}


def main() -> None:
    frames = [DATA / f"kitti_hdl64_{i:06d}.bin" for i in range(4)]
    seq, _ = register_chain(read_sequence([str(f) for f in frames]))
    runs, seconds, method_seconds = {}, {}, {m: [] for m in METHODS}
    for source in GRID_SOURCES:
        t0 = time.perf_counter()
        res = evaluate_sequence(seq, [0, 1, 2, 3], methods=METHODS, grid_from=source)
        seconds[source] = round(time.perf_counter() - t0, 1)
        runs[source] = {f["frame"]: f["table"] for f in res["frames"]}
        for f in res["frames"]:
            for r in f["rows"]:
                method_seconds[r["method"]].append(r["seconds"])
    rows = []
    for split, names in SPLITS.items():
        means = {s: mean_rows([runs[s][n] for n in names]) for s in GRID_SOURCES}
        for m, a, b in zip(METHODS, means["target"], means["others"]):
            rows.append({"held out": split, "method": m}
                        | {f"{k} (grid: target)": round(a[k], 4) for k in KEYS}
                        | {f"{k} (grid: others)": round(b[k], 4) for k in KEYS})
    head = f"{'held out':15} {'method':11}" + "".join(f" {k[:13]:>13} t/o" + " " * 9 for k in KEYS)
    print(head)
    for r in rows:
        print(f"{r['held out']:15} {r['method']:11}" + "".join(
            f" {r[f'{k} (grid: target)']:>11.4f}/{r[f'{k} (grid: others)']:<11.4f}" for k in KEYS))
    print("seconds per run (4 frames, all methods):", seconds)
    median_seconds = {m: statistics.median(v) for m, v in method_seconds.items()}
    print("median seconds a held-out frame (its scoring included; 8 frame runs):", median_seconds)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sequence_grid_source.json").write_text(json.dumps(
        {"machine": machine(), "rows": rows, "per_frame": runs, "seconds": seconds,
         "median_seconds_per_frame": median_seconds, "method_seconds": method_seconds}, indent=1))


if __name__ == "__main__":
    main()
