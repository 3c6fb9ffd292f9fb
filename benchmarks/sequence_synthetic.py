"""The synthetic drive with truth (docs/sequences.md): a rectangle street, parked boxes, one moving
box, 24 frames of one HDL-64E S2 (0.8 m apart, exact poses through KITTI's Tr), every 4th frame
from 4 to 20 held out and re-simulated from its +-2 window by every method, with the moving box's
points left out of the union (the default) and kept (--keep-moving). Prints the mean tables and
writes benchmarks/results/sequence_synthetic.json.

    python benchmarks/sequence_synthetic.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from common import machine, save  # puts this checkout first on the path

from slr_ray.evaluate import markdown_table
from slr_ray.sequence import METHODS, evaluate_sequence, read_sequence
from slr_ray.sequence.synthetic import synthetic_drive

COLUMNS = ["method", "points", "F@5cm", "F@10cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2",
           "R@10cm seen"]


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_drive(Path(tmp) / "drive", n_frames=24, sensor="velodyne_hdl64e_s2")
        seq = read_sequence(Path(tmp) / "drive")
        out = {"machine": machine()}
        for drop in (True, False):
            res = evaluate_sequence(seq, range(4, 21, 4), "velodyne_hdl64e_s2", METHODS, half=2, drop_moving=drop)
            key = "moving_left_out" if drop else "moving_kept"
            print(f"\n{key}: mean over held-out frames {[f['frame'] for f in res['frames']]}, unseen share "
                  f"{sum(f['unseen_share'] for f in res['frames']) / len(res['frames']):.3f}")
            print(markdown_table(res["mean"], COLUMNS))
            out[key] = {"mean": res["mean"], "frames": [{k: v for k, v in f.items() if k != "rows"}
                                                        for f in res["frames"]]}
        save("sequence_synthetic", out)


if __name__ == "__main__":
    main()
