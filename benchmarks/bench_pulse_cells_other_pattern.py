"""``pulse_cells`` with another pattern than the primary's (issue #46 item 2: should it be the default?).

Part 1, KITTI 000000 from its own origin with the nominal HDL-64E table (``slr-ray scan
kitti_hdl64_000000.bin --sensor velodyne_hdl64e_s2 --backend embree``: the file's fitted table is the
primary), binning and the discs alone (``primary_image=False``) with and without ``pulse_cells``: points
out, and where each nominal ray falls in the fitted table's pulses: in a pulse the frame left empty (a
lost pulse), in an occupied pulse, in one another nominal ray also falls in; and the occupied pulses no
nominal ray falls in. With ``pulse_cells`` a ray from the primary's origin returns at most its fitted
pulse's own point, so the points out are bounded by the occupied pulses the nominal rays reach.

Part 2, the same question with ground truth: bench_sensors' street-like box with a car, scanned as an
HDL-64E whose beams are 0.1 deg off the table, with 3 cm per-beam range offsets, 1 cm noise and 10 %
of pulses lost (its primary pattern the nominal table), re-scanned as the nominal table, a VLP-16 and
0.4 deg from its own origin and 1 m and 3 m aside: coverage and precision (10 cm) of binning and of the
beam-table grid (defaults) with and without ``pulse_cells``, and with ``primary_image=False`` at the
own origin with its own table (the primary's image stands in there otherwise).

Run: ``PYTHONPATH=. nice python benchmarks/bench_pulse_cells_other_pattern.py`` (about a minute).
Saves results/bench_pulse_cells_other_pattern.json.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_sensors import street_frame  # noqa: E402
from common import machine, save  # noqa: E402

from slr_ray import ScanPattern, agreement, scan_mesh  # noqa: E402
from slr_ray.backends import prepare  # noqa: E402
from slr_ray.io import read_cloud  # noqa: E402
from slr_ray.sensors import sensor  # noqa: E402

DATA = next((p for p in (Path(__file__).resolve().parents[i] / "shared" / "data" for i in (1, 2, 3)) if p.is_dir()),
            Path("/work/shared/data"))


def kitti_nominal() -> dict:
    pts = read_cloud(DATA / "kitti_hdl64_000000.bin").points
    o = np.zeros(3)
    nominal = sensor("velodyne_hdl64e_s2")
    out = {"binning": len(prepare(pts, "binning").scan(o, nominal))}
    for label, extra in (("discs", {}), ("discs, pulse_cells", {"pulse_cells": True})):
        sc = prepare(pts, "embree", primary_origin=o, primary_pattern="fit", primary_image=False, **extra)
        fitted = sc.options.primary_grid
        out[label] = len(sc.scan(o, nominal))
    # where the nominal rays fall in the fitted table's pulses (a point's pulse by its elevation band, as
    # the beam-table grid takes it: no primary_beams)
    keys, _ = fitted.pulse_ids(pts, o)
    occupied = np.unique(keys[keys >= 0])
    dirs, _, _ = nominal.rays()
    rkeys, _ = fitted.pulse_ids(10.0 * dirs, o)
    seen = rkeys >= 0
    in_occ = np.isin(rkeys, occupied)
    u, counts = np.unique(rkeys[in_occ], return_counts=True)
    out.update({"nominal_rays": int(len(dirs)), "rays_outside_fitted_table": int((~seen).sum()),
                "rays_in_empty_fitted_pulse": int((seen & ~in_occ).sum()),
                "rays_in_occupied_fitted_pulse": int(in_occ.sum()),
                "occupied_fitted_pulses_reached": int(len(u)),
                "rays_sharing_a_pulse_with_another": int((counts[counts > 1]).sum() - (counts > 1).sum()),
                "occupied_fitted_pulses": int(len(occupied)),
                "occupied_fitted_pulses_no_ray_reaches": int(len(occupied) - len(u)),
                "fitted_columns": int(fitted.columns), "nominal_columns": int(nominal.columns)})
    for k, v in out.items():
        print(f"  {k}: {v:,}", flush=True)
    return out


def frame_with_truth(seed: int = 0) -> list[dict]:
    mesh, o, pts = street_frame(seed)
    grid = {"primary_origin": o, "primary_pattern": "velodyne_hdl64e_s2"}
    settings = {"binning": ("binning", {}), "discs": ("embree", grid),
                "discs, pulse_cells": ("embree", {**grid, "pulse_cells": True}),
                "discs alone": ("embree", {**grid, "primary_image": False}),
                "discs alone, pulse_cells": ("embree", {**grid, "primary_image": False, "pulse_cells": True})}
    rows = []
    print("| from | pattern | setting | points | coverage | precision |")
    for label, (backend, opts) in settings.items():
        t0 = time.perf_counter()
        sc = prepare(pts, backend, **opts)
        t_prep = time.perf_counter() - t0
        for where, shift in (("own origin", [0, 0, 0]), ("1 m aside", [0, 1.0, 0]), ("3 m aside", [0, 3.0, 0])):
            if "alone" in label and where != "own origin":
                continue  # primary_image matters at the primary's origin only
            origin = o + shift
            for target in ("velodyne_hdl64e_s2", "velodyne_vlp16", 0.4):
                pattern = sensor(target) if isinstance(target, str) else ScanPattern(target)
                truth = scan_mesh(mesh, origin, pattern)
                s = sc.scan(origin, pattern)
                a = agreement(truth.points, pts[s.indices])
                rows.append({"setting": label, "where": where, "pattern": str(target), "frame_points": len(pts),
                             "points_out": len(s), "coverage": a.coverage, "precision": a.precision,
                             "prepare_seconds": t_prep, "scan_seconds": s.seconds,
                             "primary_view": bool(s.info.get("primary_view", False))})
                print(f"| {where} | {target} | {label} | {len(s):,} | {a.coverage:.1%} | {a.precision:.1%} |",
                      flush=True)
    return rows


def main() -> None:
    print("KITTI 000000 with the nominal table from its own origin:")
    k = kitti_nominal()
    print("\nA frame with a real sensor's departures, with ground truth:")
    rows = frame_with_truth()
    save("bench_pulse_cells_other_pattern", {"machine": machine(), "kitti_nominal": k, "frame_with_truth": rows})


if __name__ == "__main__":
    main()
