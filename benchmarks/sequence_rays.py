"""The ``rays`` estimator on the four KITTI frames (poses by registration), frames 1 and 2 held out, each
scored as ``slr-ray sequence evaluate`` scores a method; mean over the two frames. What each part of it
is worth:

- ``fpa``: the shipped first-peak average, the reference;
- ``rays, the table's pulse centres``: the planes alone, along the target table's own ray of each pulse
  (from the origin, each row's median elevation: :func:`pattern_ray_model`);
- ``rays, lasers fitted, no motion``: each laser's height on the spin axis and elevation fitted from the
  other frames' own points, the sweep's skew held at 0;
- ``rays, no range bias``: the same with the skew fitted too (the frames are motion-compensated: a point
  fired from the back of the sweep was fired up to half a frame's motion from the frame's origin);
- ``rays`` (shipped): and each laser's range bias against the other frames' planes;
- the plane's neighbour count (16, 32, 64 shipped, 128) and how far and how flat its points may be
  (within 0.5 m or a tenth of the range, shipped, or 0.5 m, or 0.05 r; flat at 0.1, shipped, 0.05, 0.2);
- ``rays`` with the pulses it leaves empty filled by fpa's returns (not shipped);
- and, as a check of choices made on frames 1 and 2, the main variants with frames 0 and 3 held out
  (the sequence's ends: the other frames all on one side), the adjacent frame alone beside them.

And the sensor model's fit, measured on the held-out frames' own points (a check of the model, never
an input of the estimator): the median |angle| of each point off its laser's line ``z = z0 + rho tan e``
fitted on the other frames, with the skew fitted and with none; per 30-degree azimuth sector for one
lower-block laser (the PNG: the motion's signature, a jump at the back where the sweep begins and ends).

Writes benchmarks/results/sequence_rays.json and sequence_rays.png (docs/sequences.md quotes them)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from common import RESULTS, machine  # noqa: F401  (puts this checkout first on the path)

from slr_ray.evaluate import fitted_pattern, markdown_table, scan_order_beams, zbuffer
from slr_ray.metrics import point_metrics, range_image_metrics
from slr_ray.sensors import sensor
from slr_ray.sequence import FrameCache, accumulate, estimate, read_sequence, register_chain, to_frame, window
import slr_ray.sequence.rays as rays_module
from slr_ray.sequence.estimators import PulseReturns
from slr_ray.sequence.rays import cast_rays, fit_range_bias, fit_ray_model, frame_motion, pattern_ray_model, sweep_offsets

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
LASER = 50  # a lower-block laser for the figure


def residuals(points, beams, motion, model):
    """Each point's angle (degrees) off its laser's line, seen from where the laser crosses the axis."""
    q = points - sweep_offsets(points, motion, model.skew)
    rho = np.hypot(q[:, 0], q[:, 1])
    z0, e = model.height[beams], model.elevation[beams]
    return np.degrees(np.arctan2(q[:, 2] - z0, rho) - e)


def with_planes(per_m, flat, run):
    """``run()`` with the planes' radius ``max(0.5, per_m r)`` and flatness ``flat``, then the defaults again."""
    keep = rays_module.PLANE_RADIUS_PER_M, rays_module.FLAT
    rays_module.PLANE_RADIUS_PER_M, rays_module.FLAT = per_m, flat
    try:
        return run()
    finally:
        rays_module.PLANE_RADIUS_PER_M, rays_module.FLAT = keep


def filled(rays, fpa):
    """``rays``' returns and fpa's on the pulses ``rays`` leaves empty."""
    miss = ~np.isin(fpa.keys, rays.keys)
    keys = np.r_[rays.keys, fpa.keys[miss]]
    o = np.argsort(keys, kind="stable")
    return PulseReturns(keys[o], np.r_[rays.ranges, fpa.ranges[miss]][o], np.r_[rays.points, fpa.points[miss]][o],
                        np.r_[rays.index, fpa.index[miss]][o])


SHIPPED = "rays (shipped: lasers, motion and range biases fitted, 64 neighbours, planes within 0.5 m or 0.1 r, " \
          "flat at 0.1)"
CHECK = ("adjacent frame alone (binning)", "fpa", "rays, the table's pulse centres", "rays, lasers fitted, no motion",
         "rays, lasers and motion fitted, no range bias", SHIPPED,
         "rays, planes within 0.5 m, flat at 0.05")


def mean(per):
    rows = [{"method": m} | {k: float(np.mean([r[k] for r in rs])) for k in rs[0]} for m, rs in per.items()]
    for r in rows:
        r["points"] = int(round(r["points"]))
    return rows


