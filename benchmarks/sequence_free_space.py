"""Moving objects removed without labels by free space (`--remove-moving visibility`,
slr_ray.sequence.sources.SeeThrough): a point of frame s is left out when, seen from another frame f
of s's +-2, its pulse and the four pulses beside it all return from more than ``margin`` metres
beyond it in f's own range image (f saw through where the point was), in at least ``votes`` frames.

1. the rule against the synthetic drive's labels (one box driving 1.5 m a frame ahead of the
   sensor; slr_ray.sequence.synthetic): recall and precision of the moving points, frames 2 to 21
   of 24, for margins 0.3 and 1 m and 1 or 2 votes (the shipped default: 1 m, 2);
2. what it changes in the leave-one-out scores on that drive (frames 4, 8, 12, 16, 20 held out,
   +-2): the union methods, the adjacent frame alone and the no-SLR z-buffer, with the moving
   points kept, left out by their labels, by visibility, by both;
3. on the four KITTI frames of the project's data (no labels: what it removes, and what it
   changes), frames 1 and 2 held out at the poses `--register` found (docs/sequence_kitti/poses.txt).

docs/sequences.md quotes it; writes benchmarks/results/sequence_free_space.json.

    python benchmarks/sequence_free_space.py [--skip-kitti]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from common import machine, save  # puts this checkout first on the path

from slr_ray.evaluate import markdown_table
from slr_ray.sequence import MOVING_CLASSES, FrameCache, SeeThrough, evaluate_sequence, read_sequence
from slr_ray.sequence.frames import read_file_list
from slr_ray.sequence.synthetic import synthetic_drive

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
KITTI = [f"kitti_hdl64_00000{i}.bin" for i in range(4)]
METHODS = ["zbuffer", "adjacent", "nearest", "fpa"]
COLUMNS = ["method", "points", "F@5cm", "F@10cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2"]
#: --remove-moving: (labels rule, see-through rule)
MODES = {"none": (False, False), "labels": (True, False), "visibility": (False, True), "both": (True, True)}


def detection(seq, sensor) -> list[dict]:
    rows = []
    for margin in (0.3, 1.0):
        for votes in (1, 2):
            st = SeeThrough(sensor, margin, votes)
            cache = FrameCache(seq, 32)
            tp = fp = fn = 0
            for s in range(2, 22):
                f, _ = cache.get(s)
                moving = np.isin(f.attributes["semantic"], MOVING_CLASSES)
                keep, _ = cache.selection(s, False, st)
                flag = np.zeros(len(moving), bool) if keep is None else ~keep
                tp += int((flag & moving).sum())
                fp += int((flag & ~moving).sum())
                fn += int((~flag & moving).sum())
            rows.append({"margin_m": margin, "votes": votes, "recall": tp / (tp + fn),
                         "precision": tp / max(tp + fp, 1), "flagged": tp + fp, "moving": tp + fn})
    return rows


def scores(seq, holdout, sensor, modes) -> dict:
    out = {}
    for mode in modes:
        drop, see = MODES[mode]
        res = evaluate_sequence(seq, holdout, sensor, METHODS, half=2, drop_moving=drop,
                                see_through=SeeThrough(sensor) if see else None)
        removed = [f["removed"] for f in res["frames"]]
        print(f"\n--remove-moving {mode}: removed from the unions {removed}")
        print(markdown_table(res["mean"], COLUMNS))
        out[mode] = {"mean": res["mean"], "removed": removed, "seconds": res["seconds"]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--skip-kitti", action="store_true")
    a = ap.parse_args()
    sensor = "velodyne_hdl64e_s2"
    out = {"machine": machine(), "default": SeeThrough(sensor).to_dict()}
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_drive(Path(tmp) / "drive", n_frames=24, sensor=sensor)
        seq = read_sequence(Path(tmp) / "drive")
        out["detection"] = detection(seq, sensor)
        print(markdown_table(out["detection"]))
        out["synthetic"] = scores(seq, range(4, 21, 4), sensor, MODES)
    if not a.skip_kitti and all((DATA / k).exists() for k in KITTI):
        seq = read_file_list([DATA / k for k in KITTI], ROOT / "docs" / "sequence_kitti" / "poses.txt")
        cache = FrameCache(seq)
        st = SeeThrough(sensor)
        out["kitti_removed_per_frame"] = [{"frame": i, "points": len(cache.get(i)[1]),
                                           "removed": cache.selection(i, False, st)[1]["seen_through"]}
                                          for i in range(4)]
        print(markdown_table(out["kitti_removed_per_frame"]))
        out["kitti"] = scores(seq, [1, 2], sensor, ("none", "visibility"))
    save("sequence_free_space", out)


if __name__ == "__main__":
    main()
