"""``rays`` and ``sequence evaluate`` on awkward sequences: what each gives, or how it refuses.

A 4-frame VLP-16 synthetic drive (slr_ray.sequence.synthetic, no moving box) and variants of it:
every frame held out (both ends included); two frames only; the window's frames or all frames with
their points shuffled (beams not known: a warning, the frame left out of the fit / the shipped table's
grid); the frames evaluated as another sensor (HDL-64E); a static sensor (one frame copied at one
pose); the poses translated by (1e6, -2e6, 300) m (every figure must match to 1e-6); a frame of 10
points; NaN rows. fpa and rays, each held-out frame's F@5cm, depth MedAE (m), drop accuracy, the ray
model's source and skew, and the warnings raised.

    PYTHONPATH=. python benchmarks/sequence_edge_cases.py

Writes benchmarks/results/sequence_edge_cases.json."""

from __future__ import annotations

import dataclasses
import json
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
from common import RESULTS, machine  # noqa: F401  (puts this checkout first on the path)

from slr_ray.io import PointCloud, read_cloud, write_cloud
from slr_ray.sequence import evaluate_sequence, read_sequence
from slr_ray.sequence.synthetic import synthetic_drive

M = ("fpa", "rays")


def summary(res):
    out = {}
    for f in res["frames"]:
        for r, m in zip(f["table"], M):
            out[f"{f['frame']} {m}"] = [round(r["F@5cm"], 4), round(r["depth_medae_m"], 4), round(r["drop_accuracy"], 4)]
        model = f["ray_model"] or {}
        out[f"{f['frame']} ray model"] = [model.get("source"), model.get("skew"), f["pattern"]["beams_known"]]
    return out


def run(seq, holdout, sensor="velodyne_vlp16"):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            res = {"figures": summary(evaluate_sequence(seq, holdout, sensor, M, half=2))}
        except Exception as e:  # noqa: BLE001  (the refusal is the result)
            res = {"refused": f"{type(e).__name__}: {e}"}
    res["warnings"] = sorted({str(w.message) for w in caught if "slr_ray" in type(w.message).__module__})
    return res


def shuffled(root, frames):
    for i in frames:
        f = root / "velodyne" / f"{i:06d}.bin"
        c = read_cloud(f)
        o = np.random.default_rng(i).permutation(len(c.points))
        write_cloud(f, PointCloud(c.points[o], {k: v[o] for k, v in c.attributes.items()}, c.origin))


def main() -> None:
    tmp = Path(tempfile.mkdtemp(prefix="seq_edges_"))
    drive = tmp / "drive"
    synthetic_drive(drive, n_frames=4, sensor="velodyne_vlp16", step=0.8, moving=False)

    def copy(name):
        d = tmp / name
        shutil.copytree(drive, d)
        return d

    seq = read_sequence(drive)
    cases = {"every frame held out (ends included)": run(seq, [0, 1, 2, 3])}
    two = copy("two")
    for i in (2, 3):
        (two / "velodyne" / f"00000{i}.bin").unlink()
        (two / "labels" / f"00000{i}.label").unlink()
    (two / "poses.txt").write_text("\n".join((two / "poses.txt").read_text().splitlines()[:2]) + "\n")
    cases["two frames"] = run(read_sequence(two), [0, 1])
    sh = copy("shuffled")
    shuffled(sh, (0, 2, 3))
    cases["the window's frames shuffled"] = run(read_sequence(sh), [1])
    shuffled(sh, (1,))
    cases["every frame shuffled"] = run(read_sequence(sh), [1])
    cases["VLP-16 frames evaluated as an HDL-64E"] = run(seq, [1], "velodyne_hdl64e_s2")
    st = copy("static")
    for i in (0, 2, 3):
        shutil.copy(st / "velodyne" / "000001.bin", st / "velodyne" / f"00000{i}.bin")
        shutil.copy(st / "labels" / "000001.label", st / "labels" / f"00000{i}.label")
    cases["static sensor (one frame, one pose)"] = run(
        dataclasses.replace(read_sequence(st), poses=np.repeat(seq.poses[1:2], len(seq), axis=0)), [0, 1])
    far = seq.poses.copy()
    far[:, :3, 3] += [1e6, -2e6, 300.0]
    near_res, far_res = run(seq, [1]), run(dataclasses.replace(seq, poses=far), [1])
    same = all(np.allclose(a, b, rtol=1e-6, atol=1e-6) for k, a in near_res["figures"].items()
               if "model" not in k for b in [far_res["figures"][k]])
    cases["poses translated by 1e6 m"] = far_res | {"equal to the untranslated to 1e-6": bool(same)}
    few = copy("few")
    f = few / "velodyne" / "000002.bin"
    c = read_cloud(f)
    write_cloud(f, PointCloud(c.points[:10], {k: v[:10] for k, v in c.attributes.items()}, c.origin))
    lab = few / "labels" / "000002.label"
    lab.write_bytes(lab.read_bytes()[:40])
    cases["a window frame of 10 points"] = run(read_sequence(few), [1])
    cases["a held-out frame of 10 points"] = run(read_sequence(few), [2])
    nan = copy("nan")
    f = nan / "velodyne" / "000002.bin"
    raw = np.fromfile(f, np.float32).reshape(-1, 4)
    raw[5:8, :3] = np.nan
    raw.tofile(f)
    cases["NaN rows in a frame"] = run(read_sequence(nan), [1])
    shutil.rmtree(tmp)
    for k, v in cases.items():
        print(k, json.dumps(v))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sequence_edge_cases.json").write_text(json.dumps({"machine": machine(), "cases": cases}, indent=1))


if __name__ == "__main__":
    main()
