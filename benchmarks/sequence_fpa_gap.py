"""The first-peak average's gap on the four KITTI frames (poses by registration), frames 1 and 2
held out: mean F@5cm, depth MedAE and ray-drop accuracy per gap, the nearest rule beside.
Writes benchmarks/results/sequence_fpa_gap.json. The choice of FPA_GAP in
slr_ray/sequence/estimators.py comes from this table (docs/sequences.md)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from common import RESULTS, machine  # noqa: F401  (puts this checkout first on the path)

from slr_ray.evaluate import markdown_table
from slr_ray.sequence import evaluate_holdout, mean_rows, read_sequence, register_chain

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def main() -> None:
    frames = [DATA / f"kitti_hdl64_00000{i}.bin" for i in range(4)]
    if not all(f.is_file() for f in frames):
        sys.exit(f"the four KITTI frames are not in {DATA}")
    seq, _ = register_chain(read_sequence(frames))
    rows = []
    for gap in (0.05, 0.1, 0.15, 0.25, 0.5, 1.0):
        tabs = []
        for h in (1, 2):
            res = evaluate_holdout(seq, h, methods=("nearest", "fpa"), fpa_gap=gap)
            tabs.append(res["table"])
        for r in mean_rows(tabs):
            rows.append({"gap_m": gap} | {k: r[k] for k in ("method", "points", "F@5cm", "depth_medae_m",
                                                             "depth_rmse_m", "drop_accuracy", "cd_sum_m2")})
    print(markdown_table(rows))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sequence_fpa_gap.json").write_text(json.dumps({"machine": machine(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
