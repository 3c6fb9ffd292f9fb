"""``slr-ray sequence``: sequences in, datasets out (:mod:`slr_ray.sequence`). Kept apart from
:mod:`.commands` so that the subcommand stands alone: its parser and its handlers."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from ..evaluate import sequence_summary, write_sequence_evaluation
from ..io import atomic_path
from ..io.outputs import LOCK_NAME, OutputPlan, resolve
from ..sensors import sensor
from ..errors import InputValueError, OutputError, SlrError, SlrWarning
from ..sequence import (REMOVE_MOVING, SeeThrough, convert_sequence, evaluate_sequence, read_sequence,
                        register_chain, write_kitti_poses)
from ..sequence.holdout import (GRID_SOURCES, check_held_out_kinds, lidar4d_holdout,
                               one_frame_refusal)
from ..sequence.convert import check_source_frame
from ..sequence.terrestrial import AUTO
from ..sequence.methods import REGISTRY, method_options, methods_with, option_keys
from . import arguments as A
from .commands import emit
from ..sequence.layouts import LAYOUTS

__all__ = ["add_sequence_parser", "sequence"]

_SEQ_HELP = ("the sequence: a KITTI / SemanticKITTI directory (velodyne/, labels/, poses.txt, calib.txt) or "
             "frame files in order, each in its sensor's frame")
#: the window's half width unless told
HALF = 2
#: the frames' sensor of ``sequence evaluate`` unless told (KITTI's)
SOURCE_SENSOR = "velodyne_hdl64e_s2"


def _common(p):
    p.add_argument("sequence", nargs="+", help=_SEQ_HELP)
    p.add_argument("--poses", nargs="+", help="a trajectory (KITTI 12 numbers or TUM 8 numbers a line, one a frame) "
                                              "instead of the sequence's own poses (for a KITTI directory with "
                                              "calib.txt, KITTI form is the camera's, as its poses.txt); or one pose "
                                              "file a frame (a 4 x 4 matrix each); or 'origins': the files are in one world frame, each "
                                              "with its scanner's origin (.npz, .pcd, .e57)")
    p.add_argument("--origins", help="the frames are in one world frame (LAS/LAZ of a campaign): a text file of "
                                     "each one's scanner origin, x y z a line")
    p.add_argument("--scan-field", nargs="?", const="point_source_id", metavar="FIELD",
                   help="one file holding several scans in one world frame (a campaign's LAS/LAZ): each value of "
                        "this per-point field a scan (default point_source_id), with --origins in ascending order")
    p.add_argument("--layout", choices=list(LAYOUTS),
                   help="the sequence's layout where its path could be two (default: the one it is in; directories: "
                        "KITTI / SemanticKITTI, PCD frames and a CSV of poses, Ouster .npz frames with their "
                        "metadata .json and *poses*.txt)")
    p.add_argument("--register", action="store_true",
                   help="no poses: register each frame to the one before (ICP) and write the poses found")
    p.add_argument("--accept-registration", action="store_true",
                   help="with --register: chain every pose found, even one failing the registration gate (fitness, "
                        "reverse fitness, inlier RMSE, tilt; docs/evaluation.md)")
    p.add_argument("--half", type=A.non_negative_int,
                   help=f"window: frames either side of the target (default {HALF}; with --radius, both hold)")
    p.add_argument("--radius", type=A.positive_float,
                   help="window: frames whose origin is within this (m), however many (alone: not only the default "
                        "--half's)")
    p.add_argument("--keep-moving", action="store_true",
                   help="keep SemanticKITTI's moving classes (252-259) in the union (default: left out); the "
                        "same as --remove-moving none")
    p.add_argument("--remove-moving", choices=list(REMOVE_MOVING),
                   help="moving objects left out of the union: 'labels' (SemanticKITTI's moving classes, where "
                        "the frames have labels; the default), 'visibility' (points that other frames saw "
                        "through, no labels needed: the frames' own sensor casts their rays), 'both', 'none'")
    p.add_argument("--visibility-margin", type=A.finite_float,
                   help=f"visibility removal: a frame saw through a point where its pulse and the four beside it "
                        f"return from this far beyond it (m, default {SeeThrough.margin})")
    p.add_argument("--visibility-votes", type=A.positive_int,
                   help=f"visibility removal: frames (of the {SeeThrough.half} either side) that must have seen "
                        f"through a point (default {SeeThrough.votes}, at most {2 * SeeThrough.half})")
    add_method_options(p)
    A.add_input_format(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--force", action="store_true",
                   help="evaluate: write into a directory that is not empty, replacing the files of an earlier "
                        "run (never an input); convert: refused (it resumes its own run by itself)")


_TYPES = {"float": A.finite_float, "int": int, "str": str}


def add_method_options(p) -> None:
    """Every registered method's options as flags (``--PREFIX-FIELD``), generated from their options
    classes (:func:`slr_ray.sequence.methods.option_keys`): a setting two methods share is one flag."""
    for key, (cls, name, methods) in option_keys().items():
        typ, text = cls.describe().get(name, ("str", ""))
        default = getattr(cls(), name)
        p.add_argument("--" + key.replace("_", "-"), dest=f"mopt_{key}", type=_TYPES.get(typ.split()[0], str),
                       metavar=name.split("_")[-1].upper(),
                       help=f"{', '.join(methods)}: {text[:1].lower()}{text[1:].rstrip('.')} (default {default})"
                       .replace("%", "%%"))


def method_options_from(args) -> dict:
    """The method options given on the command line, by flat key."""
    return {k[5:]: v for k, v in vars(args).items() if k.startswith("mopt_") and v is not None}


def _deprecated_sensor(p) -> None:
    p.add_argument("--sensor", dest="old_sensor", type=A.sensor_name, metavar="NAME", help=argparse.SUPPRESS)


def add_sequence_parser(sub) -> None:
    """``sequence evaluate`` and ``sequence convert`` under the ``sequence`` command."""
    help_text = "sequences of frames: leave-one-out evaluation, conversion to another sensor"
    p = sub.add_parser("sequence", help=help_text, description=help_text)
    p.set_defaults(func=sequence)
    ssub = p.add_subparsers(dest="sequence_cmd", required=True)
    q = ssub.add_parser("evaluate", help="re-simulate held-out frames from the others and score them",
                        description="each held-out frame re-simulated from the other frames of its window at its "
                                    "pose, by every method, scored as slr-ray evaluate scores a pair")
    _common(q)
    q.add_argument("-o", "--output", required=True, help="output directory (evaluation.json, table.md, table.csv)")
    q.add_argument("--holdout", nargs="+", type=int, help="held-out frames (positions in the sequence, from 0)")
    q.add_argument("--every", type=A.positive_int, help="hold out every N-th frame (from frame 1)")
    q.add_argument("--protocol", choices=["slr", "lidar4d"], default="slr",
                   help="lidar4d: LiDAR4D's KITTI-360 split (51 frames, frames 10, 20, 30, 40 held out, every other "
                        "frame the scene); its clamped depth errors are in every table either way")
    q.add_argument("--source-sensor", type=A.sensor_name, metavar="NAME",
                   help=f"the frames' sensor, a spinning unit's (fitted to each held-out frame; --sensor, its old "
                        f"name, still works); not given: a frame with a ring field or in {SOURCE_SENSOR}'s scan "
                        "order (KITTI's) is scored on that table, a ring-less one in another shipped sensor's scan "
                        "order or elevation bands on that sensor's, any other (a terrestrial scanner's) on a "
                        "uniform grid fitted to it; the output says which")
    _deprecated_sensor(q)
    q.add_argument("--target-sensor", type=A.sensor_name, metavar="NAME|CARD",
                   help="the held-out frames' own unit where it is not the source's (" + A.SENSOR_HELP + "): each "
                        "is scored on its grid, re-simulated from the source frames; the target's beams outside "
                        "what the source frames saw are scored apart ('in reach' / 'out of reach' columns)")
    defaults = methods_with("default")
    q.add_argument("--methods", nargs="+", default=defaults, choices=methods_with("holdout"),
                   help=f"methods (default {' '.join(defaults)}; on a terrestrial scanner's frames rays casts "
                        "the fitted grid's pulse centres, no beams being there, and embree-sources is refused)")
    q.add_argument("--grid-from", choices=list(GRID_SOURCES), default="target",
                   help="where each held-out frame's scoring grid (row elevations, column count) is fitted: target "
                        "(default) its own points, others the other frames of its window (strictly leak-free)")
    q = ssub.add_parser("convert", help="re-simulate every frame as another sensor (SemanticKITTI layout)",
                        description="each frame re-simulated from the union of its window as another sensor, at "
                                    "its pose (and --offset); resumable, parallel")
    _common(q)
    q.add_argument("-o", "--output", required=True, help="output directory (a rerun with the same settings resumes)")
    q.add_argument("--target-sensor", type=A.sensor_name, metavar="NAME",
                   help="the target sensor (required; --sensor, its old name, still works)")
    _deprecated_sensor(q)
    q.add_argument("--estimator", default="nearest", choices=methods_with("convert"),
                   help="per-pulse rule (default nearest; rays: the target table's own rays onto the union's "
                        f"planes; {', '.join(methods_with('needs_source_sensor'))} need(s) --source-sensor)")
    q.add_argument("--source-sensor", type=A.sensor_name, metavar="NAME",
                   help="the input frames' own sensor (fitted to each frame whose beams are known: a ring field "
                        "or a KITTI .bin's order), for --remove-moving visibility and --estimator embree-sources")
    q.add_argument("--offset", nargs=3, type=A.finite_float, default=[0.0, 0.0, 0.0], metavar=("DX", "DY", "DZ"),
                   help="the target sensor's offset in each frame's own axes (m); with --target-poses, in each "
                        "target pose's own axes (both applied)")
    q.add_argument("--target-poses", help="a trajectory of target poses (one a frame) instead of the frames' poses "
                                           "(for a KITTI directory, KITTI form is the camera's, as its poses.txt); "
                                           "--offset moves each in its own axes; poses.txt holds the poses cast from")
    q.add_argument("--format", default="bin", help="frame format (default bin: KITTI; others carry a ring field)")
    q.add_argument("--workers", type=A.positive_int, default=1, help="worker processes (default 1)")
    q.add_argument("--scheduler", metavar="ADDRESS",
                   help="a dask.distributed scheduler whose workers convert the frames (they write into -o: a "
                        "file system they share) instead of --workers")


def _plan_inputs(plan: OutputPlan, args, seq) -> None:
    for path in seq.inputs():
        plan.read(path, fmt=args.input_format)
    plan.read(args.origins, sidecars=False)
    for path in args.poses or []:
        if path != "origins":
            plan.read(path, sidecars=False)
    plan.read(getattr(args, "target_poses", None), sidecars=False)


def _check_apart(out: Path, seq) -> None:
    """Refuse an output directory that is an input's directory, holds an input, or lies in the sequence."""
    o = resolve(out)
    places = {resolve(p).parent for p in seq.paths}
    if seq.root is not None:
        places.add(resolve(seq.root))
    for d in places:
        if o == d or d in o.parents or o in d.parents:
            raise OutputError(f"{out} is, holds or lies in the input directory {d}: write the output elsewhere")


