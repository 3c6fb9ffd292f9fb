"""Real-pair evaluation (issue #28): KITTI frame 1 re-simulated from frame 0, and a synthetic pair with truth.

1. KITTI: ``slr-ray evaluate kitti_hdl64_000000.bin kitti_hdl64_000001.bin -o docs/evaluate_kitti --force``
   (the command a user runs; beams from the files' scan order); frame 000000 against itself beside it
   (``table_self.md``: each method's floor).
2. Synthetic: a rectangle scene (500 rectangles within 40 m, ground 1.73 m below the sensor, as KITTI's),
   scanned as one real HDL-64E unit from two poses 0.65 m apart: the beams off the nominal table
   (``sensors.miscalibrated``: 0.1 deg per beam), the unit's per-beam range offsets (3 cm, the same for
   both frames) and each frame's own 1 cm range noise and 10 % lost pulses (``sensors.sensor_noise``).
   Evaluated like KITTI (registered, beams known); the true pose tells how far the registration is off.
   Written to docs/evaluate_synthetic.

Each evaluation runs ``--repeat`` times after a warm-up (numba compiles on the first); the median wall
time is quoted. Saves benchmarks/results/evaluate_pairs.json.

Run: ``PYTHONPATH=. nice python benchmarks/evaluate_pairs.py`` from the repository root (about two minutes).
The KITTI frames are not shipped: ``--kitti-dir`` names the folder holding ``kitti_hdl64_000000.bin`` and
``kitti_hdl64_000001.bin`` (frames of url-kaist/patchwork-plusplus, ``data/``; KITTI, CC BY-NC-SA 3.0);
without them the KITTI part is skipped with a message saying so, and the synthetic pair still runs.
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save  # noqa: E402

from slr_ray import scan_mesh, sensor  # noqa: E402
from slr_ray.cli import main as cli  # noqa: E402
from slr_ray.evaluate import evaluate_pair, evaluation_table, markdown_table, write_evaluation  # noqa: E402
from slr_ray.io import read_cloud  # noqa: E402
from slr_ray.plotting import evaluation_figure, save_figure  # noqa: E402
from slr_ray.scenes import rectangle_scene  # noqa: E402
from slr_ray.sensors import miscalibrated, sensor_noise  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
KITTI_NAMES = ("kitti_hdl64_000000.bin", "kitti_hdl64_000001.bin")
POSE_A, POSE_B = np.array([0.0, 0.0, 0.0]), np.array([0.6, 0.25, 0.0])


def synthetic_pair(seed: int = 0):
    """Two frames of one miscalibrated, noisy HDL-64E in a rectangle scene, each in its sensor's frame."""
    scene = rectangle_scene(500, seed=seed, xy_range=(-40.0, 40.0), ground_z=-1.73)
    unit = miscalibrated(sensor("velodyne_hdl64e_s2"), seed=seed)
    frames = []
    for k, o in enumerate((POSE_A, POSE_B)):
        ms = scan_mesh(scene, o, unit)
        beams = unit.beam_of_row[ms.pulses[:, 0]]
        # the unit's per-beam range offsets: one draw for both frames (seed), no noise or loss yet
        pts, _ = sensor_noise(ms.points, o, beams, range_sd=0.0, beam_range_sd=0.03, dropout=0.0, seed=seed)
        # each frame's own range noise and lost pulses
        pts, kept = sensor_noise(pts, o, beams, range_sd=0.01, beam_range_sd=0.0, dropout=0.1, seed=seed + 1 + k)
        frames.append((pts - o, beams[kept]))
    return frames


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--kitti-dir", type=Path, default=DATA, help="folder of the two KITTI frames")
    args = ap.parse_args()
    kitti = [args.kitti_dir / name for name in KITTI_NAMES]
    missing = [str(p) for p in kitti if not p.exists()]
    out = {"machine": machine(), "inputs": {"kitti": [str(p) for p in kitti], "repeat": args.repeat,
                                            "synthetic": {"rectangles": 500, "xy_range": [-40, 40],
                                                          "pose_a": POSE_A.tolist(), "pose_b": POSE_B.tolist()}}}

    if missing:
        print(f"KITTI part skipped: {', '.join(missing)} not found (the frames of url-kaist/patchwork-plusplus, "
              "data/; give their folder with --kitti-dir); docs/evaluate_kitti is left as it is", file=sys.stderr)
        out["kitti"] = {"skipped": f"not found: {missing}"}
    else:
        kitti_pair(kitti, args.repeat, out)
    synthetic(args.repeat, out)
    save("evaluate_pairs", out)


