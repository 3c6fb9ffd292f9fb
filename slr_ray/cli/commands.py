"""What each ``slr-ray`` subcommand does: read its flags, call the library, print one line of JSON.

The work itself lives in the library (:mod:`slr_ray.backends`,
:mod:`slr_ray.validation`, :mod:`slr_ray.distances`, ...): a command only
turns flags into arguments and results into files and a JSON line.
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from ..arrays import json_safe
from ..augment import AugmentConfig
from ..augment import augment as run_augment
from ..backends import backends_with, options_for, prepare, scanner_class, streams
from ..backends.embree.fit import fit_primary_pattern
from ..compare import compare_backends, compared_backends
from ..demo import run_demo
from ..distances import distance_study, study_files
from ..backends.embree import refuse_cast
from ..effects import effect_cloud, ray_count, simulate, simulate_given
from ..errors import InputValueError, SlrWarning
from ..io import PointCloud, atomic_path, check_format, read_cloud, write_cloud
from ..meshscan import scan_mesh
from ..io.outputs import OutputPlan
from ..paper import Q1_SCENES, Q2_SCENES
from ..progress import phase
from ..plotting import (check_figure_path, cells_figure, comparison_figure, distances_figure, paper_figure,
                        range_image_figure, save_figure, validation_figure)
from ..positions import (AzimuthProfile, default_profile, ground_labels, require_positions,
                         select_positions)
from ..scan import Scan, check_range_image
from ..sensorfit import RING_FIELDS
from ..scenes import MESH_FORMATS, scene_effects, scene_from_spec
from ..io.streaming import STREAMED_FORMATS, checked_bounds, las_bounds
from ..streaming import scan_las
from ..validation import (build_synthetic_profile, load_config, load_rows, paper_report, paper_report_markdown,
                          run_validation, stage_summary)
from .arguments import backend_from, check_effects, effects_from, ground_from, pattern_from

__all__ = ["emit", "COMMANDS"]


def emit(obj) -> None:
    """The command's result: one line of strict JSON on stdout (nan and inf as null)."""
    sys.stdout.write(json.dumps(json_safe(obj), allow_nan=False) + "\n")
    sys.stdout.flush()


def _plan(args, *, inputs=(), outputs=(), fmt=None, figures=()) -> OutputPlan:
    """The command's :class:`~slr_ray.outputs.OutputPlan`: its inputs (with their
    sidecars and the secondary inputs its flags name), its outputs and its
    figures (whose format is checked with the rest), checked."""
    plan = OutputPlan(force=getattr(args, "force", False))
    for path in inputs:
        plan.read(path, fmt=getattr(args, "input_format", None))  # --input-format bin reads a .label beside it
    for flag in ("sensor_file", "profile_file", "effects", "ray_drop"):
        plan.read(getattr(args, flag, None), sidecars=False)
    for i, path in enumerate(outputs):
        plan.write(path, fmt=fmt if i == 0 else None)
    for path in figures:
        plan.write(path, check=check_figure_path)
    return plan.check()


def scan(args):
    plan, pattern, options, effects = _scan_checked(args)
    if args.print_config:
        emit({"input": str(args.input), "output": str(args.output), "origin": args.origin,
              "origin_relative": args.origin_relative,
              "pattern": pattern.to_dict(), "backend": args.backend, "options": options.to_dict(),
              "effects": None if effects is None else effects.to_dict()})
        return
    # LAS/LAZ stream through the uniform binning reduction; beam tables and effects read the file whole
    streamed = (effects is None and streams(scanner_class(args.backend), pattern)
                and check_format(args.input, args.input_format) in STREAMED_FORMATS)
    with plan:
        if streamed:
            (result, sub, bounds, said, t_read), primary = _scan_streamed(args, pattern), None
        else:
            result, sub, bounds, said, t_read, primary = _scan_read(args, pattern, options, effects)
        if not said:
            _check_returns(result, bounds)
        kept = _keep(args, sub, result)
        _say_carried_rings(args, sub, pattern, kept)
        # the range image is made before anything is written: an error there leaves no scan behind
        image = _range_image(args, sub, result, skip=kept) if args.range_image or args.png else None
        t1 = time.perf_counter()
        write_cloud(args.output, sub, args.format)
        if image is not None:
            _write_range_image(args, image, result)
    emit({**result.summary(), **({"primary": primary} if not streamed and primary else {}),
          "input": str(args.input), "output": str(args.output), "streamed": streamed,
          ("seconds_read_and_scan" if streamed else "seconds_read"): round(t_read, 6),
          "seconds_write": round(time.perf_counter() - t1, 6)})


