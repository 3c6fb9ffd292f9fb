"""Sensor beam tables: time per frame against input size, the HDL-64E frame against a
0.144 deg uniform scan of the same cloud, and the KITTI frame re-scanned as other sensors.

    python benchmarks/bench_sensors.py [--repeat 3] [--frame-only]

1. The 29 M-point benchmark cloud (bench_binning's), binning backend, from a
   position 14 m away: an HDL-64E S2 frame (64 x 2083 = 133 k pulses) and a
   0.144 deg uniform scan (3.1 M pulses), best of ``--repeat``, same run
   (the issue's target: HDL-64E <= 1.2 x the uniform scan).
2. Time per HDL-64E frame against the number of input points (every k-th
   point of the cloud, N = 1e5 ... 2.9e7).
3. The KITTI HDL-64E frame of ../shared/data re-scanned with its own table, as a VLP-16, a
   VLP-32C and at 0.4 and 0.144 deg from its own origin and from 1 m to the side (binning, embree with
   kNN discs, and embree with discs from the frame's own beam-table pulse grid,
   ``primary_pattern='velodyne_hdl64e_s2'``, with spacing radii and with the
   table's footprint radii): points out (also counted over the target's rows whose
   beam lies within the frame's observed elevation span, 1st-99th percentile), time; range images
   saved as docs/figures/kitti_<sensor>_<where>.png.
4. With ground truth: a synthetic room with a pillar scanned as an HDL-64E
   frame (exact ray casting), re-scanned as a VLP-16 from the same origin and
   from 1 m to the side by each backend (embree with kNN discs and with the
   frame's own pulse grid), against the room's exact VLP-16 scans: coverage
   and precision (10 cm).
5. With ground truth, a frame with a real sensor's departures from its table
   (per-beam elevation, azimuth and range offsets, noise, lost pulses):
   re-scanned with its own table, as a VLP-16 and at 0.4 deg, from its own
   origin and 1 m and 3 m aside (``real_frame_with_truth``).

Each embree setting is run with the beam-table defaults (tie window 3, discs
turned to at most 80 deg from the primary) and, beside them, with the
previous ones (``ties=1, max_incidence=90``).

Saves results/bench_sensors.json; ``--frame-only`` runs 1. and 2. (medians
of ``--repeat`` rounds taken in turn beside the best) and saves
results/bench_sensors_frame.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, realistic_cloud, save  # noqa: E402

from slr_ray import ScanPattern, prepare  # noqa: E402
from slr_ray.sensors import sensor  # noqa: E402

ORIGIN = [12.3, -7.1, 0.0]
#: how each frame is re-scanned: binning, kNN discs, discs from the frame's own beam-table grid
BACKENDS = (("binning", {}), ("embree", {}),
            ("embree pulse-grid", {"primary_origin": [0.0, 0.0, 0.0], "primary_pattern": "velodyne_hdl64e_s2"}),
            # the pulse-grid discs as they were before the beam-table defaults (tie window 1, no turn)
            ("embree pulse-grid ties 1, no turn", {"primary_origin": [0.0, 0.0, 0.0],
                                                   "primary_pattern": "velodyne_hdl64e_s2", "ties": 1.0,
                                                   "max_incidence": 90.0}),
            ("embree footprint", {"primary_origin": [0.0, 0.0, 0.0], "primary_pattern": "velodyne_hdl64e_s2",
                                  "radius": "footprint"}))
KITTI = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_hdl64_000000.bin"
FIGURES = Path(__file__).resolve().parents[1] / "docs" / "figures"


def best(fn, repeat):
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = fn()
        out.append(time.perf_counter() - t0)
    return min(out), res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--frame-only", action="store_true", help="only the 29 M-point frame timings (1. and 2.)")
    args = ap.parse_args(argv)
    hdl = sensor("velodyne_hdl64e_s2")
    cloud = np.ascontiguousarray(realistic_cloud())
    scanner = prepare(cloud)
    scanner.scan(ORIGIN, hdl)  # compile
    scanner.scan(ORIGIN, 0.144)
    t_hdl, s_hdl = best(lambda: scanner.scan(ORIGIN, hdl), args.repeat)
    t_uni, s_uni = best(lambda: scanner.scan(ORIGIN, ScanPattern(0.144)), args.repeat)
    frame = {"points": len(cloud), "hdl64e_seconds": t_hdl, "hdl64e_points_out": len(s_hdl),
             "uniform_0.144_seconds": t_uni, "uniform_points_out": len(s_uni), "ratio": t_hdl / t_uni}
    # the same in rounds taken in turn (a shared machine's load drifts): medians and the median ratio
    turns = {"hdl64e_s2": hdl, "vlp16": sensor("velodyne_vlp16"), "uniform": ScanPattern(0.144)}
    scanner.scan(ORIGIN, turns["vlp16"])
    took = {k: [] for k in turns}
    for _ in range(args.repeat):
        for k, p in turns.items():
            t0 = time.perf_counter()
            scanner.scan(ORIGIN, p)
            took[k].append(time.perf_counter() - t0)
    frame["in_turn"] = {k: {"median_seconds": float(np.median(v)), "all_seconds": v,
                            "median_ratio_to_uniform": float(np.median(np.array(v) / np.array(took["uniform"])))}
                        for k, v in took.items()}
    print(f"29 M cloud: HDL-64E frame {t_hdl:.3f} s ({len(s_hdl):,} points), 0.144 deg {t_uni:.3f} s "
          f"({len(s_uni):,}): ratio {t_hdl / t_uni:.2f}; in turn, median ratios: "
          + ", ".join(f"{k} {v['median_ratio_to_uniform']:.2f}" for k, v in frame["in_turn"].items()), flush=True)
    sizes = []
    for n in (100_000, 1_000_000, 10_000_000, len(cloud)):
        step = max(1, len(cloud) // n)  # every k-th point: the same scene, thinner
        sc = prepare(np.ascontiguousarray(cloud[::step][:n]))
        n = len(sc.points)
        t, s = best(lambda: sc.scan(ORIGIN, hdl), args.repeat)
        sizes.append({"points": n, "seconds": t, "points_out": len(s)})
        print(f"  {n:>12,} points: {t:.4f} s per HDL-64E frame, {len(s):,} out", flush=True)
    if args.frame_only:
        save("bench_sensors_frame", {"machine": machine(), "inputs": vars(args), "frame_vs_uniform": frame,
                                     "sizes": sizes})
        return
    kitti = []
    if KITTI.exists():
        from slr_ray.io import read_cloud
        from slr_ray.plotting import range_image_figure, save_figure

        k = read_cloud(KITTI)
        FIGURES.mkdir(parents=True, exist_ok=True)
        # the frame's observed elevation span (1st-99th percentile seen from its origin): KITTI's unit tops
        # out at ~+2.5 deg, the shipped (another unit's) S2 table at +5 deg
        k_el = np.degrees(np.arcsin(k.points[:, 2] / np.linalg.norm(k.points, axis=1)))
        seen_lo, seen_hi = np.percentile(k_el, [1, 99])
        # uniform 0.144 deg: the example (a little finer than the frame's 0.173 deg columns)
        for name in ("velodyne_hdl64e_s2", "velodyne_vlp16", "velodyne_vlp32c", "uniform 0.4", "uniform 0.144"):
            target = ScanPattern(float(name.split()[1])) if name.startswith("uniform") else sensor(name)
            for where, origin in (("own origin", [0.0, 0.0, 0.0]), ("1 m to the side", [0.0, 1.0, 0.0])):
                for backend, opts in BACKENDS:
                    sc = prepare(k.points, backend.split()[0], **opts)
                    sc.scan(origin, target)
                    t, s = best(lambda: sc.scan(origin, target), args.repeat)
                    row = {"sensor": name, "where": where, "backend": backend, "seconds": t,
                           "points_in": len(k), "points_out": len(s)}
                    if not name.startswith("uniform"):
                        # rows whose beam lies within what the frame saw (about -23.5 ... +2.6 deg): a
                        # VLP-16's +3 deg band (2 ... 4 deg) still catches the frame's top ring, 0.5-1 deg
                        # below the beam, by binning; a ray along the beam passes above it
                        inside = (np.asarray(target.elevation_deg) >= seen_lo) & (
                            np.asarray(target.elevation_deg) <= seen_hi)
                        row["points_out_rows_inside"] = int(inside[s.rings].sum())
                    kitti.append(row)
                    print(f"  KITTI -> {name} from {where}, {backend}: {len(s):,} points"
                          + (f" ({row['points_out_rows_inside']:,} in rows inside the frame's elevation span)"
                             if "points_out_rows_inside" in row else "") + f", {t:.3f} s", flush=True)
                    if backend == "binning" and not name.startswith("uniform"):
                        tag = "own" if where == "own origin" else "side"
                        img = s.range_image({"intensity": k.attributes["intensity"]})
                        save_figure(range_image_figure(img, title=f"KITTI frame as {name}, {where}", max_range=50),
                                    FIGURES / f"kitti_{name}_{tag}.png")
    truth_rows = with_truth()
    real_rows = real_frame_with_truth()
    save("bench_sensors", {"machine": machine(), "inputs": vars(args), "frame_vs_uniform": frame,
                           "sizes": sizes, "kitti": kitti, "room_hdl64_to_vlp16": truth_rows,
                           "real_frame_with_truth": real_rows})


def with_truth():
    import trimesh

    from slr_ray import agreement, scan_mesh

    box = trimesh.creation.box(extents=[40, 30, 8])
    box.invert()  # seen from inside
    cyl = trimesh.creation.cylinder(radius=0.8, height=8.0)
    cyl.apply_translation([3.0, 2.0, 0.0])
    mesh = trimesh.util.concatenate([box, cyl])
    o = np.array([0.0, 0.0, -2.0])
    frame = scan_mesh(mesh, o, sensor("velodyne_hdl64e_s2"))
    rows = []
    for where, shift in (("own origin", [0, 0, 0]), ("1 m to the side", [0, 1.0, 0])):
        origin = o + shift
        truth = scan_mesh(mesh, origin, sensor("velodyne_vlp16"))
        for backend, opts in BACKENDS:
            if opts:
                opts = {**opts, "primary_origin": o}
            s = prepare(frame.points, backend.split()[0], **opts).scan(origin, sensor("velodyne_vlp16"))
            a = agreement(truth.points, frame.points[s.indices])
            rows.append({"where": where, "backend": backend, "frame_points": len(frame), "true_points": len(truth),
                         "points_out": len(s), "coverage": a.coverage, "precision": a.precision})
            print(f"  room HDL-64E frame -> VLP-16 from {where}, {backend}: {len(s):,} points, coverage "
                  f"{100 * a.coverage:.1f} %, precision {100 * a.precision:.1f} %", flush=True)
    return rows


def street_frame(seed: int = 0):
    """``(mesh, origin, points)``: :func:`real_frame_with_truth`'s scene (a 40 x 30 x 8 m street-like box,
    a parked car, a pillar) scanned from ``origin`` as a miscalibrated HDL-64E with range noise and lost
    pulses (``seed``)."""
    import trimesh

    from slr_ray import scan_mesh
    from slr_ray.sensors import miscalibrated, sensor_noise

    box = trimesh.creation.box(extents=[40, 30, 8])
    box.invert()
    cyl = trimesh.creation.cylinder(radius=0.8, height=8.0)
    cyl.apply_translation([3.0, 2.0, 0.0])
    car = trimesh.creation.box(extents=[4, 1.8, 1.5])
    car.apply_translation([6, -4, -3.25])
    mesh = trimesh.util.concatenate([box, cyl, car])
    nominal = sensor("velodyne_hdl64e_s2")
    o = np.array([0.0, 0.0, -2.0])
    frame = scan_mesh(mesh, o, miscalibrated(nominal, seed=seed))
    pts, _ = sensor_noise(frame.points, o, frame.pulses[:, 0], seed=seed)
    return mesh, o, pts


def real_frame_with_truth(seed: int = 0):
    """A frame with a real sensor's departures from its table, with ground truth.

    A street-like box (40 x 30 x 8 m) with a parked car and a pillar, scanned
    as an HDL-64E whose beams are off their nominal table (per-beam elevation
    and azimuth offsets of 0.1 deg, per-beam range offsets of 3 cm), with 1 cm
    range noise and 10 % of pulses lost; re-scanned with the nominal table, a
    VLP-16 and 0.4 deg from its own origin and from 1 m and 3 m aside, against
    exact scans of the box: points out (against binning's), coverage and
    precision (10 cm)."""
    from slr_ray import agreement, scan_mesh

    mesh, o, pts = street_frame(seed)
    rows = []
    for backend, opts in BACKENDS:
        if opts:
            opts = {**opts, "primary_origin": o}
        t0 = time.perf_counter()
        sc = prepare(pts, backend.split()[0], **opts)
        t_prep = time.perf_counter() - t0
        for where, shift in (("own origin", [0, 0, 0]), ("1 m aside", [0, 1.0, 0]), ("3 m aside", [0, 3.0, 0])):
            origin = o + shift
            for target in ("velodyne_hdl64e_s2", "velodyne_vlp16", 0.4):
                pattern = sensor(target) if isinstance(target, str) else ScanPattern(target)
                truth = scan_mesh(mesh, origin, pattern)
                s = sc.scan(origin, pattern)
                a = agreement(truth.points, pts[s.indices])
                rows.append({"backend": backend, "where": where, "pattern": str(target), "frame_points": len(pts),
                             "points_out": len(s), "coverage": a.coverage, "precision": a.precision,
                             "prepare_seconds": t_prep, "scan_seconds": s.seconds})
                print(f"  real frame -> {target} from {where}, {backend}: {len(s):,} points, coverage "
                      f"{100 * a.coverage:.1f} %, precision {100 * a.precision:.1f} %", flush=True)
    return rows


if __name__ == "__main__":
    main()
