"""``embree-rays`` (the registered sequence method: rays' fitted sensor cast with Embree onto each source
frame's ring mesh, slr_ray.sequence.embree_rays) against ``rays`` and the other methods on the four KITTI
frames (poses: docs/sequence_kitti/poses.txt, the ones ``--register`` wrote), frames 1 and 2 held out,
scored as ``slr-ray sequence evaluate`` scores them; a few of its settings (``--embree-rays-*``).

Then the speed (``--runs`` runs, medians; process CPU seconds, ``time.process_time``, the scoring left
out; ``rays`` and ``embree-rays`` one after the other in the same run, their order alternated):

* ``rays``: each held-out frame's ``simulate`` (its fit on the other frames and its cast; it holds
  nothing between frames);
* ``embree-rays``, a sequence's pass: the held-out frames one after the other on one frames cache (as
  ``sequence evaluate`` runs them: each frame's mesh, own fit and bias casts made once, then held),
  per held-out frame (the total over them / their count), for frames 1, 2 and for every frame 0-3;
* ``embree-rays``, one frame cold: a fresh cache (its frames read, nothing derived) for each held-out
  frame.

Writes benchmarks/results/sequence_embree_rays.json (``--ouster``: also the Ouster OS1-128's frames,
each held out from the others, into sequence_embree_rays_ouster.json; the other units' figures of
docs/sequences.md are the command line's, benchmarks/results/sequence_embree_rays_sensors/)."""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np
from common import machine, save  # noqa: F401  (puts this checkout first on the path)

import slr_ray.sequence.holdout as H
from slr_ray.evaluate import fitted_pattern
from slr_ray.sensors import sensor
from slr_ray.sequence import FrameCache, accumulate, read_sequence, to_frame, window
from slr_ray.sequence.embree_rays import frame_beams
from slr_ray.sequence.methods import REGISTRY, HeldOut

DATA = next((p for p in (Path(__file__).resolve().parents[i] / "shared" / "data" for i in (1, 2, 3)) if p.is_dir()),
            Path("/work/shared/data"))
POSES = Path(__file__).resolve().parents[1] / "docs" / "sequence_kitti" / "poses.txt"
METHODS = ("zbuffer", "adjacent", "nearest", "fpa", "rays", "embree-rays")
VARIANTS = {"no weak-triangle rule": {"embree_rays_weak_ratio": 0}, "weak 0.05": {"embree_rays_weak_ratio": 0.05},
            "ratio 0.5": {"embree_rays_max_ratio": 0.5}, "gap 0.1": {"embree_rays_gap": 0.1},
            "fill 1 (every pulse the meshes miss that holds a union point: fpa)": {"embree_rays_fill": 1},
            "fill 3": {"embree_rays_fill": 3},
            "porous 0 (the first surface: before #46's see-through)": {"embree_rays_porous": 0},
            "porous window 1, margin 1, from 0 m": {"embree_rays_porous": 1.0, "embree_rays_porous_window": 1,
                                                     "embree_rays_porous_beyond": 0}}
KEYS = ("points", "F@5cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2", "cd_sim_to_real_m2",
        "cd_real_to_sim_m2")


def directions(ev):
    """Each mean row with the Chamfer distance's two terms (m², means over the frames): the simulation's
    points to the real frame (precision side) and the real frame's to the simulation (coverage side)."""
    for k, row in enumerate(ev["mean"]):
        pts = [f["rows"][k]["points"] for f in ev["frames"]]
        row["cd_sim_to_real_m2"] = statistics.mean(p["to_target"] for p in pts)
        row["cd_real_to_sim_m2"] = statistics.mean(p["to_simulated"] for p in pts)
    return ev["mean"]


def show(rows):
    print("| method | " + " | ".join(KEYS) + " |")
    for r in rows:
        print(f"| {r['method']} | " + " | ".join(f"{r[k]:,}" if k == "points" else f"{r[k]:.4f}" for k in KEYS) + " |")


def helds(seq, targets, cache, base):
    """Each held-out frame's HeldOut as evaluate_holdout makes it (its grid fitted to its points)."""
    out = {}
    for t in targets:
        others = window(seq, t, 2)
        fb, _ = cache.get(t)
        pat = fitted_pattern(fb.points, frame_beams(fb, base), base)
        union = accumulate(seq, others, cache=cache, exclude=(t,))
        out[t] = HeldOut(seq, t, others, union, to_frame(union.points, fb.pose), pat, base, cache, fb.pose)
    return out