def _scan_checked(args):
    """``scan``'s refusals before any work, and what they check: (the output plan, the pattern, the
    backend's options, the effects)."""
    check_format(args.output, args.format)  # refuse an unknown output format before any work
    if args.range_image and Path(args.range_image).suffix.lower() != ".npz":
        # it is written as numpy's .npz whatever its name: a .txt or .png of npz bytes misleads
        raise InputValueError(f"--range-image {args.range_image}: the range image is written as .npz "
                              "(for a picture, --png)")
    plan = _plan(args, inputs=[args.input], outputs=[args.output, args.range_image], fmt=args.format,
                 figures=[args.png])
    pattern = pattern_from(args)
    if args.range_image or args.png:
        check_range_image(pattern)  # before the scan, not after it
    options = options_for(args.backend, backend_from(args))  # built once, used below
    effects = check_effects(effects_from(args), args.backend, pattern)
    if scanner_class(args.backend).casts_rays:  # before reading and preparing: binning answers at once
        refuse_cast(ray_count(pattern, effects), f"--backend {args.backend} (it casts rays, as do the backends "
                    f"with casts_rays: {', '.join(backends_with('casts_rays'))})",
                    "choose a coarser pattern (--resolution, --columns) or a smaller --divergence-mrad cone")
    if effects is not None and (args.range_image or args.png):
        raise InputValueError("--range-image and --png draw an ideal scan (one point a pulse): drop them, or the "
                              "effects (slr_ray.effects.range_image draws a scan with effects)")
    return plan, pattern, options, effects


def _scan_streamed(args, pattern):
    """LAS/LAZ: one pass in chunks, memory bounded by a chunk and the scan, not the file. Returns
    (the scan, the points kept, the bounds, whether the origin's check said something, seconds)."""
    bounds = las_bounds(args.input)  # the header's: no point read (None: no point, refused by the scan)
    origin = _origin(args, None, bounds or (np.zeros(3), np.zeros(3)))
    said = bounds is None or _check_origin(origin, bounds, pattern)
    t0 = time.perf_counter()
    sub, result = scan_las(args.input, origin, pattern, chunk=args.chunk_size, progress=not args.quiet)
    read = checked_bounds(args.input, bounds, sub.meta.pop("points_bounds"), sub.meta["las_scales"])
    if bounds is not None and not all(map(np.array_equal, read, bounds)):
        # the header lied about its bounds (said on stderr): the origin and its check from the points
        bounds, before = read, origin
        origin = _origin(args, None, bounds)
        said = _check_origin(origin, bounds, pattern)
        if not np.array_equal(origin, before):
            sub, result = scan_las(args.input, origin, pattern, chunk=args.chunk_size,
                                   progress=not args.quiet)
            sub.meta.pop("points_bounds")
    sub.origin = np.asarray(origin, float)
    return result, sub, bounds, said, time.perf_counter() - t0