def _moving(args, source_sensor) -> tuple[bool, SeeThrough | None]:
    """``--remove-moving`` (and ``--keep-moving``) as the labels rule and the see-through rule."""
    how = args.remove_moving
    if args.keep_moving and how in ("labels", "both"):
        raise InputValueError(f"--keep-moving with --remove-moving {how}: give one")
    how = how or ("none" if args.keep_moving else "labels")
    visibility = how in ("visibility", "both")
    given = [f for f, v in (("--visibility-margin", args.visibility_margin),
                            ("--visibility-votes", args.visibility_votes)) if v is not None]
    if given and not visibility:
        raise InputValueError(f"{' and '.join(given)} without visibility removal: add --remove-moving visibility "
                              "(or both)")
    st = None
    if visibility:
        if source_sensor is None:
            raise InputValueError(f"--remove-moving {how} casts the frames' own rays: name their sensor "
                                  "(--source-sensor)")
        margin = SeeThrough.margin if args.visibility_margin is None else args.visibility_margin
        votes = SeeThrough.votes if args.visibility_votes is None else args.visibility_votes
        if not margin >= 0:
            raise InputValueError(f"--visibility-margin must be metres >= 0, got {margin}")
        if votes > 2 * SeeThrough.half:
            raise InputValueError(f"--visibility-votes {votes}: at most {2 * SeeThrough.half} frames vote (the "
                                  f"{SeeThrough.half} either side of a point's frame), so no point would be removed")
        st = SeeThrough(source_sensor, margin, votes)
    return how in ("labels", "both"), st


