"""The ``slr-ray`` command.

Results go to stdout as one line of JSON; logs and progress go to stderr. Any
error exits with status 2 and one line ``slr-ray: error: ...`` on stderr, and
leaves no output file behind.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["main"]


def _pattern_from_args(args):
    from .pattern import ScanPattern, preset

    if getattr(args, "preset", None):
        base = preset(args.preset)
        changes = {}
        if args.resolution is not None:
            changes["resolution"] = args.resolution
        if args.zenith_range is not None:
            changes["zenith_range"] = tuple(args.zenith_range)
        if args.max_range is not None:
            changes["max_range"] = args.max_range
        if args.min_range is not None:
            changes["min_range"] = args.min_range
        return base.with_(**changes) if changes else base
    if args.resolution is None:
        raise SystemExit("slr-ray: error: give --resolution DEG or --preset NAME")
    return ScanPattern(
        resolution=args.resolution,
        zenith_range=tuple(args.zenith_range) if args.zenith_range else (0.0, 180.0),
        min_range=args.min_range,
        max_range=args.max_range,
    )


def _add_pattern_args(p, origin_required=True):
    p.add_argument("--origin", nargs=3, type=float, metavar=("X", "Y", "Z"), required=origin_required,
                   help="scanner position, in the cloud's coordinates" + (
                       "" if origin_required else " (default: the input's recorded origin)"))
    p.add_argument("--resolution", type=float, metavar="DEG", help="angular resolution, both axes (degrees)")
    p.add_argument("--preset", choices=["slr", "syns", "primary", "primary-fine"],
                   help="a pattern of the paper (other options override its fields)")
    p.add_argument("--zenith-range", nargs=2, type=float, metavar=("A", "B"),
                   help="zenith field of view in degrees (0 = up; default 0 180)")
    p.add_argument("--min-range", type=float, metavar="M")
    p.add_argument("--max-range", type=float, metavar="M")


def _emit(obj):
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def cmd_scan(args):
    from .backends import simulate_scan
    from .io import check_format, read_cloud, write_cloud

    pattern = _pattern_from_args(args)
    out = Path(args.output)
    if out.exists() and not args.force:
        raise FileExistsError(f"{out} exists (use --force to overwrite)")
    check_format(out, args.format)  # refuse an unknown output format before any work
    if args.print_config:
        _emit({"input": str(args.input), "output": str(out), "origin": args.origin,
               "pattern": pattern.to_dict(), "backend": args.backend})
        return
    t0 = time.perf_counter()
    cloud = read_cloud(args.input, args.input_format)
    t_read = time.perf_counter() - t0
    origin = args.origin if args.origin is not None else cloud.origin
    if origin is None:
        hint = (" (its scan has no pose; by the E57 standard that means the scanner frame is the file's:"
                " --origin 0 0 0)") if cloud.meta.get("e57_pose") is False else ""
        raise ValueError(f"{args.input} records no scanner origin: give --origin X Y Z{hint}")
    scan = simulate_scan(cloud.points, origin, pattern, backend=args.backend)
    sub = cloud.subset(scan.indices)
    sub.origin = np.asarray(origin, float)
    if args.keep_range:
        sub.attributes["range"] = scan.ranges
    t1 = time.perf_counter()
    write_cloud(out, sub, args.format)
    _emit({**scan.summary(), "input": str(args.input), "output": str(out),
           "seconds_read": round(t_read, 6), "seconds_write": round(time.perf_counter() - t1, 6)})


def cmd_demo(args):
    from .demo import run_demo

    _emit(run_demo(args.output, n_rectangles=args.rectangles, n_positions=args.positions,
                   seed=args.seed, quick=args.quick))


def cmd_scene(args):
    from .io import PointCloud, write_cloud
    from .meshscan import scan_mesh
    from .scenes import scene_from_spec

    scene = scene_from_spec(args.spec)
    if args.scene_cmd == "info":
        _emit({"spec": args.spec, **scene.info()})
        return
    if args.scene_cmd == "build":
        out = Path(args.output)
        if out.suffix.lower() not in (".ply", ".obj", ".stl", ".glb", ".off"):
            raise ValueError(f"mesh output must be .ply, .obj, .stl, .glb or .off, got {out.suffix!r}")
        from .io import atomic_path

        with atomic_path(out) as tmp:
            scene.mesh.export(tmp, file_type=out.suffix[1:].lower())
        _emit({"spec": args.spec, "output": str(out), **scene.info()})
        return
    pattern = _pattern_from_args(args)
    from .io import check_format

    check_format(args.output)  # refuse an unknown output format before the scan
    ms = scan_mesh(scene, args.origin, pattern, mode=args.mode, supersample=args.supersample,
                   spacing=args.spacing, progress=not args.quiet)
    cloud = PointCloud(ms.points, {"label": ms.labels.astype(np.int32), "range": ms.ranges,
                                   "v": ms.pulses[:, 0].astype(np.int32),
                                   "h": ms.pulses[:, 1].astype(np.int32)},
                       origin=ms.origin)
    write_cloud(args.output, cloud)
    _emit({"spec": args.spec, "output": str(args.output), **ms.summary()})


def cmd_compare(args):
    from .compare import compare_backends, plot_comparison
    from .io import read_cloud

    pattern = _pattern_from_args(args)
    cloud = read_cloud(args.input, args.input_format)
    opts = {"orientation": args.orientation, "segments": args.segments, "radius_scale": args.radius_scale}
    try:
        opts["radius"] = float(args.radius)
    except ValueError:
        opts["radius"] = args.radius
    if args.primary_origin is not None:
        opts["primary_origin"] = args.primary_origin
        opts["primary_resolution"] = args.primary_resolution
    res = compare_backends(cloud.points, np.array(args.origin, float).reshape(-1, 3), pattern,
                           tolerance=args.tolerance, embree_options=opts)
    if args.png:
        from .io import atomic_path

        with atomic_path(Path(args.png)) as tmp:
            plot_comparison(res, tmp)
        res["png"] = args.png
    _emit(res)


def _ground_labels(cloud, args):
    """Ground labels from the input's attributes, or CSF when asked."""
    attrs = cloud.attributes
    if args.ground_attribute:
        if args.ground_attribute not in attrs:
            raise ValueError(f"no attribute {args.ground_attribute!r} in the input (has {sorted(attrs)})")
        a = np.asarray(attrs[args.ground_attribute])
        return a.astype(bool) if a.dtype == bool else a == args.ground_value
    found = None
    if "is_ground" in attrs:
        found = np.asarray(attrs["is_ground"]).astype(bool)
    elif "classification" in attrs:
        found = np.asarray(attrs["classification"]) == 2
    if found is not None and found.any():
        return found
    if args.csf:
        from .positions import label_ground

        return label_ground(cloud.points, cloth_resolution=args.cloth_resolution)
    if found is not None:
        raise ValueError("the input's ground labels (is_ground / classification 2) mark no point as ground; "
                         "label them with --csf")
    raise ValueError("the input has no ground labels (is_ground, classification); "
                     "name one with --ground-attribute or label them with --csf")