def fresh_cache(seq):
    cache = FrameCache(seq)
    for i in range(len(seq)):
        cache.get(i)
    return cache


def cpu(fn):
    c = time.process_time()
    fn()
    return time.process_time() - c


def speed(seq, runs):
    base = sensor("velodyne_hdl64e_s2")
    rays, er = REGISTRY["rays"], REGISTRY["embree-rays"]
    ro, eo = rays.options(), er.options()
    rec: dict = {}

    def add(key, v):
        rec.setdefault(key, []).append(v)

    for run in range(runs):
        for targets in ((1, 2), (0, 1, 2, 3)):
            name = "+".join(map(str, targets))
            cache = fresh_cache(seq)
            held = helds(seq, targets, cache, base)
            order = ("rays", "er") if run % 2 == 0 else ("er", "rays")
            for which in order:
                if which == "rays":
                    per = [cpu(lambda h=held[t]: rays.simulate(h, ro)) for t in targets]
                    add(f"rays {name}: per held-out frame", statistics.mean(per))
                else:  # the sequence's pass: one cache, each frame's state made once
                    per = [cpu(lambda h=held[t]: er.simulate(h, eo)) for t in targets]
                    add(f"embree-rays {name}: per held-out frame (a sequence's pass)", statistics.mean(per))
            # one frame cold: a fresh cache (its frames read) each
            cold = []
            for t in targets:
                c2 = fresh_cache(seq)
                h = helds(seq, (t,), c2, base)[t]
                cold.append(cpu(lambda h=h: er.simulate(h, eo)))
            add(f"embree-rays {name}: one held-out frame cold", statistics.mean(cold))
    med = {k: round(statistics.median(v), 4) for k, v in rec.items()}
    for name in ("1+2", "0+1+2+3"):
        r = med[f"rays {name}: per held-out frame"]
        med[f"ratio {name}: rays / embree-rays (sequence's pass)"] = round(
            r / med[f"embree-rays {name}: per held-out frame (a sequence's pass)"], 2)
        med[f"ratio {name}: rays / embree-rays (cold)"] = round(r / med[f"embree-rays {name}: one held-out frame cold"], 2)
    return {"runs": runs, "median_cpu_s": med, "all_cpu_s": rec}


def ouster():
    """The Ouster OS1-128's three frames of shared/data (ouster_os1_128/, read by its layout: the lidar
    origin, the poses), every frame held out from the others (``--half 1``), on its own grid."""
    seq = read_sequence(str(DATA / "ouster_os1_128"))
    ev = H.evaluate_sequence(seq, [0, 1, 2], sensor="ouster_os1_128", methods=METHODS, half=1)
    rows = directions(ev)
    fill = H.evaluate_sequence(seq, [0, 1, 2], sensor="ouster_os1_128", methods=("embree-rays",), half=1,
                               method_options={"embree_rays_fill": 1})
    return {"mean": rows + [directions(fill)[0] | {"method": "embree-rays, fill 1"}]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--ouster", action="store_true", help="the Ouster OS1-128's frames too")
    ap.add_argument("--ouster-only", action="store_true", help="the Ouster OS1-128's frames only")
    a = ap.parse_args()
    a.ouster = a.ouster or a.ouster_only
    res = {"machine": machine(), "load_before": os.getloadavg()}
    if a.ouster:
        res["ouster_os1_128"] = ouster()
        show(res["ouster_os1_128"]["mean"])
        save("sequence_embree_rays_ouster", res | {"load_after": os.getloadavg()})
        if a.ouster_only:
            return
    seq = read_sequence([str(DATA / f"kitti_hdl64_00000{i}.bin") for i in range(4)], str(POSES))
    if not a.skip_accuracy:
        ev = H.evaluate_sequence(seq, [1, 2], methods=METHODS)
        rows = directions(ev)
        for name, opts in VARIANTS.items():
            v = directions(H.evaluate_sequence(seq, [1, 2], methods=("embree-rays",), method_options=opts))[0]
            rows.append(v | {"method": f"embree-rays, {name}"})
        res["accuracy"] = {"mean": rows, "frames": [f["table"] for f in ev["frames"]]}
        show(rows)
    res["speed"] = speed(seq, a.runs)
    res["load_after"] = os.getloadavg()
    for k, v in res["speed"]["median_cpu_s"].items():
        print(f"{k}: {v}")
    save("sequence_embree_rays" if not a.skip_accuracy else "sequence_embree_rays_speed", res)


if __name__ == "__main__":
    main()
