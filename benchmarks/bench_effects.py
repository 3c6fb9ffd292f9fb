"""Sensor effects (slr_ray.effects): each effect's cost against the ideal scan, and the KITTI drop fit.

    python benchmarks/bench_effects.py [--repeat 3] [--only divergence ...]

1. Cost. The KITTI HDL-64E frame of --data (default $SLR_RAY_DATA, else the shared/data above the checkout) (124,668 points) prepared once
   per backend (binning; embree with discs from the frame's own beam-table pulse
   grid, ``primary_pattern='velodyne_hdl64e_s2'``), re-scanned with its own table
   (64 x 2083 pulses) from 1 m aside: the ideal scan, then each effect alone and
   all together, in the same run. Time: median of ``--repeat`` runs; memory:
   the peak of Python/numpy allocations in one run (tracemalloc; Embree's BVH
   is built once, before, and is not counted).
2. Ray drop. The frame's own pulse grid (rings from its scan order, gaps of
   up to 16 pulses) -> a logistic drop model; per range and per incidence bin:
   the frame's observed drop rate, the model's mean probability on the same
   pulses, and the drop rate the model realises on the re-simulated frame
   (embree, from the frame's own origin; seed 0; incidence from the PCA
   normals the model was fitted with). In part 1 the effects that need
   incidence take the backend's (embree: its disc normals; binning: PCA
   normals estimated in the call). Table and
   docs/figures/effects_raydrop.png.

Saves results/bench_effects.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import data_dir, machine, save  # noqa: E402

from slr_ray import prepare  # noqa: E402
from slr_ray.backends.embree import estimate_normals  # noqa: E402
from slr_ray.effects import Effects, fit_ray_drop, frame_pulses, pose, rings_from_scan_order, simulate  # noqa: E402
from slr_ray.effects.raydrop import drop_rates, incidence_deg  # noqa: E402
from slr_ray.sensors import sensor  # noqa: E402

KITTI_NAME = "kitti_hdl64_000000.bin"  # in --data (default: common.data_dir(): $SLR_RAY_DATA or shared/data above)
FIGURES = Path(__file__).resolve().parents[1] / "docs" / "figures"
ORIGIN = np.array([0.0, 1.0, 0.0])
RANGE_EDGES = [0, 5, 10, 15, 20, 30, 40, 60, 80]
INCIDENCE_EDGES = [0, 15, 30, 45, 60, 75, 85, 90]


def measure(fn, repeat):
    """Median wall and process-CPU seconds of ``repeat`` runs, the peak of one more, the output."""
    times, cpu = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return statistics.median(times), statistics.median(cpu), peak, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", nargs="*", default=None, metavar="WORD",
                    help="part 1: only the cases whose name holds one of these words, and the ideal scan "
                         "(saved as bench_effects_only.json; no figure)")
    ap.add_argument("--data", type=Path, default=None,
                    help="the real-data directory (default: $SLR_RAY_DATA, else the shared/data found above the "
                         "checkout: a git worktree's too)")
    args = ap.parse_args(argv)
    KITTI = (args.data or data_dir()) / KITTI_NAME
    if not KITTI.exists():
        sys.exit(f"{KITTI} is absent (give --data DIR or SLR_RAY_DATA)")
    a = np.fromfile(KITTI, np.float32).reshape(-1, 4).astype(np.float64)
    pts, inten = np.ascontiguousarray(a[:, :3]), a[:, 3]
    hdl = sensor("velodyne_hdl64e_s2")

    # --- 2 first: the drop model the cost part applies
    t0 = time.perf_counter()
    rings = rings_from_scan_order(pts)
    fit_normals = estimate_normals(pts, k=10, primary_origin=[0.0, 0.0, 0.0])
    fp = frame_pulses(pts, intensity=inten, rings=rings, normals=fit_normals)
    model = fit_ray_drop(fp["range"], fp["incidence"], fp["dropped"], fp["intensity"],
                         info={"source": KITTI.name, "max_gap": 16})
    fit_seconds = time.perf_counter() - t0
    print(f"drop model from {KITTI.name}: {len(fp['dropped']):,} pulses, {fp['dropped'].sum():,} dropped "
          f"({fp['dropped'].mean():.2%}), fitted in {fit_seconds:.2f} s", flush=True)
    for name, c, se in zip(model.names, model.coef, model.stderr):
        print(f"  {name:<12} {c:+8.3f} +- {se:.3f}")

    emb_opts = {"primary_origin": [0.0, 0.0, 0.0], "primary_pattern": "velodyne_hdl64e_s2"}
    scanners = {"binning": prepare(pts), "embree": prepare(pts, "embree", **emb_opts)}
    # the realised drop on a re-simulated frame (own origin: the frame's own pulses, re-made)
    emb = scanners["embree"]
    base = simulate(emb, [0, 0, 0], hdl)
    # the model applied with the normals it was fitted with (the discs' are turned to <= 80 deg)
    dropped_run = simulate(emb, [0, 0, 0], hdl, Effects(ray_drop=model, seed=0), intensity=inten,
                           normals=fit_normals)
    kept = np.zeros(len(base), bool)
    kept[np.isin(base.pulses[:, 0] * hdl.shape[1] + base.pulses[:, 1],
                 dropped_run.pulses[:, 0] * hdl.shape[1] + dropped_run.pulses[:, 1])] = True
    base_inc = incidence_deg(emb.points[base.indices], fit_normals[base.indices], [0, 0, 0])
    p = model.probability(fp["range"], fp["incidence"], fp["intensity"])
    tables = {}
    for feat, edges, real_v, sim_v in (("range_m", RANGE_EDGES, fp["range"], base.ranges),
                                       ("incidence_deg", INCIDENCE_EDGES, fp["incidence"], base_inc)):
        tables[feat] = {"real": drop_rates(real_v, fp["dropped"], edges), "model": drop_rates(real_v, p, edges),
                        "resimulated": drop_rates(sim_v, ~kept, edges)}
        print(f"\ndrop rate by {feat}: real frame | model on its pulses | model applied to the re-simulated frame")
        t = tables[feat]
        for i in range(len(edges) - 1):
            print(f"  {edges[i]:>3}-{edges[i + 1]:<3} {t['real']['rate'][i]:7.2%} ({t['real']['pulses'][i]:>6,})"
                  f"  {t['model']['rate'][i]:7.2%}  {t['resimulated']['rate'][i]:7.2%} "
                  f"({t['resimulated']['pulses'][i]:>6,})")
    if args.only is None:
        figure(tables)

    # --- 1: cost of each effect against the ideal scan, same run
    moving = [pose(ORIGIN - [1.0, 0, 0]), pose(ORIGIN, yaw_deg=2.0)]  # 10 m/s and 20 deg/s at 10 Hz
    cases = [("ideal", Effects(), {}),
             ("range noise", Effects(range_noise="sensor"), {}),
             ("blind zone + reflectivity range", Effects(min_range=2.0, max_range_at="sensor"), {}),
             ("ray drop (KITTI fit)", Effects(ray_drop=model), {}),
             ("intensity carry", Effects(intensity="carry"), {}),
             ("intensity correct", Effects(intensity="correct"), {"primary_origin": [0.0, 0.0, 0.0]}),
             ("motion", Effects(motion=True), {"poses": moving}),
             ("divergence 3 mrad, 3 rings (19 sub-rays)", Effects(divergence_mrad=3.0), {}),
             ("divergence 3 mrad, 5 rings (61 sub-rays)", Effects(divergence_mrad=3.0, beam_rings=5), {}),
             ("all (divergence 3 rings, motion, noise, drop, range, intensity)",
              Effects(divergence_mrad=3.0, motion=True, range_noise="sensor", ray_drop=model, min_range=2.0,
                      max_range_at="sensor", intensity="carry"), {"poses": moving})]
    rows = []
    if args.only is not None:
        cases = [c for c in cases if c[0] == "ideal" or any(w in c[0] for w in args.only)]
    for backend, sc in scanners.items():
        simulate(sc, ORIGIN, hdl, intensity=inten)  # compile
        ideal_t = ideal_c = None
        for name, eff, kw in cases:
            if eff.divergence_mrad and backend != "embree":
                continue
            origin = None if "poses" in kw else ORIGIN
            t, c, peak, es = measure(lambda: simulate(sc, origin, hdl, eff, intensity=inten, **kw), args.repeat)
            if name == "ideal":
                ideal_t, ideal_c = t, c
            rows.append({"backend": backend, "effect": name, "seconds": t, "x_ideal": t / ideal_t,
                         "cpu_seconds": c, "cpu_x_ideal": c / ideal_c,
                         "peak_mib": peak / 2**20, "returns": len(es),
                         "multiple": int(np.count_nonzero(es.number_of_returns > 1))})
            r = rows[-1]
            print(f"{backend:<8} {name:<66} {t:8.3f} s  x{r['x_ideal']:5.2f}  cpu {c:7.3f} s  x{r['cpu_x_ideal']:5.2f}"
                  f"  {r['peak_mib']:7.1f} MiB  {len(es):>7,} returns ({r['multiple']:,} of pulses with several)",
                  flush=True)
    save("bench_effects" if args.only is None else "bench_effects_only", {"machine": machine(), "inputs": {"cloud": KITTI.name, "points": len(pts),
                                                           "pattern": "velodyne_hdl64e_s2", "origin": ORIGIN.tolist(),
                                                           "repeat": args.repeat, "embree_options": emb_opts},
                           "cost": rows, "drop_model": model.to_dict(), "drop_fit_seconds": fit_seconds,
                           "drop_rates": tables})


def figure(tables):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from slr_ray.plotting import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, (feat, t) in zip(axes, tables.items()):
        e = np.asarray(t["real"]["edges"])
        mid = 0.5 * (e[1:] + e[:-1])
        for key, style in (("real", "o-"), ("model", "s--"), ("resimulated", "^:")):
            ax.plot(mid, 100 * np.asarray(t[key]["rate"], float), style,
                    label={"real": "KITTI frame", "model": "fitted model, same pulses",
                           "resimulated": "model on re-simulated frame"}[key])
        ax.set_xlabel(feat.replace("_", " (") + ")")
        ax.set_ylabel("pulses dropped (%)")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle("Ray drop: KITTI HDL-64E frame 000000 against the logistic model fitted from it")
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    save_figure(fig, FIGURES / "effects_raydrop.png")
    plt.close(fig)


if __name__ == "__main__":
    main()