def _scan_read(args, pattern, options, effects):
    """A cloud read whole, prepared and scanned (with its effects). Returns (the scan, the points
    kept, the bounds, whether the origin's check said something, seconds to read, the primary)."""
    t0 = time.perf_counter()
    cloud = read_cloud(args.input, args.input_format, allow_empty=False)
    t_read = time.perf_counter() - t0
    bounds = (cloud.points.min(axis=0), cloud.points.max(axis=0))
    origin = _origin(args, cloud.origin, bounds, cloud.meta.get("e57_pose") is False)
    said = _check_origin(origin, bounds, pattern)
    if effects is not None and effects.intensity == "correct" and cloud.origin is None:
        raise InputValueError(f"--intensity correct needs where {args.input} was scanned from, and it "
                              "records no scanner origin (use --intensity carry)")
    options, primary = _primary_from_file(args, cloud, options)
    with phase(f"{args.backend}: preparing {len(cloud):,} points", progress=not args.quiet):
        scanner = prepare(cloud.points, args.backend, options)
    if effects is None:
        with phase(f"{args.backend}: scanning", progress=not args.quiet):
            result = scanner.scan(origin, pattern)
        sub = cloud.subset(result.indices)
        sub.origin = np.asarray(origin, float)
    else:
        what = "with beam divergence" if effects.divergence_mrad else "with effects"
        with phase(f"{args.backend}: scanning {what}", progress=not args.quiet):
            result, sub = _scan_with_effects(args, cloud, origin, pattern, scanner, effects)
    return result, sub, bounds, said, t_read, primary


def _scan_with_effects(args, cloud, origin, pattern, scanner, effects):
    """(a Scan of the returns, for the summary and --keep-*; the cloud written)."""
    intensity = cloud.attributes.get("intensity")
    if intensity is not None and np.ndim(intensity) != 1:
        intensity = None
    t0 = time.perf_counter()
    es = simulate(scanner, origin, pattern, effects, intensity=intensity,
                  primary_origin=cloud.origin)
    info = {k: v for k, v in es.info.items() if k.startswith(("removed_", "returns_", "max_range_at"))}
    result = Scan(es.indices, es.ranges, es.pulses, es.origin, es.pattern, backend=args.backend,
                  n_input=len(cloud), seconds=time.perf_counter() - t0,
                  info={"effects": effects.to_dict(), **info,
                        "returns_in_multi_return_pulses": int(np.count_nonzero(es.number_of_returns > 1))})
    return result, effect_cloud(es, cloud)


def _keep(args, sub, result) -> set:
    """--keep-range / --keep-ring as attributes (their names are returned); an input attribute of
    those names is never replaced."""
    added = {}
    if args.keep_range:
        added["range"] = ("--keep-range", result.ranges)
    if args.keep_ring:
        dtype = np.uint16 if result.pattern.shape[0] < 2**16 else np.int64
        added["ring"] = ("--keep-ring", result.rings.astype(dtype))
        added["column"] = ("--keep-ring", result.columns.astype(np.uint32))
    clash = [f"{flag} ({name!r})" for name, (flag, _) in added.items() if name in sub.attributes]
    if clash:
        raise InputValueError(f"{args.input} has its own attribute(s) of the names {', '.join(clash)} would add: "
                              "refusing to replace them (rename them in the input, or drop the flag)")
    for name, (_, values) in added.items():
        sub.attributes[name] = values
    return set(added)


def _say_carried_rings(args, sub, pattern, kept) -> None:
    """A sensor's scan that carries the input's ring field (each point's beam on the input's unit) says so
    in one line: a reader of the output (``slr-ray sensor fit``, ``evaluate``) takes it for the scan's beams."""
    carried = [k for k in RING_FIELDS if k in sub.attributes and k not in kept]
    if carried and pattern.has_beams:
        name = getattr(pattern, "name", None) or "the sensor"
        warnings.warn(f"{args.output}: {', '.join(map(repr, carried))} carried from {args.input}: each point's "
                      f"beam on the input's unit, not one of {name}'s {pattern.shape[0]} "
                      "beams it was scanned by (slr-ray sensor fit and evaluate read it as the scan's beams); "
                      "--keep-ring writes the scan's own once the input's is renamed or dropped", SlrWarning,
                      stacklevel=2)