def kitti_pair(kitti, repeat, out):
    """The KITTI pair through the command, and frame 000000 against itself."""
    # 1. KITTI, through the command (what a user runs)
    argv = ["evaluate", *map(str, kitti), "-o", str(ROOT / "docs" / "evaluate_kitti"), "--force", "--quiet"]
    times = []
    for i in range(repeat + 1):
        buf = io.StringIO()
        t0 = time.perf_counter()
        with redirect_stdout(buf):
            assert cli(argv) == 0
        times.append(time.perf_counter() - t0)
        print(f"KITTI evaluate run {i}: {times[-1]:.2f} s{' (warm-up)' if i == 0 else ''}", flush=True)
    res = json.loads(buf.getvalue())
    # what a user waits for: a fresh process (interpreter, imports, numba's compile of each kernel) and the run
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "slr_ray.cli", *argv[:3], "-o", tmp, "--force", "--quiet"], check=True,
                       stdout=subprocess.DEVNULL)
        cold = time.perf_counter() - t0
    print(f"KITTI evaluate in a fresh process: {cold:.2f} s", flush=True)
    out["kitti"] = {"command": "slr-ray " + " ".join(argv), "seconds_fresh_process": cold, "seconds_runs": times,
                    "seconds_median_warm": statistics.median(times[1:]), "stages": res["seconds"],
                    "registration": res["registration"], "unseen_share": res["unseen_share"], "table": res["table"]}
    print(markdown_table(res["table"]), flush=True)

    # 1b. frame 000000 against itself (B = A, the identity given): what each method scores against the
    # frame it is made from, the floor under the pair's figures (the baseline must be perfect)
    a0 = read_cloud(kitti[0]).points
    own = evaluate_pair(a0, a0, transform=np.eye(4))
    (ROOT / "docs" / "evaluate_kitti" / "table_self.md").write_text(markdown_table(evaluation_table(own)) + "\n")
    out["kitti_self"] = {"frame": str(kitti[0]), "table": evaluation_table(own), "frames": own["frames"]}
    print("frame 000000 against itself:\n" + markdown_table(evaluation_table(own)), flush=True)



def synthetic(repeat, out):
    """The synthetic pair with truth, written to docs/evaluate_synthetic."""
    # 2. the synthetic pair with truth
    t0 = time.perf_counter()
    (a, ba), (b, bb) = synthetic_pair()
    t_scan = time.perf_counter() - t0
    times = []
    for i in range(repeat + 1):
        t0 = time.perf_counter()
        syn = evaluate_pair(a, b, a_beams=ba, b_beams=bb)
        times.append(time.perf_counter() - t0)
        print(f"synthetic evaluate run {i}: {times[-1]:.2f} s{' (warm-up)' if i == 0 else ''}", flush=True)
    T = np.array(syn["registration"]["transform"])
    pose_error = float(np.linalg.norm(T[:3, 3] - (POSE_B - POSE_A)))
    truth = evaluate_pair(a, b, a_beams=ba, b_beams=bb, transform=np.r_[np.c_[np.eye(3), POSE_B - POSE_A],
                                                                           [[0, 0, 0, 1]]])
    syn["truth"] = {"pose_b_in_a": (POSE_B - POSE_A).tolist(), "registration_translation_error_m": pose_error,
                    "table_at_true_pose": evaluation_table(truth)}
    write_evaluation(syn, ROOT / "docs" / "evaluate_synthetic", force=True,
                     inputs={"scene": "rectangle_scene(500, seed=0, xy_range=(-40, 40), ground_z=-1.73)",
                             "sensor": "miscalibrated(velodyne_hdl64e_s2, seed=0) with sensor_noise",
                             "pose_a": POSE_A.tolist(), "pose_b": POSE_B.tolist()})
    save_figure(evaluation_figure(syn), ROOT / "docs" / "evaluate_synthetic" / "evaluation.png")  # as the command
    (ROOT / "docs" / "evaluate_synthetic" / "table_true_pose.md").write_text(
        markdown_table(evaluation_table(truth)) + "\n")
    out["synthetic"] = {"scan_seconds": t_scan, "seconds_runs": times, "seconds_median_warm": statistics.median(times[1:]),
                        "stages": syn["seconds"], "registration": syn["registration"],
                        "registration_translation_error_m": pose_error, "unseen_share": syn["unseen_share"],
                        "table": evaluation_table(syn), "table_at_true_pose": evaluation_table(truth)}
    print(f"synthetic pair: registration off the true pose by {100 * pose_error:.1f} cm, "
          f"fitness {syn['registration']['fitness']:.3f}", flush=True)
    print(markdown_table(evaluation_table(syn)), flush=True)


if __name__ == "__main__":
    main()
