"""Cross-sensor scoring against a real target (issue #45 item 3): the Pandar64 -> PandarQT64 moment.

One moment seen by two units of one vehicle (``../shared/data/hesai_p64_qt64``: ``p64.pcd``, the roof
Pandar64 with its ring field; ``qt.pcd``, a PandarQT64, no ring field; ``p64-to-qt-extrinsic.json``, the
rig's hand calibration). The QT64 frame is re-simulated from the Pandar64 frame at the QT64's pose by
every method of ``slr-ray evaluate`` and scored against the real QT64 frame, split by what the Pandar64
could have seen (docs/cross_sensor.md):

1. the extrinsic's direction: the QT64 frame moved by the file's matrix and by its inverse, each then
   refined by point-to-plane ICP (Open3D, 1, 0.5, 0.2 m): the direction that fits needs the smaller
   correction (the file maps Pandar64 coordinates into the QT64's frame);
2. ``slr-ray evaluate p64.pcd qt.pcd --source-sensor hesai_pandar64 --target-sensor T --extrinsic
   p64-to-qt-extrinsic.json`` for T the card fitted to this QT64 frame (``hesai_pandarqt64_pjlab``) and
   the card of another QT64 unit (``hesai_pandarqt64``, tier4/nebula's frame);
3. the same with the extrinsic refined by ICP (``--transform`` of the refined pose).

Saves benchmarks/results/cross_sensor.json; prints the tables of docs/cross_sensor.md.
Run: ``PYTHONPATH=. nice python benchmarks/cross_sensor.py`` from the repository root (about a minute).
"""

from __future__ import annotations

import io
import json
import sys
import tempfile
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save  # noqa: E402

from slr_ray.cli import main as cli  # noqa: E402
from slr_ray.cli.evaluate_command import read_extrinsic  # noqa: E402
from slr_ray.evaluate import rig_extrinsic  # noqa: E402
from slr_ray.io import read_cloud  # noqa: E402
from slr_ray.reports import markdown_table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = next((p / "shared" / "data" for p in ROOT.parents if (p / "shared" / "data").is_dir()),
            ROOT.parent / "shared" / "data") / "hesai_p64_qt64"
COLUMNS = ("method", "points", "F@5cm", "P@5cm", "R@5cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy",
           "cd_sum_m2")
REACH = ("method", "part", "target points", "real pulses", "F@5cm", "P@5cm", "R@5cm", "depth_medae_m",
         "drop_accuracy")


def icp(b, a, start):
    """``(pose, fitness before, fitness after)``: B's pose in A's frame refined by point-to-plane ICP."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    src, tgt = o3d.geometry.PointCloud(), o3d.geometry.PointCloud()
    src.points, tgt.points = o3d.utility.Vector3dVector(b), o3d.utility.Vector3dVector(a)
    tgt.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=1.0, max_nn=30))
    before = reg.evaluate_registration(src, tgt, 0.2, start).fitness
    T = start
    for d in (1.0, 0.5, 0.2):
        T = reg.registration_icp(src, tgt, d, T, reg.TransformationEstimationPointToPlane(),
                                 reg.ICPConvergenceCriteria(max_iteration=50)).transformation
    return np.asarray(T), before, reg.evaluate_registration(src, tgt, 0.2, T).fitness


def moved(T0, T1):
    """``(metres, degrees)`` between two poses."""
    d = T1 @ np.linalg.inv(T0)
    return float(np.linalg.norm(d[:3, 3])), float(np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1))))


def run(args: list) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        buf = io.StringIO()
        with redirect_stdout(buf):
            code = cli(["evaluate", *args, "-o", str(Path(tmp) / "out"), "--quiet"])
        assert code in (0, None), code
        return json.loads(buf.getvalue())


def main() -> None:
    a, b = read_cloud(DATA / "p64.pcd").points, read_cloud(DATA / "qt.pcd").points
    E = rig_extrinsic(read_extrinsic(DATA / "p64-to-qt-extrinsic.json"))
    direction = {}
    for name, start in (("file as B's pose in A's frame (a = E b)", E), ("its inverse (b = E a)", np.linalg.inv(E))):
        T, before, after = icp(b, a, start)
        direction[name] = {"fitness_before": before, "fitness_after_icp": after, "icp_moved_m_deg": moved(start, T)}
        if name.startswith("its inverse"):
            refined = T
    print(json.dumps(direction, indent=1))
    out = {"machine": machine(), "direction": direction, "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        pose = Path(tmp) / "qt_in_p64_icp.txt"
        np.savetxt(pose, refined)
        for target in ("hesai_pandarqt64_pjlab", "hesai_pandarqt64"):
            for how, flag in (("extrinsic", ["--extrinsic", str(DATA / "p64-to-qt-extrinsic.json")]),
                              ("extrinsic refined by ICP", ["--transform", str(pose)])):
                res = run([str(DATA / "p64.pcd"), str(DATA / "qt.pcd"), "--source-sensor", "hesai_pandar64",
                           "--target-sensor", target, *flag])
                key = f"{target}, {how}"
                out["runs"][key] = res
                print(f"\n### {key}\n\n{markdown_table(res['table'], list(COLUMNS))}\n")
                print(json.dumps(res["source_reach"]))
                print(markdown_table(res["reach_table"], list(REACH)))
    save("cross_sensor", out)


if __name__ == "__main__":
    main()
