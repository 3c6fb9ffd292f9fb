"""Embree discs from each source frame's own pulse grid (`embree-sources`, slr_ray.sequence.sources)
and variants of it that were not shipped, scored as `slr-ray sequence evaluate` scores every method:

- shipped: each frame's discs from its fitted pulse grid at its origin, one scene a frame; a
  target pulse's return is where its centre ray meets the first disc over the window's frames (the
  backend's tie rule within a frame, ``ties`` 3, a beam-table primary's);
- ``ties 0`` (Embree's first hit) and ``ties 6``;
- the disc's own point returned (its centre, as the ``embree-knn`` estimator returns) instead of
  where the ray meets the disc.

On the four KITTI frames of the project's data (frames 1 and 2 held out, +-2, at the poses
`--register` found: docs/sequence_kitti/poses.txt) and the synthetic drive (frames 4, 8, 12, 16, 20
held out, +-2, moving box left out by its labels). docs/sequences.md quotes it; writes
benchmarks/results/sequence_sources.json.

    python benchmarks/sequence_sources.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from common import machine, save  # puts this checkout first on the path

from slr_ray.evaluate import markdown_table
from slr_ray.sequence import evaluate_sequence, read_sequence, sources, union
from slr_ray.sequence.frames import read_file_list
from slr_ray.sequence.synthetic import synthetic_drive

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
KITTI = [f"kitti_hdl64_00000{i}.bin" for i in range(4)]
COLUMNS = ["variant", "points", "F@5cm", "F@10cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2",
           "seconds"]
SHIPPED = sources.cast_sources


def _centres(scanners, pose, pattern):
    pts = np.concatenate([sc.points for sc, _ in scanners if sc is not None])
    return SHIPPED(scanners, pose, pattern, centres=pts)


VARIANTS = {"shipped (ties 3, where the ray meets the disc)": (3.0, SHIPPED), "ties 0": (0.0, SHIPPED),
            "ties 6": (6.0, SHIPPED), "the disc's own point": (3.0, _centres)}


def run(seq, holdout) -> list[dict]:
    rows = []
    for name, (ties, cast) in VARIANTS.items():
        sources.SOURCE_TIES, union.cast_sources = ties, cast  # read at call time
        try:
            res = evaluate_sequence(seq, holdout, "velodyne_hdl64e_s2", ["embree-sources"], half=2)
        finally:
            sources.SOURCE_TIES, union.cast_sources = 3.0, SHIPPED
        rows.append({"variant": name, **res["mean"][0], "seconds": res["seconds"]})
    print(markdown_table(rows, COLUMNS))
    return rows


def main() -> None:
    out = {"machine": machine()}
    if all((DATA / k).exists() for k in KITTI):
        seq = read_file_list([DATA / k for k in KITTI], ROOT / "docs" / "sequence_kitti" / "poses.txt")
        out["kitti"] = run(seq, [1, 2])
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_drive(Path(tmp) / "drive", n_frames=24, sensor="velodyne_hdl64e_s2")
        out["synthetic"] = run(read_sequence(Path(tmp) / "drive"), range(4, 21, 4))
    save("sequence_sources", out)


if __name__ == "__main__":
    main()