def cmd_positions(args):
    from .io import atomic_path, read_cloud
    from .positions import AzimuthProfile, default_profile, plot_cells, select_positions

    out = Path(args.output)
    if not out.parent.is_dir():
        raise FileNotFoundError(f"no directory {out.parent} for {out}")
    cloud = read_cloud(args.input, args.input_format)
    is_ground = _ground_labels(cloud, args)
    profile = None if args.profile == "none" else default_profile() if args.profile == "default" \
        else AzimuthProfile.load(args.profile)
    positions, cells = select_positions(
        cloud.points, is_ground, args.n, seed=args.seed, cell_size=args.cell_size,
        min_ground_points=args.min_ground_points, ground_count_radius=args.ground_count_radius,
        ground_height_radius=args.ground_height_radius, scanner_height=args.scanner_height,
        profile=profile, allow_fewer=args.allow_fewer, return_cells=True)
    res = {"input": str(args.input), "n_requested": args.n, "seed": args.seed,
           "positions": positions.tolist(), "ground_points": int(is_ground.sum()), **cells.summary()}
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(res, indent=1))
    if args.png:
        with atomic_path(Path(args.png)) as tmp:
            plot_cells(cells, tmp, positions, cloud.points)
    _emit({k: v for k, v in res.items() if k != "positions"} | {"n_positions": len(positions),
                                                               "output": str(out)})


def cmd_profile(args):
    from .io import atomic_path
    from .positions import build_synthetic_profile

    prof = build_synthetic_profile(tuple(args.scenes.split(",")), args.positions_per_scene, args.seed)
    with atomic_path(Path(args.output)) as tmp:
        prof.save(tmp)
    _emit({"output": args.output, "n_scans": prof.meta["n_scans"], "min": int(prof.counts[0]),
           "max": int(prof.counts[-1])})