def _sensors(args) -> None:
    """``--source-sensor`` / ``--target-sensor`` resolved; ``--sensor``, their old name, said so on one line."""
    old = args.old_sensor
    new = "--source-sensor" if args.sequence_cmd == "evaluate" else "--target-sensor"
    dest = new[2:].replace("-", "_")
    if old is not None:
        if getattr(args, dest) is not None:
            raise InputValueError(f"--sensor and {new}: give {new} (--sensor is its old name)")
        warnings.warn(f"sequence {args.sequence_cmd} --sensor is {new} now (the old name still works)", SlrWarning,
                      stacklevel=2)
        setattr(args, dest, old)
    for flag in ("--source-sensor", "--target-sensor"):
        name = getattr(args, flag[2:].replace("-", "_"), None)
        try:
            if name is not None:
                sensor(name)  # a card that is no card, or no file: one line now, before any frame is read
        except SlrError as exc:
            raise type(exc)(f"{flag}: {exc}") from None
    if args.sequence_cmd == "evaluate" and args.target_sensor is not None and args.source_sensor is None:
        raise InputValueError(f"--target-sensor {args.target_sensor} without --source-sensor: a target unit is "
                              "re-simulated from the source frames' own table: name it (--source-sensor)")
    if args.sequence_cmd == "evaluate" and args.target_sensor is not None and args.grid_from == "others":
        raise InputValueError("--grid-from others with --target-sensor: the other frames are the source's, not the "
                              "target unit's (use --grid-from target)")
    if args.sequence_cmd == "evaluate":
        args.scored_sensor = args.source_sensor or AUTO  # none named: spinning or terrestrial, frame by frame
        args.source_sensor = args.source_sensor or SOURCE_SENSOR
    elif args.target_sensor is None:
        raise InputValueError("sequence convert: name the target sensor (--target-sensor NAME)")


