"""Each KITTI frame re-simulated from itself at its own pose (issue #38): the embree backend's
primary view against the disc cast it replaced.

For each ``kitti_hdl64_00000{0..3}.bin`` of --data (default $SLR_RAY_DATA, else the shared/data above the checkout): ``evaluate_pair(F, F, transform=identity)``
(beams from the scan order, the frame's fitted table), methods binning, embree (beam-table grid) and
embree (primary beams), once with the default ``primary_image=True`` (a scan from the primary's own
origin with its own pattern returns its own image) and once with ``primary_image=False`` (the discs
cast there too: the behaviour before). Prints one table row per frame, method and setting: depth RMSE
(m), ray-drop accuracy, recall at 5 cm, points out. Saves results/bench_self_view.json.

Part 2, terrestrial scans from their own origins: forest_tls_riegl.laz (its pattern known: 0.048 deg
zenith x 0.622 deg azimuth, zenith 30-130) and pump_tls.e57 (origin 0, its pose the identity; its
pattern only fitted), each scanned with the known pattern (the forest) or its fitted one (the pump) by
binning and by embree with the primary's pattern given or ``primary_pattern='fit'``, with and without
``primary_image`` (without it, also with ``pulse_cells``): points out, their share of binning's count,
and the share of binning's points among them (binning's is the primary's own image there).

Part 3, away from the origin: frame 000001 re-simulated from frame 000000 (registered, as
``slr-ray evaluate`` does), embree with the beam-table grid, ``silhouettes`` on (the default) and off:
depth RMSE, ray-drop accuracy, recall at 5 cm.

Run: ``PYTHONPATH=. nice python benchmarks/bench_self_view.py`` from the repository root (about 1-2
minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import data_dir, machine, save  # noqa: E402

import slr_ray.evaluate as ev  # noqa: E402
from slr_ray import ScanPattern  # noqa: E402
from slr_ray.backends import prepare  # noqa: E402
from slr_ray.io import read_cloud  # noqa: E402

DATA = data_dir()  # $SLR_RAY_DATA, else the shared/data above the checkout (a git worktree's too)
METHODS = ("binning", "embree-grid", "embree-beams")


def _evaluate(a, b, setting: dict, **kw):
    def prep(points, backend, **opts):  # evaluate_pair's prepare, with the setting under test
        if backend == "embree":
            opts.update(setting)
        return prepare(points, backend, **opts)

    ev.prepare = prep
    try:
        return ev.evaluate_pair(a, b, **kw)
    finally:
        ev.prepare = prepare


def run(frame: Path, primary_image: bool) -> list[dict]:
    pts = read_cloud(frame).points
    res = _evaluate(pts, pts, {"primary_image": primary_image}, transform=np.eye(4), methods=METHODS)
    out = []
    for row in ev.evaluation_table(res):
        out.append({"frame": frame.name, "primary_image": primary_image, "method": row["method"],
                    "points": row["points"], "depth_rmse_m": row["depth_rmse_m"],
                    "drop_accuracy": row["drop_accuracy"], "recall_5cm": row["R@5cm"]})
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA,
                    help="the real-data directory (default: $SLR_RAY_DATA, else the shared/data found above the "
                         "checkout)")
    ap.add_argument("--frames", nargs="*", default=[f"kitti_hdl64_00000{i}.bin" for i in range(4)])
    ap.add_argument("--terrestrial-only", action="store_true",
                    help="part 2 only (results/bench_self_view_terrestrial.json)")
    args = ap.parse_args(argv)
    if args.terrestrial_only:
        save("bench_self_view_terrestrial", {"machine": machine(), "terrestrial": terrestrial(args.data)})
        return
    rows = []
    print("| frame | primary_image | method | points | depth RMSE (m) | ray-drop accuracy | recall @ 5 cm |")
    print("|---|---|---|---|---|---|---|")
    for name in args.frames:
        for primary_image in (True, False):
            for r in run(args.data / name, primary_image):
                if not primary_image and r["method"] == "binning":
                    continue  # the same as with it
                rows.append(r)
                print(f"| {r['frame']} | {r['primary_image']} | {r['method']} | {r['points']:,} | "
                      f"{r['depth_rmse_m']:.4f} | {r['drop_accuracy']:.4f} | {r['recall_5cm']:.4f} |", flush=True)
    tls = terrestrial(args.data)
    pair = []
    a, b = (read_cloud(args.data / f"kitti_hdl64_00000{i}.bin").points for i in (0, 1))
    print("\n| pair | method | silhouettes | depth RMSE (m) | ray-drop accuracy | recall @ 5 cm |\n|---|---|---|---|---|---|")
    for sil in (True, False):
        res = _evaluate(a, b, {"silhouettes": sil}, methods=("binning", "embree-grid"))
        for row in ev.evaluation_table(res):
            r = {"pair": "000000 -> 000001", "method": row["method"], "silhouettes": sil,
                 "depth_rmse_m": row["depth_rmse_m"], "drop_accuracy": row["drop_accuracy"],
                 "recall_5cm": row["R@5cm"]}
            pair.append(r)
            print(f"| {r['pair']} | {r['method']} | {sil} | {r['depth_rmse_m']:.4f} | {r['drop_accuracy']:.4f} | "
                  f"{r['recall_5cm']:.4f} |", flush=True)
    save("bench_self_view", {"machine": machine(), "rows": rows, "terrestrial": tls, "pair": pair})


FOREST = ScanPattern(azimuth_resolution=0.622, zenith_resolution=0.048, zenith_range=(30, 130))


def terrestrial(data: Path) -> list[dict]:
    rows = []
    print("\n| scan | primary pattern | scanned with | primary_image | pulse_cells | points | share of binning's "
          "| binning's points among them |")
    print("|---|---|---|---|---|---|---|---|")
    for name, known in (("forest_tls_riegl.laz", FOREST), ("pump_tls.e57", None)):
        pts = read_cloud(data / name).points
        fitted = prepare(pts, "embree", primary_origin=np.zeros(3), primary_pattern="fit")
        scan_with = known if known is not None else fitted.options.primary_grid
        b = prepare(pts, "binning").scan(np.zeros(3), scan_with)
        for label, prim in (("given", known), ("fit", "fit")):
            if prim is None:
                continue
            for primary_image, cells in ((True, False), (False, False), (False, True)):
                s = prepare(pts, "embree", primary_origin=np.zeros(3), primary_pattern=prim,
                            primary_image=primary_image, pulse_cells=cells).scan(np.zeros(3), scan_with)
                same = np.intersect1d(s.indices, b.indices).size  # binning's own points among them
                r = {"scan": name, "primary_pattern": label, "fitted": fitted.primary_fit,
                     "fitted_pattern": fitted.options.primary_grid.to_dict(),
                     "scanned_with": "known" if known is not None else "fitted", "primary_image": primary_image,
                     "pulse_cells": cells, "points": len(s), "binning_points": len(b), "share": len(s) / len(b),
                     "same_points_share": same / len(b), "primary_view": s.info["primary_view"]}
                rows.append(r)
                print(f"| {name} | {label} | {r['scanned_with']} | {primary_image} | {cells} | {len(s):,} | "
                      f"{r['share']:.4f} | {r['same_points_share']:.4f} |", flush=True)
        print(f"  fitted: {fitted.primary_fit}", flush=True)
    return rows


if __name__ == "__main__":
    main()
