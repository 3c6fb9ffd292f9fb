"""``embree-rays`` (slr_ray.sequence.embree_rays: rays' fitted sensor cast with Embree onto each source
frame's ring mesh) against ``rays`` and the other methods on the four KITTI frames, frames 1 and 2 held
out (poses: docs/sequence_kitti/poses.txt, the ones ``--register`` wrote), scored as ``slr-ray sequence
evaluate`` scores a method (the holdout machinery; the method hooked in here until the sequence
methods' registry takes it). Then the speed: each held-out frame's simulation by ``rays`` (its fit on
the other frames and its cast) and by ``embree-rays`` (the same fit, or the biases against the meshes;
its meshes and its cast), CPU and wall seconds, medians of ``--runs`` runs, the two one after the other
in one process (same-run ratios), the scoring left out. Also: where ``rays``' time goes.

Writes benchmarks/results/sequence_embree_rays.json."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np
from common import RESULTS, machine  # noqa: F401  (puts this checkout first on the path)

import slr_ray.sequence.holdout as H
import slr_ray.sequence.embree_rays as E
from slr_ray.evaluate import fitted_pattern
from slr_ray.sensors import sensor
from slr_ray.sequence import FrameCache, accumulate, read_sequence, to_frame, window
from slr_ray.sequence.rays import cast_rays, fit_ray_model, frame_motion

DATA = next((p for p in (Path(__file__).resolve().parents[i] / "shared" / "data" for i in (1, 2, 3)) if p.is_dir()),
            Path("/work/shared/data"))
POSES = Path(__file__).resolve().parents[1] / "docs" / "sequence_kitti" / "poses.txt"
NAME = "embree-rays"
LABEL = "the fitted sensor cast with Embree onto the frames' ring meshes (embree-rays)"


def fit_parts(seq, others, base, pattern, cache, bias="planes", meshes=None):
    """rays' model (lines and skew, then the range biases: ``planes`` as rays fits them, ``meshes``
    against the other frames' raw meshes (``meshes``: a MeshFrames to keep them in), ``none``) and each
    part's CPU seconds."""
    t0 = time.process_time()
    frames, worlds = [], []
    for i in others:
        f, w = cache.get(i)
        b = E.frame_beams(f, base)
        frames.append((f.points, b, frame_motion(seq.poses, i)))
        worlds.append((w, b, seq.poses[i], frames[-1][2]))
    model = fit_ray_model(frames, base.n_beams)
    t1 = time.process_time()
    if bias == "planes":
        model = H.fit_range_bias(model, worlds)
    elif bias == "meshes":
        raw = E.union_meshes(cache, others, base, None, meshes=meshes)
        model = E.mesh_range_bias(model, [(f[0], f[1], w[2], f[2]) for f, w in zip(frames, worlds)], raw)
    return model, {"lines_and_skew": t1 - t0, "range_bias": time.process_time() - t1}


VARIANTS = {NAME: {"library": True},
            f"{NAME}, rays' model (biases against the union's planes), vertices unbiased": {},
            f"{NAME}, rays' model, raw meshes": {"raw": True},
            f"{NAME}, no range bias": {"bias": "none"}, f"{NAME}, no weak triangles rule": {"weak": None},
            f"{NAME}, weak 0.15": {"weak": 0.15}, f"{NAME}, weak 0.05": {"weak": 0.05},
            f"{NAME}, ratio 0.5": {"max_ratio": 0.5}, f"{NAME}, ratio 1": {"max_ratio": 1.0},
            f"{NAME}, gap 0.1": {"gap": 0.1}}
_MODELS = {}