def _load(args):
    seq = read_sequence(args.sequence if len(args.sequence) > 1 else args.sequence[0], args.poses,
                        args.input_format, args.origins, args.scan_field, args.layout)
    if args.register and (args.poses or args.origins):
        raise InputValueError("--register with --poses or --origins: give one")
    if args.accept_registration and not args.register:
        raise InputValueError("--accept-registration without --register: it accepts the poses registration finds")
    if args.sequence_cmd == "evaluate" and len(seq) < 2:
        raise InputValueError(one_frame_refusal(seq))
    if seq.poses is None and not args.register:
        raise InputValueError(f"{seq.root or seq.paths[0]}: the sequence has no poses: give --poses FILE "
                              "or --register")
    return seq


def _poses_of(args, seq):
    regs = []
    if args.register:
        seq, regs = register_chain(seq, progress=not args.quiet, accept_registration=args.accept_registration)
    return seq, regs


def sequence(args):
    # refused before anything is read or written
    _sensors(args)
    args.moving = _moving(args, args.source_sensor)
    if args.sequence_cmd == "convert":
        m = REGISTRY[args.estimator]
        if m.needs_source_sensor and args.source_sensor is None:
            raise InputValueError(f"--estimator {args.estimator} needs the frames' sensor (--source-sensor): "
                                  f"{m.source_why}")
    else:
        twice = sorted({m for m in args.methods if args.methods.count(m) > 1})
        if twice:
            raise InputValueError(f"--methods: {', '.join(twice)} given twice (each method is one row)")
        if args.protocol == "lidar4d" and (args.half is not None or args.radius is not None):
            raise InputValueError("--half / --radius with --protocol lidar4d: its scene is every other frame of the "
                                  "51 (no window)")
    args.method_options = method_options_from(args)
    method_options(args.method_options)  # every method's options checked, before anything is read
    _unused_method_flags(args)
    lidar4d = args.sequence_cmd == "evaluate" and args.protocol == "lidar4d"
    if args.half is None and args.radius is None and not lidar4d:
        args.half = HALF  # not with --radius: its window is every frame within it, not those of the +-2 within it
    seq = _load(args)
    plan = OutputPlan(force=args.force)
    _plan_inputs(plan, args, seq)
    _check_apart(Path(args.output), seq)
    out = plan.directory(args.output)
    if args.sequence_cmd == "evaluate":
        holdout = list(args.holdout or [])
        if args.protocol == "lidar4d":
            if holdout or args.every:
                raise InputValueError("--protocol lidar4d holds out its own frames: no --holdout or --every")
            holdout = lidar4d_holdout(len(seq))
        if args.every:
            holdout += list(range(1, len(seq), args.every))
        if not holdout:
            raise InputValueError("name the held-out frames: --holdout I [J ...] or --every N")
        holdout = sorted(set(holdout))
        bad = [h for h in holdout if not 0 <= h < len(seq)]
        if bad:
            raise InputValueError(f"--holdout {bad}: not in a sequence of {len(seq)} frames (0 to {len(seq) - 1})")
        stale = None if args.register else _registered_poses(out, args.poses)
        names = ("evaluation.json", "table.md", "table.csv") + (("poses.txt",) if args.register or stale else ())
        _check_evaluate_output(out, args.force)
        pair = _pair_results(out)  # a replaced `slr-ray evaluate` run's splits and figure: they go with it
        names += tuple(p.name for p in pair)
        check_held_out_kinds(seq, holdout, args.scored_sensor, args.methods, args.moving[1])  # before registering
        for name in names:
            plan.write(out / name, sidecars=False)
        with plan:
            _evaluate(args, seq, holdout, out)
            if stale is not None:  # an earlier --register run's: it would stay beside results it is not of
                stale.unlink(missing_ok=True)
            for p in pair:
                p.unlink(missing_ok=True)
            if pair:
                print(f"slr-ray: note: {out}: removed {', '.join(p.name for p in pair)} of the pair evaluation "
                      "(slr-ray evaluate) whose results this run replaced", file=sys.stderr)
    else:
        if args.force:
            raise InputValueError("sequence convert has no --force: it resumes its own run by itself and never "
                                  "writes over what it did not write; write elsewhere, or remove the directory "
                                  "to start again")
        if args.register:  # before registering (convert_sequence checks it where the poses are given)
            check_source_frame(seq, args.estimator, args.source_sensor, args.method_options)
        for name in ("manifest.json", "poses.txt", "calib.txt", "journal.jsonl"):
            plan.write(out / name, sidecars=False, resumed=True)
        with plan:
            _convert(args, seq, out)