def cmd_validate(args):
    from .validate import (PAPER_Q1_SCENES, PAPER_Q2_SCENES, load_config, paper_report, paper_report_markdown,
                           plot_paper_figure, plot_validation, run_validation)

    config = load_config(args.config)
    if args.positions is not None:
        config.positions = args.positions
    if args.print_config:
        from dataclasses import asdict

        _emit(asdict(config))
        return
    out = Path(args.output or f"slr_ray_validate_{config.name}")
    res = run_validation(config, out, progress=not args.quiet)
    from .io import atomic_path

    with atomic_path(out / "figure3.png") as tmp:
        plot_validation(out / "results.csv", tmp)
    res["figures"] = [str(out / "figure3.png")]
    report = paper_report(out / "results.csv")
    with atomic_path(out / "report.json") as tmp:
        tmp.write_text(json.dumps(report, indent=1))
    with atomic_path(out / "report.md") as tmp:
        tmp.write_text(paper_report_markdown(report))
    res["report"] = str(out / "report.md")
    paper_scenes = set(PAPER_Q1_SCENES) | set(PAPER_Q2_SCENES)
    if any(config.scene_entry(e)[0] in paper_scenes for e in config.scenes):
        for b in config.backends:
            png = out / f"paper_figure_{b}.png"
            with atomic_path(png) as tmp:
                plot_paper_figure(out / "results.csv", tmp, backend=b, truth="center")
            res["figures"].append(str(png))
    _emit(res)


def cmd_distances(args):
    from .distances import DistanceHistogram, distance_histogram, height_sweep, plot_distances, pulse_sized_bins
    from .io import atomic_path, read_cloud
    from .pattern import ScanPattern
    from .positions import select_positions

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    bins = pulse_sized_bins(args.scanner_height, args.resolution, args.max_range, from_zero=True)
    original = DistanceHistogram(bins)
    slr = DistanceHistogram(bins)
    sweep = None
    pattern = ScanPattern(args.resolution, max_range=args.max_range)
    per_input = []
    for path in args.input:
        cloud = read_cloud(path)
        is_ground = _ground_labels(cloud, args)
        origin = cloud.origin if cloud.origin is not None else args.origin
        if origin is None:
            raise ValueError(f"{path} records no scanner origin: give --origin X Y Z")
        original += distance_histogram(cloud.points, origin, is_ground, bins)
        positions = select_positions(cloud.points, is_ground, args.positions, seed=args.seed,
                                     min_ground_points=args.min_ground_points, allow_fewer=True,
                                     scanner_height=args.scanner_height)
        sw = height_sweep(cloud.points, is_ground, positions, args.heights, pattern,
                          scanner_height=args.scanner_height, progress=not args.quiet)
        if sweep is None:
            sweep = sw
        else:
            for h in sweep:
                sweep[h] += sw[h]
        # SLR clouds at the scanner height, on the common bins
        from .backends import prepare

        scanner = prepare(cloud.points)
        for p in positions:
            scan = scanner.scan(p, pattern)
            slr.add(cloud.points[scan.indices], p, is_ground[scan.indices])
        per_input.append({"input": str(path), "positions": len(positions),
                          "ground_fraction": float(is_ground.mean())})
    files = {"original.csv": original, "slr.csv": slr} | {f"height_{h:g}m.csv": v for h, v in (sweep or {}).items()}
    for name, hist in files.items():
        with atomic_path(out / name) as tmp:
            hist.to_csv(tmp)
    with atomic_path(out / "distances.png") as tmp:
        plot_distances(original, slr, sweep, tmp)
    _emit({"output_dir": str(out), "inputs": per_input, "original": original.summary(), "slr": slr.summary(),
           "heights": {f"{h:g}": {"peak_ground_m": v.peak("ground"), "peak_non_ground_m": v.peak("non_ground")}
                       for h, v in (sweep or {}).items()},
           "files": sorted(files) + ["distances.png"]})