def _range_image(args, sub, result, skip=()) -> dict:
    """The scan's range image with every 1-D attribute of ``sub`` (the scanned subset, in index order)
    but those in ``skip`` (--keep-range's and --keep-ring's: the image has its own range, ring and column)."""
    local = replace(result, indices=np.arange(len(result)))  # images of the subset's own rows
    attrs = {k: v for k, v in sub.attributes.items()
             if k not in skip and np.asarray(v).ndim == 1 and np.asarray(v).dtype.kind in "biuf"}
    taken = sorted(set(attrs) & {"range", "ring", "index"})  # the image's own arrays
    if taken:
        flags = " and ".join(f for f, on in (("--range-image", args.range_image), ("--png", args.png)) if on)
        raise InputValueError(f"{args.input} has its own attribute(s) {', '.join(map(repr, taken))}: names the range "
                              f"image of {flags} keeps for its own arrays: rename them in the input, or drop {flags}")
    image = local.range_image(attrs)
    local_index = image["index"]
    image["index"] = np.full(local_index.shape, -1, dtype=np.asarray(result.indices).dtype)
    hit = local_index >= 0
    image["index"][hit] = result.indices[local_index[hit]]  # an empty scan has no index to look up
    return image


def _write_range_image(args, image, result):
    if args.range_image:
        with atomic_path(Path(args.range_image)) as tmp:
            with open(tmp, "wb") as f:
                np.savez_compressed(f, **image)
    if args.png:
        save_figure(range_image_figure(image, title=f"{result.pattern.to_dict().get('name') or 'scan'} "
                                                    f"from {np.round(result.origin, 2).tolist()}"), args.png)


def _primary_from_file(args, cloud, options):
    """Embree options with the primary taken from the input file when the user gave none: where its
    scanner was (a KITTI .bin is in its sensor's frame; an .npz origin, PCD VIEWPOINT, E57 pose) and
    its pattern fitted to the points (``primary_pattern='fit'``: a .bin's scan order gives its beams).
    Returns ``(options, what the JSON says about it, or None)``."""
    takes = scanner_class(args.backend).primary_options  # {} for a backend that is told nothing of its primary
    if cloud.origin is None or not takes((0.0, 0.0, 0.0), 1.0):
        return options, None
    given = backend_from(args)
    if any(k in given for k in ("primary_origin", "primary_pattern", "primary_resolution")):
        return options, None
    origin = np.asarray(cloud.origin, np.float64)
    try:
        fitted, how, quality = fit_primary_pattern(cloud.points, origin)
    except InputValueError as e:  # no grid, or not a scan's: the discs go without the primary (kNN), and say why
        warnings.warn(f"{args.input}: its pattern is not fitted, the discs take kNN neighbours: {e}", SlrWarning,
                      stacklevel=2)
        return options, {"from_file": False, "why": str(e)}
    with_primary = options_for(args.backend, {**given, **takes(tuple(origin.tolist()), fitted)})
    return with_primary, {"from_file": True, "origin": origin.tolist(), "pattern": fitted.to_dict(), "fit": how,
                          "fit_quality": round(quality, 4),
                          "why": f"{args.input} records where its scanner was; its pattern is fitted to the points "
                                 "(--primary-origin and --primary-pattern or --primary-resolution choose them)"}


def _origin(args, recorded, bounds, poseless_e57: bool = False):
    """--origin, else the input's recorded origin; with --origin-relative, --origin
    (default 0 0 0) is an offset from the cloud's centre or its recorded origin."""
    offset = np.zeros(3) if args.origin is None else np.asarray(args.origin, float)
    if args.origin_relative == "centre":
        return 0.5 * (bounds[0] + bounds[1]) + offset
    if args.origin_relative is None and args.origin is not None:
        return offset
    if recorded is None:
        hint = (" (its scan has no pose; by the E57 standard that means the scanner frame is the file's:"
                " --origin 0 0 0)") if poseless_e57 else ""
        raise InputValueError(f"{args.input} records no scanner origin: give --origin X Y Z"
                              f"{' (or --origin-relative centre)' if args.origin_relative else ''}{hint}")
    return np.asarray(recorded, float) + offset


def _extent(bounds) -> str:
    lo, hi = bounds
    return ", ".join(f"{a} {lo[i]:,.1f} to {hi[i]:,.1f}" for i, a in enumerate("xyz"))


