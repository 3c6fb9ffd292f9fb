"""Every sensor effect's output on a fixed cloud and seed, fingerprinted: the check that a
change to how effects run (issue #39: divergence and motion as stages, the effects resolved
once) leaves every result as it was.

    python benchmarks/effects_fingerprints.py [OTHER_CHECKOUT]

Runs :func:`slr_ray.effects.simulate` with each effect alone and in combination (ideal,
noise, range limits, intensity, divergence with one and all returns, motion in both frames,
motion with divergence, a sensor's 'sensor' divergence, a scan made elsewhere) on the
binning and embree backends, and hashes each result's points, indices, ranges, pulses,
return numbers, shares and intensity, with its ``info`` (timings left out). With
``OTHER_CHECKOUT`` (``git archive COMMIT slr_ray | tar -x -C DIR``), the same in a process
of that checkout, and says which results differ. Saves results/effects_fingerprints.json.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def fingerprints() -> dict:
    """``{case: [hash, returns, frame, info]}`` of this process's slr_ray."""
    import numpy as np

    import slr_ray
    from slr_ray.effects import Effects, pose, simulate, simulate_given

    rng = np.random.default_rng(0)
    ground = rng.uniform(-10, 10, (6000, 3))
    ground[:, 2] = -1.5
    wall = rng.uniform(-10, 10, (3000, 3))
    wall[:, 0] = 8
    box = rng.uniform(-2, 2, (2000, 3)) + [3, 3, 0]
    pts = np.vstack([ground, wall, box])
    inten = rng.uniform(0, 1, len(pts))

    def fp(es):
        h = hashlib.sha256()
        for a in (es.points, es.indices, es.ranges, es.pulses, es.return_number, es.number_of_returns, es.share):
            h.update(np.ascontiguousarray(a).tobytes())
        if es.intensity is not None:
            h.update(es.intensity.tobytes())
        info = {k: v for k, v in es.info.items() if k != "seconds"}
        return [h.hexdigest()[:16], len(es), es.frame, json.dumps(info, sort_keys=True, default=str)]

    poses = [pose((0, 0, 0)), pose((0.5, 0.1, 0), yaw_deg=3)]
    cases = {
        "ideal": ({}, None), "noise": ({"range_noise": 0.02, "seed": 3}, None),
        "limits": ({"min_range": 3.0, "max_range_at": (8, 0.5)}, None), "intensity": ({"intensity": "carry"}, None),
        "divergence": ({"divergence_mrad": 3.0}, None),
        "divergence_all": ({"divergence_mrad": 3.0, "returns": ["all"], "beam_rings": 2, "intensity": "carry",
                            "range_noise": 0.01}, None),
        "motion": ({"motion": True}, poses),
        "motion_firing": ({"motion": True, "motion_frame": "firing", "sweep_start_deg": 180,
                           "sweep_clockwise": True}, poses),
        "motion_divergence": ({"motion": True, "divergence_mrad": 2.0, "motion_sectors": 16}, poses),
    }
    out = {}
    for backend, opts in (("binning", {}), ("embree", {"radius": 0.15})):
        scanner = slr_ray.prepare(pts, backend, opts)
        for name, (eff, p) in cases.items():
            if backend == "binning" and eff.get("divergence_mrad"):
                continue  # refused: binning casts no rays
            es = simulate(scanner, None if p is not None else [0.1, 0.2, 0.0], 0.8, Effects(**eff),
                          intensity=inten, poses=p)
            out[f"{backend}:{name}"] = fp(es)
    scanner = slr_ray.prepare(pts, "embree", {"radius": 0.15})
    out["embree:sensor_divergence"] = fp(simulate(scanner, [0.1, 0.2, 0.0], slr_ray.sensor("velodyne_vls128"),
                                                  Effects(range_noise=0.01, divergence_mrad="sensor", beam_rings=2),
                                                  intensity=inten))
    scan = slr_ray.simulate_scan(pts, [0.1, 0.2, 0], 0.8)
    out["given"] = fp(simulate_given(scan, pts, {"range_noise": 0.01, "intensity": "carry"}, intensity=inten))
    return out


def main() -> None:
    from common import RESULTS, machine

    def run(checkout: Path) -> dict:
        env = {**os.environ, "PYTHONPATH": str(checkout)}
        code = (f"import sys; sys.path.insert(0, {str(checkout)!r}); sys.path.insert(1, {str(HERE)!r}); "
                "import effects_fingerprints as m, json; print(json.dumps(m.fingerprints()))")
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True,
                              cwd="/")
        return json.loads(done.stdout.strip().splitlines()[-1])

    mine = run(HERE.parent)
    doc = {"machine": machine(), "this": mine}
    if len(sys.argv) > 1:
        other = run(Path(sys.argv[1]).resolve())
        differ = sorted(k for k in set(mine) | set(other) if mine.get(k) != other.get(k))
        doc.update(other_checkout=sys.argv[1], other=other, differ=differ)
        print(f"{len(mine)} cases; differ from {sys.argv[1]}: {differ or 'none'}")
    else:
        print(f"{len(mine)} cases fingerprinted")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "effects_fingerprints.json").write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