def hook():
    """embree-rays and its variants as holdout methods (a local hook: the registry will take it)."""
    orig = H._simulate

    def simulate(m, held, models):
        if m not in VARIANTS:
            return orig(m, held, models)
        v = VARIANTS[m]
        motion = frame_motion(held.seq.poses, held.target)
        if v.get("library"):  # the library's pipeline: fit_embree_model, then cast_embree_rays
            model, s = E.fit_embree_model(held.seq, held.others, held.base, held.cache, None, held.drop_moving,
                                          held.see_through, (held.target,))
            models[m] = model.to_dict()
            ret = E.cast_embree_rays(held.u, held.pattern, model, motion, surfaces=s, pose=held.pose)
            return ret, ret.points
        key = (held.target, v.get("bias", "planes"))
        if key not in _MODELS:
            _MODELS[key] = fit_parts(held.seq, held.others, held.base, held.pattern, held.cache, key[1])[0]
        model = _MODELS[key]
        meshes = E.MeshFrames(v.get("max_ratio", E.MAX_RATIO), weak_ratio=v.get("weak", E.WEAK_RATIO))
        s = E.union_meshes(held.cache, held.others, held.base, None if v.get("raw") else model, held.drop_moving,
                           held.see_through,
                           (held.target,), meshes)
        ret = E.cast_embree_rays(held.u, held.pattern, model, frame_motion(held.seq.poses, held.target),
                                 v.get("gap", E.EMBREE_GAP), surfaces=s, pose=held.pose)
        return ret, ret.points

    H._simulate = simulate
    H.METHODS = H.METHODS + tuple(VARIANTS)
    H.LABELS.update({k: (LABEL if k == NAME else k) for k in VARIANTS})


def speed(seq, targets, runs):
    """Per held-out frame, medians of ``runs``: rays (fit + cast) and embree-rays (fit + meshes + cast)."""
    base = sensor("velodyne_hdl64e_s2")
    out = []
    for t in targets:
        cache = FrameCache(seq)
        others = window(seq, t, 2)
        fb, _ = cache.get(t)
        pat = fitted_pattern(fb.points, E.frame_beams(fb, base), base)
        u = to_frame(accumulate(seq, others, cache=cache).points, fb.pose)
        motion = frame_motion(seq.poses, t)
        rec = {k: [] for k in ("rays_cpu", "rays_wall", "rays_fit_cpu", "rays_cast_cpu", "rays_lines_cpu",
                               "rays_bias_cpu", "er_cpu", "er_wall", "er_fit_and_meshes_cpu", "er_cast_cpu",
                               "er_model_held_cpu", "er_model_held_wall", "er_cast_only_cpu", "er_cast_only_wall")}
        for _ in range(runs):
            c0, w0 = time.process_time(), time.perf_counter()
            model, parts = fit_parts(seq, others, base, pat, cache, "planes")
            c1 = time.process_time()
            cast_rays(u, pat, model, motion)
            c2, w2 = time.process_time(), time.perf_counter()
            rec["rays_cpu"].append(c2 - c0), rec["rays_wall"].append(w2 - w0), rec["rays_fit_cpu"].append(c1 - c0)
            rec["rays_cast_cpu"].append(c2 - c1), rec["rays_lines_cpu"].append(parts["lines_and_skew"])
            rec["rays_bias_cpu"].append(parts["range_bias"])
            # embree-rays (the library's pipeline): lines and skew as rays fits them, the biases against the
            # frames' raw meshes, the cast onto them (no k-d tree anywhere; each frame's mesh built once)
            c0, w0 = time.process_time(), time.perf_counter()
            m2, s = E.fit_embree_model(seq, others, base, cache)
            c1 = time.process_time()
            E.cast_embree_rays(u, pat, m2, motion, surfaces=s, pose=fb.pose)
            c2, w2 = time.process_time(), time.perf_counter()
            rec["er_cpu"].append(c2 - c0), rec["er_wall"].append(w2 - w0), rec["er_fit_and_meshes_cpu"].append(c1 - c0)
            rec["er_cast_cpu"].append(c2 - c1)
            # embree-rays with a model fitted before (a sequence's fit reused across targets): its raw meshes
            # and its cast
            c0, w0 = time.process_time(), time.perf_counter()
            s = E.union_meshes(cache, others, base, None)
            E.cast_embree_rays(u, pat, model, motion, surfaces=s, pose=fb.pose)
            c1, w1 = time.process_time(), time.perf_counter()
            rec["er_model_held_cpu"].append(c1 - c0), rec["er_model_held_wall"].append(w1 - w0)
            # the cast alone, the meshes held (a sliding window builds each frame's once)
            c0, w0 = time.process_time(), time.perf_counter()
            E.cast_embree_rays(u, pat, model, motion, surfaces=s, pose=fb.pose)
            c1, w1 = time.process_time(), time.perf_counter()
            rec["er_cast_only_cpu"].append(c1 - c0), rec["er_cast_only_wall"].append(w1 - w0)
        med = {k: round(statistics.median(v), 4) for k, v in rec.items()}
        med["ratio_cpu_rays_over_er"] = round(med["rays_cpu"] / med["er_cpu"], 2)
        med["ratio_cpu_rays_over_er_model_reused"] = round(med["rays_cpu"] / med["er_model_held_cpu"], 2)
        med["ratio_cpu_rays_over_er_cast_only"] = round(med["rays_cpu"] / med["er_cast_only_cpu"], 2)
        out.append({"frame": seq.names[t], "runs": runs, "median": med, "all": rec})
    return out


