"""Discs that are right by themselves (issue #46, item 2): each real frame re-scanned from its own
origin by the embree discs alone, with the primary's image turned off (``primary_image=False``),
scored against itself.

Frames (../shared/data): the four KITTI HDL-64E frames (beams from their scan order, the
``velodyne_hdl64e_s2`` table fitted to them), the first Ouster OS1-128 frame (``ouster_os1_128``,
beams from its ring field) and the first Hesai Pandar64 frame of ``hesai_p64_seq`` (the
``hesai_pandar64_pjlab`` card, beams from its ring field). Each frame F is ``evaluate_pair(F, F,
transform=identity)`` ([evaluation.md](../docs/evaluation.md)): re-simulated from itself with its own
fitted card, scored against its own range image (nearest point per pulse: binning's image), for the
methods ``binning`` (the reference: exact by construction), ``embree-grid`` (beam-table pulse grid)
and ``embree-beams`` (the same with each point in its beam's row), each embree method under the
settings of ``SETTINGS``:

- ``before``: ``primary_image=False`` and the defaults otherwise (the discs as they were);
- ``pulse_cells``: ``primary_image=False, pulse_cells=True`` (each disc cut to its own pulse of the
  primary and reaching that pulse's centre ray; no tie window from the primary's origin).

Figures: depth RMSE and MedAE (m), drop accuracy (pulse hit/miss agreement), F@5cm, points out.
Prints a table, saves ``results/embree_self_rescan.json`` and ``results/embree_self_rescan.png``.

Run: ``PYTHONPATH=. nice python benchmarks/embree_self_rescan.py`` from the repository root (a few
minutes on the shared 2-core machine; ``--frames kitti_hdl64_000000.bin`` for one frame,
``--settings before pulse_cells`` for some settings). ``--pair`` adds KITTI 000001 re-simulated from
000000 (registered, ``primary_image`` at its default): the settings away from the primary's origin;
``--pair-only`` runs that alone (``results/NAME_pair.json``); ``--speed-only N`` measures what
``pulse_cells`` costs to prepare and cast on KITTI 000000, medians of N alternated rounds in one
process (``results/NAME_speed.json``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import RESULTS, machine, save  # noqa: E402

import slr_ray.evaluate as ev  # noqa: E402
from slr_ray.backends import prepare  # noqa: E402
from slr_ray.io import read_cloud  # noqa: E402

DATA = next((p for p in (Path(__file__).resolve().parents[i] / "shared" / "data" for i in (1, 2, 3)) if p.is_dir()),
            Path("/work/shared/data"))
#: (label, file under DATA, sensor card, beams: 'auto' (scan order) or 'ring')
FRAMES = [*((f"kitti {i:06d}", f"kitti_hdl64_{i:06d}.bin", "velodyne_hdl64e_s2", "auto") for i in range(4)),
          ("ouster os1-128 frame 00", "ouster_os1_128/os1_128_frame00.npz", "ouster_os1_128", "ring"),
          ("hesai pandar64 seq 468", "hesai_p64_seq/2021-10-26-16-21-29-468.pcd", "hesai_pandar64_pjlab", "ring")]
METHODS = ("binning", "embree-grid", "embree-beams")
SETTINGS = {"before": {"primary_image": False},
            "pulse_cells": {"primary_image": False, "pulse_cells": True}}
#: the issue's bounds
RMSE_BOUND, DROP_BOUND = 0.2, 0.95


@contextlib.contextmanager
def _embree_given(setting: dict):
    """``evaluate_pair`` inside gives ``setting`` to every embree scanner it prepares."""
    def prep(pts, backend, **opts):
        if backend == "embree":
            opts.update(setting)
        return prepare(pts, backend, **opts)

    ev.prepare = prep
    try:
        yield
    finally:
        ev.prepare = prepare


def _evaluate(points, beams, sensor, setting: dict, methods) -> dict:
    """``evaluate_pair(F, F, transform=identity)`` with ``setting`` given to every embree scanner."""
    with _embree_given(setting):
        return ev.evaluate_pair(points, points, a_beams=beams, b_beams=beams, transform=np.eye(4), sensor=sensor,
                                methods=methods)


def run_frame(label, path, sensor, beams_from, settings) -> list[dict]:
    cloud = read_cloud(path)
    pts = cloud.points
    beams = np.asarray(cloud.attributes["ring"], np.int64) if beams_from == "ring" else "auto"
    rows = []
    for name in settings:
        methods = METHODS if name == settings[0] else METHODS[1:]  # binning once
        t0 = time.perf_counter()
        res = _evaluate(pts, beams, sensor, SETTINGS[name], methods)
        for r, raw in zip(ev.evaluation_table(res), res["rows"]):
            row = {"frame": label, "file": path.name, "sensor": sensor, "method": raw["method"],
                   "setting": "-" if raw["method"] == "binning" else name, "points": r["points"],
                   "depth_rmse_m": r["depth_rmse_m"], "depth_medae_m": r["depth_medae_m"],
                   "drop_accuracy": r["drop_accuracy"], "F@5cm": r["F@5cm"],
                   "prepare_seconds": raw["prepare_seconds"], "seconds": raw["seconds"]}
            rows.append(row)
            print(f"| {label} | {row['method']} | {row['setting']} | {row['points']:,} | {row['depth_rmse_m']:.3f} | "
                  f"{row['depth_medae_m']:.4f} | {row['drop_accuracy']:.4f} | {row['F@5cm']:.4f} |", flush=True)
        print(f"  ({name}: {time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
    return rows


def plot(rows, settings, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = list(dict.fromkeys(r["frame"] for r in rows))
    series = [(m, s) for m in METHODS[1:] for s in settings]
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8))
    width = 0.8 / len(series)
    for ax, key, bound, title in ((axes[0], "depth_rmse_m", RMSE_BOUND, "depth RMSE (m)"),
                                  (axes[1], "drop_accuracy", DROP_BOUND, "drop accuracy")):
        for j, (m, s) in enumerate(series):
            vals = [next((r[key] for r in rows if r["frame"] == f and r["method"] == m and r["setting"] == s),
                         np.nan) for f in frames]
            ax.bar(np.arange(len(frames)) + (j - (len(series) - 1) / 2) * width, vals, width,
                   label=f"{ev.LABELS[m]}, {s}")
        ax.axhline(bound, color="k", ls="--", lw=1, label=f"issue's bound {bound}")
        ax.set_xticks(np.arange(len(frames)), frames, rotation=25, ha="right", fontsize=8)
        ax.set_title(f"{title}: each frame re-scanned by its own discs")
        if key == "drop_accuracy":
            ax.set_ylim(0.8, 1.0)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def pair(data: Path, settings) -> list[dict]:
    """Away from the origin: KITTI 000001 re-simulated from 000000 (registered, as ``slr-ray evaluate``
    does), the embree methods under each setting, with ``primary_image`` at its default (the target's
    pose is not the primary's)."""
    a, b = (read_cloud(data / f"kitti_hdl64_00000{i}.bin").points for i in (0, 1))
    rows = []
    print("\n| pair | method | setting | points | depth RMSE (m) | MedAE (m) | drop accuracy | F@5cm |\n"
          "|---|---|---|---|---|---|---|---|")
    for name in settings:
        setting = {k: v for k, v in SETTINGS[name].items() if k != "primary_image"}
        with _embree_given(setting):
            res = ev.evaluate_pair(a, b, methods=METHODS if name == settings[0] else METHODS[1:])
        for r, raw in zip(ev.evaluation_table(res), res["rows"]):
            row = {"pair": "000000 -> 000001", "method": raw["method"],
                   "setting": "-" if raw["method"] == "binning" else name, "points": r["points"],
                   "depth_rmse_m": r["depth_rmse_m"], "depth_medae_m": r["depth_medae_m"],
                   "drop_accuracy": r["drop_accuracy"], "F@5cm": r["F@5cm"]}
            rows.append(row)
            print(f"| {row['pair']} | {row['method']} | {row['setting']} | {row['points']:,} | "
                  f"{row['depth_rmse_m']:.3f} | {row['depth_medae_m']:.4f} | {row['drop_accuracy']:.4f} | "
                  f"{row['F@5cm']:.4f} |", flush=True)
    return rows


def speed(data: Path, repeats: int) -> dict:
    """What ``pulse_cells`` costs: KITTI 000000's beam-table-grid scanner prepared with and without it
    (``primary_image=False``), cast from its origin and from 1 m aside with its fitted table, the two
    alternated in this process, medians of ``repeats`` (wall and CPU seconds: all threads)."""
    import statistics

    from slr_ray.sensors import fitted_pattern, scan_order_beams, sensor

    pts = read_cloud(data / "kitti_hdl64_000000.bin").points
    base = sensor("velodyne_hdl64e_s2")
    pat = fitted_pattern(pts, scan_order_beams(pts, base.n_beams), base)
    opts = {"primary_origin": np.zeros(3), "primary_pattern": pat, "primary_image": False}
    times = {k: [] for k in ("before", "pulse_cells")}
    for i in range(repeats + 1):  # the first round compiles: not counted
        for name, extra in (("before", {}), ("pulse_cells", {"pulse_cells": True})):
            row = {}
            t, c = time.perf_counter(), time.process_time()
            sc = prepare(pts, "embree", **opts, **extra)
            row["prepare_s"], row["prepare_cpu_s"] = time.perf_counter() - t, time.process_time() - c
            for where, origin in (("origin", np.zeros(3)), ("1m_aside", np.array([0.0, 1.0, 0.0]))):
                t, c = time.perf_counter(), time.process_time()
                sc.scan(origin, pat)
                row[f"cast_{where}_s"], row[f"cast_{where}_cpu_s"] = time.perf_counter() - t, time.process_time() - c
            if i:
                times[name].append(row)
    med = {k: {m: statistics.median(r[m] for r in v) for m in v[0]} for k, v in times.items()}
    ratio = {m: med["pulse_cells"][m] / med["before"][m] for m in med["before"]}
    print("\nspeed (medians of", repeats, "):", json_line(med), "\npulse_cells / before:", json_line(ratio), flush=True)
    return {"runs": times, "median": med, "pulse_cells_over_before": ratio}


def json_line(d) -> str:
    return ", ".join(f"{k}: " + (json_line(v) if isinstance(v, dict) else f"{v:.3f}") for k, v in d.items())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--frames", nargs="*", default=None, help="files under --data (default: the six of FRAMES)")
    ap.add_argument("--settings", nargs="*", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--name", default="embree_self_rescan", help="results/NAME.json and NAME.png")
    ap.add_argument("--pair", action="store_true", help="also KITTI 000001 re-simulated from 000000 (registered)")
    ap.add_argument("--pair-only", action="store_true", help="only that (results/NAME_pair.json)")
    ap.add_argument("--speed-only", type=int, default=0, metavar="N",
                    help="only what pulse_cells costs, medians of N (results/NAME_speed.json)")
    args = ap.parse_args(argv)
    if args.speed_only:
        save(f"{args.name}_speed", {"machine": machine(), "load_before": os.getloadavg(),
                                    **speed(args.data, args.speed_only), "load_after": os.getloadavg()})
        return
    if args.pair_only:
        save(f"{args.name}_pair", {"machine": machine(), "load_before": os.getloadavg(),
                                   "pair": pair(args.data, args.settings), "load_after": os.getloadavg()})
        return
    frames = [f for f in FRAMES if args.frames is None or f[1] in args.frames]
    load = os.getloadavg()
    print("| frame | method | setting | points | depth RMSE (m) | MedAE (m) | drop accuracy | F@5cm |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for label, name, sensor, beams in frames:
        rows += run_frame(label, args.data / name, sensor, beams, args.settings)
    plot(rows, args.settings, RESULTS / f"{args.name}.png")
    within = {s: all(r["depth_rmse_m"] <= RMSE_BOUND and r["drop_accuracy"] >= DROP_BOUND
                     for r in rows if r["setting"] == s) for s in args.settings}
    print(f"within the issue's bounds (RMSE <= {RMSE_BOUND} m, drop >= {DROP_BOUND}) on every frame: {within}")
    out = {"machine": machine(), "load_before": load, "settings": {s: SETTINGS[s] for s in args.settings},
           "rows": rows, "within_bounds": within}
    if args.pair:
        out["pair"] = pair(args.data, args.settings)
    save(args.name, out | {"load_after": os.getloadavg()})


if __name__ == "__main__":
    main()