def _unused_method_flags(args) -> None:
    """A method's flag given while no method it sets is run is refused (as a backend's option is with
    another backend), not ignored: ``--tsdf-voxel 0.1 --methods zbuffer`` would score without it."""
    run = [args.estimator] if args.sequence_cmd == "convert" else args.methods
    keys = option_keys()
    for key in args.method_options:
        if not set(keys[key][2]) & set(run):
            flag = "--estimator" if args.sequence_cmd == "convert" else "--methods"
            raise InputValueError(f"--{key.replace('_', '-')} does not apply to {flag} {' '.join(run)} "
                                  f"(it sets {', '.join(keys[key][2])})")


def _check_evaluate_output(out: Path, force: bool) -> None:
    """``sequence evaluate`` writes into a new or empty directory; ``--force``: among other
    files (its own of an earlier run replaced, never an input)."""
    if force or not out.is_dir():
        return
    held = sorted(p.name for p in out.iterdir() if p.name != LOCK_NAME and ".part" not in p.name)
    if held:
        raise OutputError(f"{out} is not empty ({', '.join(held[:3])}{', ...' if len(held) > 3 else ''}): "
                          "sequence evaluate writes into a new or empty directory; write elsewhere, or give "
                          "--force to write among these files (replacing evaluation.json, table.md, table.csv, "
                          "and an earlier --register run's poses.txt)")