def cmd_augment(args):
    from .augment import augment
    from .io import read_cloud

    ground = None
    if args.csf or args.ground_attribute:
        ground = _ground_labels(read_cloud(args.input), args)
    res = augment(args.input, args.output, args.n, backend=args.backend, resolution=args.resolution,
                  heights=tuple(args.heights), fmt=args.format, seed=args.seed,
                  min_ground_points=args.min_ground_points, ground=ground, workers=args.workers,
                  scheduler=args.scheduler, progress=not args.quiet)
    _emit({k: res[k] for k in ("input", "n_requested", "new_scans", "seconds", "software")}
          | {"scans": len(res["scans"]), "positions": len(res["positions"]),
             "points_out": sum(s["points"] for s in res["scans"]), "output_dir": str(args.output)})


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    ap = argparse.ArgumentParser(prog="slr-ray", description=(
        "Simulated LiDAR Repositioning: simulate the scans an ideal static scanner "
        "would record from new positions, using only points of one cloud."))
    ap.add_argument("--version", action="version", version=f"slr-ray {__version__}")
    sub = ap.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("scan", help="simulate one scan of a point cloud from a position")
    p.add_argument("input", help="input cloud (.npy, .npz, .ply, .las, .laz, .bin (KITTI), .xyz, .txt)")
    _add_pattern_args(p, origin_required=False)
    p.add_argument("-o", "--output", required=True, help="output cloud (same formats)")
    p.add_argument("--backend", default="binning", choices=["binning", "embree"])
    p.add_argument("--format", help="output format, overriding the extension")
    p.add_argument("--input-format", help="input format, overriding the extension")
    p.add_argument("--keep-range", action="store_true", help="add a 'range' attribute")
    p.add_argument("--force", action="store_true", help="overwrite the output")
    p.add_argument("--print-config", action="store_true",
                   help="print the resolved configuration as JSON and stop")
    p.set_defaults(func=cmd_scan)

    p = sub.add_parser("compare", help="run both backends on a cloud and report where they differ")
    p.add_argument("input", help="input cloud (.npy, .npz, .ply)")
    p.add_argument("--origin", nargs=3, type=float, action="append", required=True, metavar=("X", "Y", "Z"),
                   help="a scanner position (repeat for several)")
    p.add_argument("--resolution", type=float, metavar="DEG")
    p.add_argument("--preset", choices=["slr", "syns", "primary", "primary-fine"])
    p.add_argument("--zenith-range", nargs=2, type=float, metavar=("A", "B"))
    p.add_argument("--min-range", type=float, metavar="M")
    p.add_argument("--max-range", type=float, metavar="M")
    p.add_argument("--tolerance", type=float, default=0.10, help="see-through tolerance (m, default 0.1)")
    p.add_argument("--radius", default="spacing", help="disc radius: metres, 'spacing' or 'footprint'")
    p.add_argument("--radius-scale", type=float, default=1.0)
    p.add_argument("--orientation", default="normal", choices=["normal", "billboard"])
    p.add_argument("--segments", type=int, default=5)
    p.add_argument("--primary-origin", nargs=3, type=float, metavar=("X", "Y", "Z"),
                   help="primary scanner (for --radius footprint)")
    p.add_argument("--primary-resolution", type=float, metavar="DEG")
    p.add_argument("--input-format")
    p.add_argument("--png", help="also write a figure")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("positions", help="choose secondary scanner positions (the paper's grid method)")
    p.add_argument("input", help="input cloud (.npy, .npz, .ply)")
    p.add_argument("--n", type=int, required=True, help="positions to draw")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", required=True, help="positions and per-stage counts (JSON)")
    p.add_argument("--ground-attribute", help="per-point attribute holding ground labels")
    p.add_argument("--ground-value", type=int, default=2, help="its ground value (default 2, LAS ground)")
    p.add_argument("--csf", action="store_true", help="label ground by Cloth Simulation Filtering if the input has no labels")
    p.add_argument("--cloth-resolution", type=float, default=0.5)
    p.add_argument("--cell-size", type=float, default=2.0)
    p.add_argument("--min-ground-points", type=int, default=50_000)
    p.add_argument("--ground-count-radius", type=float, default=5.0)
    p.add_argument("--ground-height-radius", type=float, default=3.0)
    p.add_argument("--scanner-height", type=float, default=1.65)
    p.add_argument("--profile", default="none", help="azimuth minimum profile: none (default), default, or a JSON path")
    p.add_argument("--allow-fewer", action="store_true", help="return fewer positions than --n if cells run out")
    p.add_argument("--png", help="also write a top view of the cells kept and removed")
    p.add_argument("--input-format")
    p.set_defaults(func=cmd_positions)

    p = sub.add_parser("profile", help="rebuild the shipped azimuth minimum profile from synthetic scans")
    p.add_argument("--scenes", default="distance-1,distance-2,distance-3,distance-4,distance-5")
    p.add_argument("--positions-per-scene", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", required=True)
    p.set_defaults(func=cmd_profile)

    p = sub.add_parser("validate", help="reproduce the paper's validation (Experiment 1) from a config")
    p.add_argument("config", help="a config name in scenes/ (quick, paper, distance, occlusion, resolution) "
                                  "or a TOML path")
    p.add_argument("-o", "--output", help="output directory (default slr_ray_validate_NAME); reruns resume")
    p.add_argument("--positions", type=int, help="override the number of positions per scene")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--print-config", action="store_true", help="print the resolved config and stop")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("distances", help="distance distributions with pulse-sized bins (the paper's Experiment 2)")
    p.add_argument("input", nargs="+", help="input clouds (each one scan; origin from the file or --origin)")
    p.add_argument("--origin", nargs=3, type=float, metavar=("X", "Y", "Z"))
    p.add_argument("--heights", nargs="+", type=float, default=[0.5, 1.0, 1.65, 2.5, 4.0])
    p.add_argument("--positions", type=int, default=20, help="SLR positions per input")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resolution", type=float, default=0.144)
    p.add_argument("--max-range", type=float, default=120.0)
    p.add_argument("--scanner-height", type=float, default=1.65)
    p.add_argument("--min-ground-points", type=int, default=50_000)
    p.add_argument("--ground-attribute")
    p.add_argument("--ground-value", type=int, default=2)
    p.add_argument("--csf", action="store_true")
    p.add_argument("--cloth-resolution", type=float, default=0.5)
    p.add_argument("--quiet", action="store_true")
    p.add_argument("-o", "--output", required=True, help="output directory (CSV tables, distances.png)")
    p.set_defaults(func=cmd_distances)

    p = sub.add_parser("augment", help="many simulated scans of one real scan (resumable, parallel)")
    p.add_argument("input", help="input cloud (.las, .laz, .ply, .npz, .bin, .xyz, ...)")
    p.add_argument("--n", type=int, required=True, help="positions")
    p.add_argument("-o", "--output", required=True, help="output directory (a rerun resumes)")
    p.add_argument("--backend", default="binning", choices=["binning", "embree"])
    p.add_argument("--resolution", type=float, default=0.144)
    p.add_argument("--heights", nargs="+", type=float, default=[1.65], help="scanner heights above ground")
    p.add_argument("--format", help="output extension (default: the input's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--min-ground-points", type=int, default=50_000)
    p.add_argument("--ground-attribute")
    p.add_argument("--ground-value", type=int, default=2)
    p.add_argument("--csf", action="store_true", help="label ground by CSF (the input has no labels)")
    p.add_argument("--cloth-resolution", type=float, default=0.5)
    p.add_argument("--workers", type=int, help="local worker processes (default: all cores)")
    p.add_argument("--scheduler", help="address of a dask.distributed scheduler to run on")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_augment)

    p = sub.add_parser("demo", help="the main job on a built-in scene: scene, primary scan, SLR scans, report")
    p.add_argument("-o", "--output", default="slr_ray_demo", help="output directory (default slr_ray_demo)")
    p.add_argument("--rectangles", type=int, default=200)
    p.add_argument("--positions", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="a coarser, faster run (for tests)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("scene", help="synthetic rectangle scenes: info, build, scan")
    ssub = p.add_subparsers(dest="scene_cmd", required=True)
    q = ssub.add_parser("info", help="counts of a scene spec (name in scenes/ or path)")
    q.add_argument("spec")
    q = ssub.add_parser("build", help="write the scene's mesh")
    q.add_argument("spec")
    q.add_argument("-o", "--output", required=True)
    q = ssub.add_parser("scan", help="ground-truth scan of a scene")
    q.add_argument("spec")
    _add_pattern_args(q)
    q.add_argument("--mode", default="center", choices=["center", "nearest", "dense"])
    q.add_argument("--supersample", type=int, default=4, help="k for --mode nearest (k x k rays a pulse)")
    q.add_argument("--spacing", type=float, default=0.005, help="grid spacing for --mode dense (m)")
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    q.add_argument("-o", "--output", required=True)
    p.set_defaults(func=cmd_scene)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except KeyboardInterrupt:
        print("slr-ray: interrupted", file=sys.stderr)
        return 130
    except (OSError, ValueError, TypeError, ImportError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"slr-ray: error: {msg}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