def ouster(tmp: Path):
    """The Ouster OS1-128's three frames of shared/data (ouster_os1_128/: each frame's xyz grid, its rows
    the rings, highest first; the poses in KITTI form), frame 1 held out from frames 0 and 2: each
    frame written as an .npz of its returns (``points``, ``ring``, ``intensity``) for the sequence
    reader."""
    src = DATA / "ouster_os1_128"
    files = []
    for i in range(3):
        z = np.load(src / f"os1_128_frame{i:02d}.npz")
        ok = z["range_mm"] > 0
        ring = np.broadcast_to(np.arange(ok.shape[0])[:, None], ok.shape)
        f = tmp / f"os1_128_{i:06d}.npz"
        np.savez(f, points=z["xyz"][ok].astype(np.float64), ring=ring[ok].astype(np.int64),
                 intensity=z["reflectivity"][ok].astype(np.float32))
        files.append(str(f))
    seq = read_sequence(files, str(next(src.glob("*_poses_kitti.txt"))))
    methods = ("zbuffer", "adjacent", "nearest", "fpa", "rays", NAME)
    ev = H.evaluate_sequence(seq, [1], sensor="ouster_os1_128", methods=methods, half=1)
    return {"mean": ev["mean"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--ouster-only", action="store_true", help="the Ouster OS1-128 frames only (written to "
                    "results/sequence_embree_rays_ouster.json)")
    a = ap.parse_args()
    keys = ("points", "F@5cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2")

    def show(rows):
        print("| method | " + " | ".join(keys) + " |")
        for r in rows:
            print(f"| {r['method']} | " + " | ".join(f"{r[k]:,}" if k == "points" else f"{r[k]:.4f}" for k in keys) + " |")

    if a.ouster_only:
        import tempfile
        hook()
        with tempfile.TemporaryDirectory() as tmp:
            res = {"machine": machine(), "load_before": os.getloadavg(), "ouster_os1_128": ouster(Path(tmp))}
        show(res["ouster_os1_128"]["mean"])
        (RESULTS / "sequence_embree_rays_ouster.json").write_text(json.dumps(res, indent=1, default=float))
        return
    seq = read_sequence([str(DATA / f"kitti_hdl64_00000{i}.bin") for i in range(4)], str(POSES))
    res = {"machine": machine(), "load_before": os.getloadavg()}
    if not a.skip_accuracy:
        hook()
        methods = ("zbuffer", "adjacent", "nearest", "fpa", "rays") + tuple(VARIANTS)
        ev = H.evaluate_sequence(seq, [1, 2], methods=methods)
        res["accuracy"] = {"mean": ev["mean"], "frames": [f["table"] for f in ev["frames"]]}
        show(ev["mean"])
    res["speed"] = speed(seq, [1, 2], a.runs)
    res["load_after"] = os.getloadavg()
    for s in res["speed"]:
        print(s["frame"], json.dumps(s["median"]))
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / "sequence_embree_rays.json"
    if a.skip_accuracy and out.exists():  # the speed again: the accuracy of the last full run kept
        res = json.loads(out.read_text()) | {"speed": res["speed"], "speed_load": [res["load_before"], res["load_after"]]}
    out.write_text(json.dumps(res, indent=1, default=float))


if __name__ == "__main__":
    main()