def main() -> None:
    frames = [DATA / f"kitti_hdl64_00000{i}.bin" for i in range(4)]
    if not all(f.is_file() for f in frames):
        sys.exit(f"the four KITTI frames are not in {DATA}")
    seq, _ = register_chain(read_sequence(frames))
    base = sensor("velodyne_hdl64e_s2")
    cache = FrameCache(seq)
    per, check, fits, sectors = {}, {}, [], {}
    for h in (1, 2, 0, 3):  # 1 and 2 the study; 0 and 3 (the ends: every other frame on one side) a check
        main_frame = h in (1, 2)
        fb, _ = cache.get(h)
        b = fb.points
        beams = scan_order_beams(b, base.n_beams)
        pat = fitted_pattern(b, beams, base)
        keys, _ = pat.pulse_ids(b, np.zeros(3))
        b_in = b[keys >= 0]
        real = zbuffer(b, pat, backend="real").range_image()["range"]
        others = window(seq, h, 2)
        u = to_frame(accumulate(seq, others, cache=cache).points, fb.pose)
        own = [(cache.get(i)[0].points, scan_order_beams(cache.get(i)[0].points, base.n_beams),
                frame_motion(seq.poses, i)) for i in others]
        t0 = time.perf_counter()
        lines = fit_ray_model(own, base.n_beams)
        fitted = fit_range_bias(lines, [(cache.get(i)[1], b_, seq.poses[i], v_) for i, (_, b_, v_) in zip(others, own)])
        fit_s = time.perf_counter() - t0
        still = fit_ray_model(own, base.n_beams, skews=[0.0])
        v = frame_motion(seq.poses, h)
        adjacent = to_frame(accumulate(seq, [min(others, key=lambda i: (abs(i - h), i > h))], cache=cache).points,
                            fb.pose)
        methods = {
            "adjacent frame alone (binning)": lambda: estimate(adjacent, pat, "nearest"),
            "fpa": lambda: estimate(u, pat, "fpa"),
            "rays, the table's pulse centres": lambda: cast_rays(u, pat, pattern_ray_model(pat)),
            "rays, lasers fitted, no motion": lambda: cast_rays(u, pat, still, v),
            "rays, lasers and motion fitted, no range bias": lambda: cast_rays(u, pat, lines, v),
            SHIPPED: lambda: cast_rays(u, pat, fitted, v),
            "rays, 16 neighbours": lambda: cast_rays(u, pat, fitted, v, neighbours=16),
            "rays, 32 neighbours": lambda: cast_rays(u, pat, fitted, v, neighbours=32),
            "rays, 128 neighbours": lambda: cast_rays(u, pat, fitted, v, neighbours=128),
            "rays, planes within 0.5 m, flat at 0.05":
                lambda: with_planes(0.0, 0.05, lambda: cast_rays(u, pat, fitted, v)),
            "rays, planes within 0.5 m or 0.05 r, flat at 0.05":
                lambda: with_planes(0.05, 0.05, lambda: cast_rays(u, pat, fitted, v)),
            "rays, planes within 0.5 m or 0.1 r, flat at 0.2":
                lambda: with_planes(0.1, 0.2, lambda: cast_rays(u, pat, fitted, v)),
            "rays, the pulses it leaves empty filled by fpa's": lambda: filled(cast_rays(u, pat, fitted, v),
                                                                                estimate(u, pat, "fpa")),
        }
        for name, run in methods.items():
            if not main_frame and name not in CHECK:
                continue
            t0 = time.perf_counter()
            ret = run()
            sec = time.perf_counter() - t0
            pm = point_metrics(b_in, ret.points, thresholds=(0.05,))
            im = range_image_metrics(real, ret.image(pat))
            (per if main_frame else check).setdefault(name, []).append({"points": len(ret), "F@5cm": pm.fscore[0.05]["fscore"],
                                             "depth_medae_m": im.medae, "depth_rmse_m": im.rmse,
                                             "drop_accuracy": im.accuracy, "cd_sum_m2": pm.chamfer_sum,
                                             "seconds": sec})
        if not main_frame:
            continue
        fit = {"frame": h, "skew": fitted.skew, "fit_seconds": round(fit_s, 2)}
        az = np.degrees(np.arctan2(b[:, 1], b[:, 0])) % 360
        for label, model in (("skew fitted", fitted), ("no skew", still)):
            a = residuals(b, beams, v if model is fitted else np.zeros(3), model)
            fit[label] = {"upper_block_deg": float(np.median(np.abs(a[beams < 32]))),
                          "lower_block_deg": float(np.median(np.abs(a[beams >= 32])))}
            m = beams == LASER
            sectors.setdefault(label, []).append([float(np.median(a[m][(az[m] // 30) == k])) for k in range(12)])
        fits.append(fit)
    rows, check_rows = mean(per), mean(check)
    print(markdown_table(rows))
    print("\nthe check: frames 0 and 3 held out (the parameters were chosen on 1 and 2)")
    print(markdown_table(check_rows))
    for f in fits:
        print(f"frame {f['frame']}: skew {f['skew']} (fitted in {f['fit_seconds']} s); its own points off the "
              f"lines fitted on the other frames, median |angle| upper / lower block: skew fitted "
              f"{f['skew fitted']['upper_block_deg']:.4f} / {f['skew fitted']['lower_block_deg']:.4f} deg, no skew "
              f"{f['no skew']['upper_block_deg']:.4f} / {f['no skew']['lower_block_deg']:.4f} deg")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sequence_rays.json").write_text(json.dumps(
        {"machine": machine(), "rows": rows, "per_frame": per, "check_frames_0_3": check_rows,
         "check_per_frame": check, "fits": fits,
         "laser_sectors_deg": {"laser": LASER, "sector_deg": 30, **sectors}}, indent=1))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(figsize=(6, 3.2))
    x = np.arange(12) * 30 + 15
    for label, vals in sectors.items():
        for k, s in enumerate(vals):
            ax.plot(x, s, "o-" if label == "no skew" else "s-", color="C1" if label == "no skew" else "C0",
                    label=label if k == 0 else None, alpha=0.8)
    ax.axhline(0, color="0.5", lw=0.5)
    ax.set_xlabel("azimuth (deg, 0 ahead, counter-clockwise)")
    ax.set_ylabel("median angle off the line (deg)")
    ax.set_title(f"KITTI frames 1, 2: laser {LASER} against its line fitted on the other frames", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(RESULTS / "sequence_rays.png", dpi=110)


if __name__ == "__main__":
    main()