def _pair_results(out: Path) -> list:
    """``splits.csv`` and ``evaluation.png`` where ``out/evaluation.json`` is a pair evaluation's
    (``slr-ray evaluate``): a ``--force`` rerun replaces that run's results, and these would stay beside
    this run's as if they were of it (a sequence evaluation writes neither)."""
    try:
        inputs = json.loads((out / "evaluation.json").read_text()).get("inputs")
    except (OSError, ValueError, AttributeError):
        return []
    if not (isinstance(inputs, dict) and "a" in inputs):
        return []
    return [p for p in (out / "splits.csv", out / "evaluation.png") if p.is_file()]


def _registered_poses(out: Path, given) -> Path | None:
    """``out/poses.txt`` where an earlier ``sequence evaluate --register`` wrote it beside its
    ``evaluation.json`` (a ``--force`` rerun replaces that run's results: its poses go with them;
    not where this run reads it, ``--poses OUT/poses.txt``: they are then this run's poses too)."""
    poses, doc = out / "poses.txt", out / "evaluation.json"
    if any(p != "origins" and resolve(Path(p)) == resolve(poses) for p in given or []):
        return None
    try:
        return poses if poses.is_file() and json.loads(doc.read_text()).get("pose_source") == "register" else None
    except (OSError, ValueError, AttributeError):
        return None


def _evaluate(args, seq, holdout, out):
    seq, regs = _poses_of(args, seq)
    drop, st = args.moving
    res = evaluate_sequence(seq, holdout, args.scored_sensor, args.methods, args.half, args.radius,
                            drop_moving=drop, progress=not args.quiet, see_through=st, grid_from=args.grid_from,
                            method_options=args.method_options, target_sensor=args.target_sensor)
    res |= {"protocol": args.protocol, "grid_from": args.grid_from, "registration": regs,
            "pose_source": seq.pose_source, "inputs": [str(p) for p in seq.paths]}
    files = write_sequence_evaluation(res, out, force=True)  # out: planned and locked above
    if args.register:
        files["poses"] = str(out / "poses.txt")
        with atomic_path(files["poses"]) as tmp:
            write_kitti_poses(tmp, seq.poses)
    table, mean = sequence_summary(res)
    grids = _grids(res)
    if not args.quiet:
        sys.stderr.write("".join(f"scoring grid: {g}\n" for g in grids)
                         + f"mean over {len(holdout)} held-out frame(s):\n{table}\n")
    emit({"output_dir": str(out), "files": files, "frames": len(seq), "holdout": [seq.names[h] for h in holdout],
          "pose_source": seq.pose_source, "seconds": res["seconds"],
          "sensor_kind": sorted({f["sensor_kind"] for f in res["frames"]}), "scoring_grid": grids,
          "in_view_share": [round(f["in_view_share"], 4) for f in res["frames"]], "mean": mean})


def _grids(res) -> list[str]:
    """Each held-out frame's scoring grid in one line (frames on the same kind of grid named together)."""
    by: dict = {}
    for f in res["frames"]:
        by.setdefault(f["grid"].split(":")[0], []).append(f)
    return [f"frame(s) {', '.join(f['frame'] for f in fs)}: {fs[0]['grid']}"
            + (" (the first frame's)" if len(fs) > 1 else "")
            + f"; {', '.join(format(f['in_view_share'], '.1%') for f in fs)} of the held-out scan in its view"
            for fs in by.values()]


def _convert(args, seq, out):
    seq, regs = _poses_of(args, seq)
    target = seq.trajectory(args.target_poses)[0] if args.target_poses else None  # a KITTI directory's Tr
    drop, st = args.moving
    res = convert_sequence(seq, out, args.target_sensor, estimator=args.estimator, half=args.half,
                           radius=args.radius, offset=tuple(args.offset), poses=target, drop_moving=drop,
                           fmt=args.format, method_options=args.method_options, workers=args.workers,
                           progress=not args.quiet, see_through=st,
                           source_sensor=args.source_sensor, scheduler=args.scheduler,
                           inputs={"sequence": [str(p) for p in seq.paths], "poses": args.poses,
                                   "register": bool(args.register)})
    emit(res | {"pose_source": seq.pose_source, "registration": regs})
