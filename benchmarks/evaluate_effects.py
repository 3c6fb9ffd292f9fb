"""The gain of each sensor effect (issue 29) on the real-pair evaluation's metrics (issue 28).

    PYTHONPATH=. nice python benchmarks/evaluate_effects.py [--seeds 5] [--pairs kitti synthetic]

Each pair as ``slr_ray.evaluate`` sets it up (B registered to A by ICP, beams from the files' scan
order, B's table fitted to B, A moved into B's frame), then B re-simulated from A at B's pose by the
evaluation's best SLR methods, embree with primary beams and binning, each with no effect (ideal),
each effect alone and all together, scored against the real B with ``slr_ray.metrics`` (Chamfer
distance, F-score at 5 and 10 cm, depth RMSE / MedAE and ray-drop accuracy / drop recall over B's
range image) and ``slr_ray.effects.scoring.intensity_metrics`` (simulated vs B's real intensity on
pulses where both return). Effects:

- range noise: sigma = the HDL-64E S2 table's ``range_accuracy_m`` (0.02 m);
- ray drop fitted on A's own frame (``frame_pulses`` + ``fit_ray_drop``; never on B, the target);
  the same fitted on B is reported as an **oracle** (an upper bound, not a usable setting);
- intensity carried, and corrected for range and incidence;
- beam divergence 2 and 3 mrad (no shipped value: a sensitivity), strongest return (one per pulse,
  as the frames hold), 19 sub-rays;
- motion during the sweep: A deskewed and B re-simulated from each column's pose, written as a raw
  frame (each return in its firing pose's frame), the per-sweep motion = the registration's pose
  delta (10 Hz: one frame = one sweep), timed clockwise from the rear (KISS-ICP's timing of KITTI raw
  frames) and, as a check of the timing, counter-clockwise from the front (the file order);
- all together: noise, drop (A's fit), carried intensity, divergence 2 mrad, motion.

Divergence and motion take embree's cast path (one return per pulse at the disc surface), which
differs from the ideal embree scan (the disc's point, each point once) with no effect at all, so
they are compared against that path with static poses ("ideal, cast path"). Random effects (noise,
drop, all) are run with ``--seeds`` seeds; the median of each figure is reported, with its range.
The motion hypothesis of docs/evaluation.md (the error image changes sign at the rear, column ~1005,
because KITTI's sweeps are not motion-compensated) is tested by the signed median depth error just
left and right of azimuth 180 deg ("rear jump") and the RMSE within 20 deg of it.

The synthetic pair is benchmarks/evaluate_pairs.py's (a mesh scene scanned by a miscalibrated,
noisy HDL-64E from two poses; no intensity, no motion during its sweeps): a control, where an
effect the data lack should not help.

Saves results/evaluate_effects.json and docs/figures/effects_gain.png; prints the tables.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save  # noqa: E402
from evaluate_pairs import KITTI, synthetic_pair  # noqa: E402

from slr_ray import prepare  # noqa: E402
from slr_ray.backends.embree import estimate_normals  # noqa: E402
from slr_ray.effects import Effects, deskew, fit_ray_drop, frame_pulses, intensity_metrics, range_image  # noqa: E402
from slr_ray.effects import rings_from_scan_order, simulate  # noqa: E402
from slr_ray.evaluate import fitted_pattern, register, scan_order_beams, zbuffer  # noqa: E402
from slr_ray.metrics import point_metrics, range_image_metrics  # noqa: E402
from slr_ray.sensors import sensor  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
THRESHOLDS = (0.05, 0.10)
REAR = 20.0  # degrees either side of azimuth 180 for the rear figures
KITTI_SWEEP = {"sweep_start_deg": 180.0, "sweep_clockwise": True}  # KISS-ICP's timing of KITTI raw frames
FILE_ORDER_SWEEP = {"sweep_start_deg": 0.0, "sweep_clockwise": False}


# --- a pair, set up as slr_ray.evaluate sets it up ------------------------------------------------------------

def setup(a, b, a_int, b_int, a_beams, b_beams):
    base = sensor("velodyne_hdl64e_s2")
    pat_a, pat_b = fitted_pattern(a, a_beams, base), fitted_pattern(b, b_beams, base)
    reg = register(b, a)
    T = reg.transform
    R, t = T[:3, :3], T[:3, 3]
    real = zbuffer(b, pat_b, beams=b_beams, backend="real").range_image()
    real_int = None
    if b_int is not None:
        real_int = np.where(real["index"] >= 0, b_int[np.maximum(real["index"], 0)], np.nan)
    return {"a": a, "b": b, "a_int": a_int, "b_int": b_int, "a_beams": a_beams, "b_beams": b_beams,
            "pat_a": pat_a, "pat_b": pat_b, "registration": reg.to_dict(), "R": R, "t": t,
            "a_in_b": (a - t) @ R, "a_origin": -(R.T @ t), "real": np.asarray(real["range"], np.float64),
            "real_intensity": real_int}


def sweep_poses(rot, trans):
    """Start and end pose of a sweep centred on the identity that moves by (rot, trans) in one sweep."""
    rv = Rotation.from_matrix(rot).as_rotvec()
    out = []
    for s in (-0.5, 0.5):
        p = np.eye(4)
        p[:3, :3] = Rotation.from_rotvec(s * rv).as_matrix()
        p[:3, 3] = s * np.asarray(trans)
        out.append(p)
    return np.array(out)


def drop_model(points, intensity, rings):
    nrm = estimate_normals(points, k=10, primary_origin=np.zeros(3))
    fp = frame_pulses(points, intensity=intensity, rings=rings, normals=nrm)
    return fit_ray_drop(fp["range"], fp["incidence"], fp["dropped"], fp["intensity"])


# --- scoring -------------------------------------------------------------------------------------------------

def score(pair, points, img, img_int):
    real = pair["real"]
    pm = point_metrics(pair["b"], points, thresholds=THRESHOLDS)
    im = range_image_metrics(real, img)
    nh = real.shape[1]
    az = (np.arange(nh) + 0.5) * 360.0 / nh
    both = np.isfinite(real) & np.isfinite(img)
    err = np.where(both, img - real, np.nan)
    left = err[:, (az >= 180 - REAR) & (az < 180)]
    right = err[:, (az >= 180) & (az < 180 + REAR)]
    rear = err[:, np.abs(az - 180) < REAR]
    sectors = [float(np.nanmedian(err[:, (az >= a0) & (az < a0 + 10)])) for a0 in range(0, 360, 10)]
    out = {"cd": pm.chamfer_sum, "F@5cm": pm.fscore[0.05]["fscore"], "F@10cm": pm.fscore[0.10]["fscore"],
           "P@5cm": pm.fscore[0.05]["precision"], "R@5cm": pm.fscore[0.05]["recall"],
           "rmse": im.rmse, "medae": im.medae, "drop_acc": im.accuracy, "drop_recall": im.drop_recall,
           "returns": im.simulated_returns, "points": int(len(points)),
           "rear_jump": float(np.nanmedian(right) - np.nanmedian(left)),
           "rear_left_median": float(np.nanmedian(left)), "rear_right_median": float(np.nanmedian(right)),
           "rear_rmse": float(np.sqrt(np.nanmean(rear ** 2))), "sector_median_error": sectors}
    ii = intensity_metrics(pair["real_intensity"], img_int) if pair["real_intensity"] is not None else \
        intensity_metrics(np.full(img.shape, np.nan), None)
    out |= {"int_mae": ii["mae"], "int_r": ii["pearson"], "int_bias": ii["bias"], "int_pulses": ii["pulses"]}
    return out


def run(pair, scanner, eff, normals, poses=None):
    es = simulate(scanner, None if poses is not None else np.zeros(3), pair["pat_b"], eff,
                  intensity=pair["a_int"], normals=normals, poses=poses, primary_origin=pair["a_origin"])
    ri = range_image(es)
    return score(pair, es.points, ri["range"], ri["intensity"])


def median_of(results):
    keys = [k for k in results[0] if k != "sector_median_error"]
    out = {k: statistics.median(r[k] for r in results) for k in keys}
    out["range"] = {k: [min(r[k] for r in results), max(r[k] for r in results)] for k in keys}
    out["sector_median_error"] = np.median([r["sector_median_error"] for r in results], axis=0).tolist()
    return out


# --- the variants ----------------------------------------------------------------------------------------------

def evaluate(name, pair, seeds):
    has_int = pair["a_int"] is not None
    a_int = pair["a_int"]
    t0 = time.perf_counter()
    fit_a = drop_model(pair["a"], a_int, rings_from_scan_order(pair["a"]) if name == "kitti" else pair["a_beams"])
    fit_b = drop_model(pair["b"], pair["b_int"], rings_from_scan_order(pair["b"]) if name == "kitti"
                       else pair["b_beams"])
    # motion: per-sweep motion = the registration's pose delta; A deskewed into its mid-sweep frame
    R, t = pair["R"], pair["t"]
    motion = {}
    for label, sweep in (("rear, clockwise", KITTI_SWEEP), ("front, counter-clockwise", FILE_ORDER_SWEEP)):
        a_mid = deskew(pair["a"], sweep_poses(R, t), sweep["sweep_start_deg"], sweep["sweep_clockwise"])
        motion[label] = {"a_in_b": (a_mid - t) @ R, "poses": sweep_poses(R, R.T @ t), "sweep": sweep}
    scanners, normals = {}, {}

    def scanner_of(method, key="raw"):
        if (method, key) not in scanners:
            pts = pair["a_in_b"] if key == "raw" else motion[key]["a_in_b"]
            opts = {} if method == "binning" else {"primary_origin": pair["a_origin"], "primary_pattern": pair["pat_a"],
                                                   "primary_beams": pair["a_beams"]}
            scanners[(method, key)] = prepare(pts, method, **opts)
            normals[(method, key)] = estimate_normals(pts, k=10, primary_origin=pair["a_origin"])
        return scanners[(method, key)], normals[(method, key)]

    static = np.array([np.eye(4), np.eye(4)])
    cast = {"motion": True, "motion_frame": "firing"}
    variants = []  # (method, variant, baseline variant, effects, poses, motion key, random)
    for m in ("embree", "binning"):
        variants += [(m, "ideal", None, {}, None, "raw", False)]
        if m == "embree":
            variants += [(m, "ideal, cast path", None, cast, static, "raw", False)]
        variants += [(m, "range noise 2 cm", "ideal", {"range_noise": "sensor"}, None, "raw", True),
                     (m, "ray drop (fit on A)", "ideal", {"ray_drop": fit_a}, None, "raw", True),
                     (m, "ray drop (fit on B: oracle)", "ideal", {"ray_drop": fit_b}, None, "raw", True)]
        if has_int:
            variants += [(m, "intensity carried", "ideal", {"intensity": "carry"}, None, "raw", False),
                         (m, "intensity corrected", "ideal", {"intensity": "correct"}, None, "raw", False)]
        if m == "embree":
            for d in (2.0, 3.0):
                variants += [(m, f"divergence {d:g} mrad", "ideal, cast path",
                              cast | {"divergence_mrad": d, "returns": "strongest"}, static, "raw", False)]
        base_m = "ideal, cast path" if m == "embree" else "ideal"
        mot = cast | ({} if m == "embree" else {"motion_sectors": 72})
        variants += [(m, "motion (sweep clockwise from the rear)", base_m, mot | KITTI_SWEEP, "rear, clockwise",
                      "rear, clockwise", False),
                     (m, "motion (sweep ccw from the front: file order)", base_m, mot | FILE_ORDER_SWEEP,
                      "front, counter-clockwise", "front, counter-clockwise", False),
                     (m, "A deskewed, B static (diagnostic)", "ideal", {}, None, "rear, clockwise", False)]
        all_eff = mot | KITTI_SWEEP | {"range_noise": "sensor", "ray_drop": fit_a}
        all_eff |= {"intensity": "carry"} if has_int else {}
        all_eff |= {"divergence_mrad": 2.0, "returns": "strongest"} if m == "embree" else {}
        variants += [(m, "all (noise, drop A, carry, " + ("div 2 mrad, " if m == "embree" else "") + "motion)",
                      base_m, all_eff, "rear, clockwise", "rear, clockwise", True)]
    rows = []
    for m, var, basev, eff, poses, key, random in tqdm(variants, desc=name):
        sc, nrm = scanner_of(m, key)
        pz = static if isinstance(poses, np.ndarray) else (motion[poses]["poses"] if poses else None)
        t1 = time.perf_counter()
        res = [run(pair, sc, Effects(**eff, seed=s), nrm, pz) for s in (range(seeds) if random else [0])]
        rows.append({"method": m, "variant": var, "baseline": basev, "seeds": len(res),
                     "seconds": time.perf_counter() - t1, "effects": Effects(**eff).to_dict(), **median_of(res)})
        if var == "ideal" and has_int:  # reference for intensity: a constant (A's median) on the same pulses
            img = range_image(simulate(sc, np.zeros(3), pair["pat_b"]))["range"]
            const = np.where(np.isfinite(img), float(np.median(a_int)), np.nan)
            rows[-1]["intensity_constant_reference"] = intensity_metrics(pair["real_intensity"], const)
    for r in rows:
        base = next((x for x in rows if x["method"] == r["method"] and x["variant"] == r["baseline"]), None)
        r["gain"] = {k: r[k] - base[k] for k in GAIN_KEYS} if base else None
    return {"rows": rows, "registration": pair["registration"], "drop_fit_a": fit_a.to_dict(),
            "drop_fit_b": fit_b.to_dict(), "seconds": time.perf_counter() - t0}


GAIN_KEYS = ("cd", "F@5cm", "F@10cm", "rmse", "medae", "drop_acc", "drop_recall", "rear_jump", "rear_rmse")


def fmt(v, nd=4):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    return f"{v:.{nd}f}" if isinstance(v, float) else str(v)


def table(rows, has_int):
    cols = ["CD (m²)", "F@5cm", "F@10cm", "RMSE (m)", "MedAE (m)", "drop acc", "drop recall", "rear jump (m)",
            "rear RMSE (m)"] + (["int MAE", "int r"] if has_int else [])
    keys = ["cd", "F@5cm", "F@10cm", "rmse", "medae", "drop_acc", "drop_recall", "rear_jump", "rear_rmse"] + \
        (["int_mae", "int_r"] if has_int else [])
    lines = ["| method | variant | seeds | " + " | ".join(cols) + " |", "|---|---|---|" + "---|" * len(cols)]
    for r in rows:
        lines.append(f"| {r['method']} | {r['variant']} | {r['seeds']} | " + " | ".join(fmt(r[k]) for k in keys) + " |")
        if "intensity_constant_reference" in r:
            c = r["intensity_constant_reference"]
            lines.append(f"| {r['method']} | ideal + constant intensity (A's median; reference) | 1 | "
                         + " | ".join("" for _ in keys[:-2]) + f" | {fmt(c['mae'])} | {fmt(c['pearson'])} |")
    return "\n".join(lines)


def figure(results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from slr_ray.plotting import save_figure

    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4), squeeze=False)
    mid = np.arange(5, 360, 10)
    for ax, (name, res) in zip(axes[0], results.items()):
        for r in res["rows"]:
            if r["method"] == "embree" and (r["variant"].startswith(("ideal", "motion", "A deskewed"))):
                ax.plot(mid, r["sector_median_error"], "o-" if "clockwise" in r["variant"] else ".-",
                        label=r["variant"], ms=3)
        ax.axhline(0, color="k", lw=0.5)
        ax.axvline(180, color="grey", ls=":")
        ax.set_xlabel("azimuth in B (deg; 0 front, 180 rear)")
        ax.set_ylabel("median depth error, simulated - real (m)")
        ax.set_title(f"{name}: embree (primary beams)")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, ROOT / "docs" / "figures" / "effects_gain.png")
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--pairs", nargs="+", default=["kitti", "synthetic"], choices=["kitti", "synthetic"])
    args = ap.parse_args(argv)
    results, inputs = {}, {"seeds": args.seeds, "thresholds": THRESHOLDS, "rear_deg": REAR}
    for name in args.pairs:
        if name == "kitti":
            fr = [np.fromfile(p, np.float32).reshape(-1, 4).astype(np.float64) for p in KITTI]
            a, b = (np.ascontiguousarray(f[:, :3]) for f in fr)
            pair = setup(a, b, fr[0][:, 3], fr[1][:, 3], scan_order_beams(a), scan_order_beams(b))
            inputs["kitti"] = [str(p) for p in KITTI]
        else:
            (a, ba), (b, bb) = synthetic_pair()
            pair = setup(a, b, None, None, ba, bb)
            inputs["synthetic"] = "benchmarks/evaluate_pairs.py synthetic_pair(seed=0)"
        results[name] = evaluate(name, pair, args.seeds)
        print(f"\n{name}: registration {pair['registration']['translation_m']} m, "
              f"fitness {pair['registration']['fitness']:.3f}; {results[name]['seconds']:.0f} s")
        print(table(results[name]["rows"], pair["a_int"] is not None), flush=True)
    figure(results)
    save("evaluate_effects", {"machine": machine(), "inputs": inputs, "results": results})


if __name__ == "__main__":
    main()