def _check_origin(origin, bounds, pattern, relative: bool = True) -> bool:
    """Refuse an origin from which the pattern reaches no point of the cloud; warn
    when it lies over 1 km and ten times the cloud's width outside it (a local
    origin given for a georeferenced cloud, say): True when it warned."""
    lo, hi = (np.asarray(b, float) for b in bounds)
    o = np.asarray(origin, float)
    gap = float(np.linalg.norm(np.maximum(lo - o, 0.0) + np.maximum(o - hi, 0.0)))  # distance to the box
    reach = pattern.range_limits[1]
    where = (f"the origin ({', '.join(f'{v:,.2f}' for v in o)}) lies {gap:,.1f} m outside the cloud "
             f"({_extent(bounds)})")
    hint = "give it in the cloud's coordinates" + (", or from its centre with --origin-relative centre"
                                                    if relative else "")
    if gap > reach:
        raise InputValueError(f"{where}, beyond the pattern's max range ({reach:g} m): the scan would be empty; "
                              f"{hint}")
    if gap > max(1000.0, 10 * float(np.linalg.norm(hi - lo))):
        warnings.warn(f"{where}, over ten times farther than the cloud is wide: {hint}", SlrWarning, stacklevel=2)
        return True
    return False


#: A scan returning fewer than one point in this many of a cloud of at least as many is said to (almost) miss it.
_SPARSE = 10_000


def _check_returns(result, bounds) -> None:
    """Warn when a scan returns almost nothing of a large cloud."""
    if result.n_input >= _SPARSE and len(result) * _SPARSE < result.n_input:
        warnings.warn(f"the scan returned {len(result):,} of the cloud's {result.n_input:,} points: is the origin "
                      f"({', '.join(f'{v:,.2f}' for v in result.origin)}) where you meant, in the cloud's "
                      f"coordinates ({_extent(bounds)})? (--origin-relative centre takes it from the cloud's centre)",
                      SlrWarning, stacklevel=2)


def demo(args):
    emit(run_demo(args.output, n_rectangles=args.rectangles, n_positions=args.positions, seed=args.seed,
                  quick=args.quick, backends=args.backends, force=args.force, progress=not args.quiet))


def scene(args):
    spec_file = args.spec if Path(args.spec).suffix else None  # a path (any extension), not a shipped name
    if args.scene_cmd == "info":
        emit({"spec": args.spec, **scene_from_spec(args.spec).info()})
        return
    if args.scene_cmd == "build":
        out = Path(args.output)
        if out.suffix.lower()[1:] not in MESH_FORMATS:
            raise InputValueError(f"mesh output must be one of {['.' + f for f in MESH_FORMATS]}, "
                                  f"got {out.suffix!r}")
        plan = _plan(args, inputs=[spec_file] if spec_file else [], outputs=[out])
        sc = scene_from_spec(args.spec)
        with plan, atomic_path(out) as tmp:
            sc.mesh.export(tmp, file_type=out.suffix[1:].lower())
        emit({"spec": args.spec, "output": str(out), **sc.info()})
        return
    check_format(args.output)  # refuse an unknown output format before the scan
    plan = _plan(args, inputs=[spec_file] if spec_file else [], outputs=[args.output])
    pattern = pattern_from(args)
    effects = None if args.no_effects else scene_effects(args.spec)  # the effects the scene requires
    if effects is not None and not effects.any:
        effects = None
    if effects is not None:
        effects = effects.resolve(pattern)
        if effects.divergence_mrad or effects.motion:
            raise InputValueError(f"{args.spec}: [effects] asks for beam divergence or motion, which a mesh scan "
                                  "does not model (it takes ray drop, range limits, noise): drop them there, "
                                  "or give --no-effects")
    sc = scene_from_spec(args.spec)
    with plan:
        ms = scan_mesh(sc, args.origin, pattern, mode=args.mode, supersample=args.supersample,
                       spacing=args.spacing, progress=not args.quiet)
        points, labels, ranges, pulses, info = ms.points, ms.labels, ms.ranges, ms.pulses, {}
        if effects is not None:
            given = Scan(np.arange(len(ms.points)), ms.ranges, ms.pulses, ms.origin, ms.pattern, backend="mesh")
            es = simulate_given(given, ms.points, effects)
            points, labels, ranges, pulses = es.points, ms.labels[es.indices], es.ranges, es.pulses
            info = {"effects": effects.to_dict(), "points_before_effects": len(ms.points),
                    **{k: v for k, v in es.info.items() if k.startswith("removed_")}}
        cloud = PointCloud(points, {"label": labels.astype(np.int32), "range": ranges,
                                    "v": pulses[:, 0].astype(np.int32), "h": pulses[:, 1].astype(np.int32)},
                           origin=ms.origin)
        write_cloud(args.output, cloud)
    emit({"spec": args.spec, "output": str(args.output), **ms.summary(), "points_out": len(points), **info})


