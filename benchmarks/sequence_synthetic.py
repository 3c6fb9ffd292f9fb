"""The synthetic drive with truth (docs/sequences.md): a rectangle street, parked boxes, one moving
box, 24 frames of one HDL-64E S2 (0.8 m apart, exact poses through KITTI's Tr), every 4th frame
from 4 to 20 held out and re-simulated from its +-2 window by every method.

``--unit exact`` (the default): the frames scanned along the table's pulse centres, the moving box's
points left out of the union (labels) and kept; writes benchmarks/results/sequence_synthetic.json.

``--unit real``: the frames scanned by one real-like unit (``synthetic.REAL_UNIT``: beams off the
table, per-beam range offsets, range noise, lost pulses), written in KITTI's scan order (beams known),
each held-out frame scored against its noisy self (``noisy``, as on real data) and, for the removals of
``--truth`` (each a second run), against the noiseless scan of the same pulses (``truth``: where the
unit's kept pulses hit the street, without its per-beam offsets or noise), with the moving box
removed by its labels, by see-through (``visibility``) and not at all (``none``); writes
benchmarks/results/sequence_synthetic_real.json.

    python benchmarks/sequence_synthetic.py
    python benchmarks/sequence_synthetic.py --unit real --truth labels visibility none

The ``rays`` rows' last digits (<= 1.9e-12 relative) depend on the kernels OpenBLAS picks for the CPU:
``OPENBLAS_CORETYPE=Zen`` on an AVX-512 host reproduces the committed JSON bit for bit (docs/sequences.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

from common import machine, save  # puts this checkout first on the path

from slr_ray.evaluate import markdown_table
from slr_ray.sequence import METHODS, REMOVE_MOVING, SeeThrough, evaluate_sequence, mean_rows, read_sequence
from slr_ray.sequence.synthetic import REAL_UNIT, UNITS, synthetic_drive

COLUMNS = ["method", "points", "F@5cm", "F@10cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2",
           "R@10cm seen"]
SENSOR = "velodyne_hdl64e_s2"
HELD_OUT = range(4, 21, 4)


def _frames(res):
    return [{k: v for k, v in f.items() if k != "rows"} for f in res["frames"]]


def _removal(how):
    return {"drop_moving": how in ("labels", "both"),
            "see_through": SeeThrough(SENSOR) if how in ("visibility", "both") else None}


def _print(key, frames, mean):
    print(f"\n{key}: mean over held-out frames {[f['frame'] for f in frames]}, unseen share "
          f"{sum(f['unseen_share'] for f in frames) / len(frames):.3f}")
    print(markdown_table(mean, COLUMNS))


def exact(methods) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_drive(Path(tmp) / "drive", n_frames=24, sensor=SENSOR)
        seq = read_sequence(Path(tmp) / "drive")
        out = {"machine": machine(), "unit": "exact"}
        for drop in (True, False):
            res = evaluate_sequence(seq, HELD_OUT, SENSOR, methods, half=2, drop_moving=drop)
            key = "moving_left_out" if drop else "moving_kept"
            _print(key, res["frames"], res["mean"])
            out[key] = {"mean": res["mean"], "frames": _frames(res)}
    return out


def real(methods, removals, truth_removals) -> dict:
    """Each removal: every held-out frame scored against its noisy self and against the truth (the
    sequence with the held-out frame's file swapped for its noiseless scan: the union, its ray model
    and its see-through votes come from the other, noisy frames only)."""
    out = {"machine": machine(), "unit": "real", "departures": REAL_UNIT, "unit_seed": 0,
           "truth": "the noiseless scan of the held-out frame's kept pulses (its table fitted to it)",
           "noisy": "the held-out frame as written (range noise, per-beam offsets, lost pulses)"}
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_drive(Path(tmp) / "drive", n_frames=24, sensor=SENSOR, unit="real", truth=Path(tmp) / "truth")
        seq, truth = read_sequence(Path(tmp) / "drive"), read_sequence(Path(tmp) / "truth")
        for how in removals:
            kw = _removal(how)
            res = evaluate_sequence(seq, HELD_OUT, SENSOR, methods, half=2, **kw)
            _print(f"{how}, against the noisy frame", res["frames"], res["mean"])
            out[how] = {"noisy": {"mean": res["mean"], "frames": _frames(res)}}
            if how not in truth_removals:
                continue
            frames_t = []
            for h in HELD_OUT:
                paths = list(seq.paths)
                paths[h] = truth.paths[h]
                frames_t += evaluate_sequence(dataclasses.replace(seq, paths=paths), [h], SENSOR, methods, half=2,
                                              **kw)["frames"]
            mean_t = mean_rows([f["table"] for f in frames_t])
            _print(f"{how}, against the truth", frames_t, mean_t)
            out[how]["truth"] = {"mean": mean_t, "frames": [{k: v for k, v in f.items() if k != "rows"}
                                                            for f in frames_t]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--unit", choices=UNITS, default="exact")
    ap.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    ap.add_argument("--remove-moving", nargs="+", choices=REMOVE_MOVING, default=["labels", "visibility", "none"],
                    help="--unit real: the removals measured")
    ap.add_argument("--truth", nargs="*", choices=REMOVE_MOVING, default=["labels"],
                    help="--unit real: the removals also scored against the truth (each a second run)")
    args = ap.parse_args()
    if args.unit == "exact":
        save("sequence_synthetic", exact(args.methods))
    else:
        save("sequence_synthetic_real", real(args.methods, args.remove_moving, args.truth))


if __name__ == "__main__":
    main()
