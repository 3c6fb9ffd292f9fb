"""What applying calib.txt's ``Tr`` to ``--poses`` is worth (issue #48 item 5): the four KITTI frames of
the shared data laid out as a KITTI directory (velodyne/NNNNNN.bin, calib.txt with KITTI odometry
sequence 00's ``Tr``), their velodyne poses (docs/sequence_kitti/poses.txt, by ``--register``) written
in KITTI's form, the left camera's (``Tr V Tr^-1``), and given with ``--poses``:

- ``tr_applied``: the directory with its calib.txt: the poses are moved to the velodyne (``Tr^-1 P Tr``,
  what slr-ray does);
- ``tr_ignored``: the same directory without calib.txt: the camera's poses taken as the velodyne's (what
  slr-ray did before the fix).

Each: ``sequence evaluate DIR --poses cam.txt --holdout 1 2 --methods rays nearest``; the mean F@5cm.

    python benchmarks/kitti_calib_tr.py [--data /work/shared/data]

Prints and saves results/kitti_calib_tr.json.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np
from common import machine, save  # puts this checkout first on the path

from slr_ray.cli import main as cli
from slr_ray.sequence.poses import read_trajectory, write_kitti_poses

HERE = Path(__file__).resolve().parent
#: KITTI odometry sequence 00's calib.txt Tr (velodyne to left camera), 3 x 4
TR_00 = [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02,
         -7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02,
         9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01]
METHODS = ("rays", "nearest")


def _layout(root: Path, data: Path, calib: bool) -> Path:
    (root / "velodyne").mkdir(parents=True)
    for i in range(4):
        (root / "velodyne" / f"{i:06d}.bin").symlink_to(data / f"kitti_hdl64_00000{i}.bin")
    if calib:
        (root / "calib.txt").write_text("Tr: " + " ".join(f"{x:.12e}" for x in TR_00) + "\n")
    return root


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("/work/shared/data"))
    args = ap.parse_args()
    Tr = np.eye(4)
    Tr[:3] = np.reshape(TR_00, (3, 4))
    velo = read_trajectory(HERE.parent / "docs" / "sequence_kitti" / "poses.txt", 4)
    out = {"machine": machine(), "tr": TR_00, "velodyne_poses": "docs/sequence_kitti/poses.txt",
           "holdout": [1, 2], "methods": list(METHODS)}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cam = tmp / "cam.txt"
        write_kitti_poses(cam, np.einsum("ij,njk,kl->nil", Tr, velo, np.linalg.inv(Tr)))
        for key, calib in (("tr_applied", True), ("tr_ignored", False)):
            root = _layout(tmp / key, args.data, calib)
            argv = ["sequence", "evaluate", str(root), "--poses", str(cam), "--holdout", "1", "2", "--methods",
                    *METHODS, "--quiet", "-o", str(tmp / f"{key}_out")]
            with contextlib.redirect_stdout(io.StringIO()):
                if cli(argv) != 0:
                    raise SystemExit(f"{key}: sequence evaluate failed")
            res = json.loads((tmp / f"{key}_out" / "evaluation.json").read_text())
            out[key] = {"pose_source": res.get("pose_source"),
                        "mean": {r["method"]: {k: r[k] for k in ("F@5cm", "depth_medae_m", "drop_accuracy")}
                                 for r in res["mean"]}}
            print(f"{key}: " + ", ".join(f"{m} F@5cm {v['F@5cm']:.4f}" for m, v in out[key]["mean"].items()))
    save("kitti_calib_tr", out)


if __name__ == "__main__":
    main()