def compare(args):
    plan = _plan(args, inputs=[args.input], figures=[args.png])
    pattern = pattern_from(args)
    ray_backend = compared_backends()[1]  # the pair from the registry's capabilities (binning, embree)
    ray_options = backend_from(args, ray_backend)
    with plan:
        cloud = read_cloud(args.input, args.input_format, allow_empty=False)
        bounds = (cloud.points.min(axis=0), cloud.points.max(axis=0))
        for origin in args.origin:  # each reaches the cloud (a local origin for a UTM cloud does not)
            _check_origin(origin, bounds, pattern, relative=False)
        res = compare_backends(cloud.points, np.array(args.origin, float).reshape(-1, 3), pattern,
                               tolerance=args.tolerance, ray_options=ray_options, progress=not args.quiet)
        if args.png:
            save_figure(comparison_figure(res), args.png)
            res["png"] = args.png
    emit(res)


def positions(args):
    args.profile_file = None if args.profile in ("none", "default") else args.profile
    plan = _plan(args, inputs=[args.input], outputs=[args.output], figures=[args.png])
    ground = ground_from(args)
    with plan:
        profile = None if args.profile == "none" else default_profile() if args.profile == "default" \
            else AzimuthProfile.load(args.profile)  # before CSF, which can take a minute
        cloud = read_cloud(args.input, args.input_format, allow_empty=False)
        is_ground = ground_labels(cloud, **ground, progress=not args.quiet)
        pos, cells = select_positions(
            cloud.points, is_ground, args.n, seed=args.seed, cell_size=args.cell_size,
            min_ground_points=args.min_ground_points, ground_count_radius=args.ground_count_radius,
            ground_height_radius=args.ground_height_radius, scanner_height=args.scanner_height,
            profile=profile, allow_fewer=args.allow_fewer, return_cells=True,
            progress=profile is not None and not args.quiet)
        require_positions(pos, args.n, cells, args.input)  # --allow-fewer is fewer, not none: as augment
        res = {"input": str(args.input), "n_requested": args.n, "seed": args.seed,
               "positions": pos.tolist(), "ground_points": int(is_ground.sum()), **cells.summary()}
        with atomic_path(args.output) as tmp:
            tmp.write_text(json.dumps(res, indent=1))
        if args.png:
            save_figure(cells_figure(cells, pos, cloud.points), args.png)
    emit({k: v for k, v in res.items() if k != "positions"} | {"n_positions": len(pos), "output": str(args.output)})


def profile(args):
    plan = _plan(args, outputs=[args.output])
    with plan:
        prof = build_synthetic_profile(tuple(args.scenes.split(",")), args.positions_per_scene, args.seed)
        with atomic_path(args.output) as tmp:
            prof.save(tmp)
    emit({"output": args.output, "n_scans": prof.meta["n_scans"], "min": int(prof.counts[0]),
          "max": int(prof.counts[-1])})


def validate(args):
    config = load_config(args.config)
    if args.positions is not None:
        config.positions = args.positions
    if args.print_config:
        emit(asdict(config))
        return
    out = Path(args.output or f"slr_ray_validate_{config.name}")
    # what the command writes after the run (which locks `out` and plans its own files), checked before it:
    # never over the config or a scene spec, never through a directory or a link to an input
    plan = OutputPlan()
    plan.read(args.config if Path(args.config).suffix else None, sidecars=False)
    for entry in config.scenes:
        spec = config.scene_entry(entry)[0]
        plan.read(spec if Path(spec).suffix else None, sidecars=False)
    plan.directory(out)
    for name in ("figure3.png", "report.json", "report.md", *(f"paper_figure_{b}.png" for b in config.backends)):
        plan.write(out / name, resumed=True)
    plan.check()
    res = run_validation(config, out, progress=not args.quiet,
                         then=lambda out, res: _validation_reports(config, out, res))  # under the run's lock
    emit(res)


def _validation_reports(config, out: Path, res: dict) -> None:
    """figure3.png, report.json/.md and the paper figures, made from a run's rows
    while its directory is still locked (never beside another run's rows)."""
    rows = load_rows(out / "results.csv")
    save_figure(validation_figure(rows), out / "figure3.png")
    res["figures"] = [str(out / "figure3.png")]
    report = paper_report(out / "results.csv")
    report["run"] = stage_summary(out / "stages.csv")
    with atomic_path(out / "report.json") as tmp:
        tmp.write_text(json.dumps(report, indent=1))
    with atomic_path(out / "report.md") as tmp:
        tmp.write_text(paper_report_markdown(report))
    res["report"] = str(out / "report.md")
    paper_scenes = set(Q1_SCENES) | set(Q2_SCENES)
    if any(config.scene_entry(e)[0] in paper_scenes for e in config.scenes):
        for b in config.backends:
            png = out / f"paper_figure_{b}.png"
            save_figure(paper_figure(rows, backend=b, truth="center"), png)
            res["figures"].append(str(png))


def distances(args):
    plan = OutputPlan(force=args.force)
    for path in args.input:
        plan.read(path)
    out = plan.directory(args.output)
    for name in study_files(args.heights):
        plan.write(out / name)
    ground = ground_from(args)
    with plan:
        study = distance_study(args.input, origin=args.origin, heights=args.heights, positions=args.positions,
                               seed=args.seed, resolution=args.resolution, max_range=args.max_range,
                               scanner_height=args.scanner_height, min_ground_points=args.min_ground_points,
                               ground=ground, progress=not args.quiet)
        files = study.write(args.output) + ["distances.png"]
        save_figure(distances_figure(study.original, study.slr, study.sweep), out / "distances.png")
    emit({"output_dir": str(args.output), **study.summary(), "files": files})


def augment(args):
    ground = ground_from(args)
    # the pattern and the backend's options are built once, by config.check() in augment()
    config = AugmentConfig(n=args.n, resolution=args.resolution, sensor=args.sensor,
                           heights=tuple(args.heights) if args.heights else None,
                           scanner_height=args.scanner_height, backend=args.backend,
                           backend_options=backend_from(args), fmt=args.format, seed=args.seed,
                           min_ground_points=args.min_ground_points, workers=args.workers,
                           scheduler=args.scheduler, chunk_size=args.chunk_size, per_pass=args.per_pass,
                           effects=effects_from(args), allow_fewer=args.allow_fewer)
    # the files its settings came from are inputs: no file of the run may be one of them
    reads = [getattr(args, f, None) for f in ("sensor_file", "profile_file", "effects", "ray_drop")]
    res = run_augment(args.input, args.output, config, ground=ground if args.csf or args.ground_attribute else None,
                      progress=not args.quiet, reads=reads, force=args.force)
    emit({k: res[k] for k in ("input", "n_requested", "new_scans", "seconds", "software")}
         | {"scans": len(res["scans"]), "positions": len(res["positions"]),
            "points_out": sum(s["points"] for s in res["scans"]), "output_dir": str(args.output)})


COMMANDS = {f.__name__: f for f in (scan, demo, scene, compare, positions, profile, validate, distances, augment)}
