"""``slr-ray sequence``: sequences in, datasets out (:mod:`slr_ray.sequence`). Kept apart from
:mod:`.commands` so that the subcommand stands alone: its parser and its handlers."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from ..arrays import json_safe
from ..evaluate import compact_json, markdown_table
from ..io import atomic_path
from ..io.outputs import LOCK_NAME, OutputPlan, resolve
from ..errors import InputValueError, OutputError
from ..sensors import SENSORS
from ..sequence import (CONVERT_ESTIMATORS, FPA_GAP, METHODS, REMOVE_MOVING, SeeThrough, convert_sequence,
                        evaluate_sequence, read_sequence, read_trajectory, register_chain, write_kitti_poses)
from ..sequence.holdout import DEFAULT_METHODS, GRID_SOURCES, lidar4d_holdout
from . import arguments as A
from .commands import emit

__all__ = ["add_sequence_parser", "sequence"]

_SEQ_HELP = ("the sequence: a KITTI / SemanticKITTI directory (velodyne/, labels/, poses.txt, calib.txt) or "
             "frame files in order, each in its sensor's frame")
#: the table's columns in table.md (every column is in table.csv and the JSON)
COLUMNS = ("frame", "method", "points", "F@5cm", "F@10cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy",
           "drop_recall", "cd_sum_m2", "R@10cm seen")
LIDAR4D_COLUMNS = ("frame", "method", "points", "cd_sum_m2", "F@22.3607cm", "lidar4d_depth_rmse_m",
                   "lidar4d_depth_medae_m", "drop_accuracy")


def _common(p):
    p.add_argument("sequence", nargs="+", help=_SEQ_HELP)
    p.add_argument("--poses", nargs="+", help="a trajectory (KITTI 12 numbers or TUM 8 numbers a line, one a frame) "
                                              "instead of the sequence's own poses; or one pose file a frame (a 4 x 4 "
                                              "matrix each); or 'origins': the files are in one world frame, each "
                                              "with its scanner's origin (.npz, .pcd, .e57)")
    p.add_argument("--origins", help="the frames are in one world frame (LAS/LAZ of a campaign): a text file of "
                                     "each one's scanner origin, x y z a line")
    p.add_argument("--scan-field", nargs="?", const="point_source_id", metavar="FIELD",
                   help="one file holding several scans in one world frame (a campaign's LAS/LAZ): each value of "
                        "this per-point field a scan (default point_source_id), with --origins in ascending order")
    p.add_argument("--register", action="store_true",
                   help="no poses: register each frame to the one before (ICP) and write the poses found")
    p.add_argument("--half", type=int, default=2, help="window: frames either side of the target (default 2)")
    p.add_argument("--radius", type=A.positive_float, help="window: frames whose origin is within this (m)")
    p.add_argument("--keep-moving", action="store_true",
                   help="keep SemanticKITTI's moving classes (252-259) in the union (default: left out); the "
                        "same as --remove-moving none")
    p.add_argument("--remove-moving", choices=list(REMOVE_MOVING),
                   help="moving objects left out of the union: 'labels' (SemanticKITTI's moving classes, where "
                        "the frames have labels; the default), 'visibility' (points that other frames saw "
                        "through, no labels needed: the frames' own sensor casts their rays), 'both', 'none'")
    p.add_argument("--visibility-margin", type=A.finite_float, default=SeeThrough.margin,
                   help=f"visibility removal: a frame saw through a point where its pulse and the four beside it "
                        f"return from this far beyond it (m, default {SeeThrough.margin})")
    p.add_argument("--visibility-votes", type=A.positive_int, default=SeeThrough.votes,
                   help=f"visibility removal: frames (of the {SeeThrough.half} either side) that must have seen "
                        f"through a point (default {SeeThrough.votes})")
    p.add_argument("--fpa-gap", type=A.positive_float, default=FPA_GAP,
                   help=f"first-peak average: largest step between ranges in the first cluster (m, default {FPA_GAP})")
    A.add_input_format(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--force", action="store_true",
                   help="evaluate: write into a directory that is not empty, replacing the files of an earlier "
                        "run (never an input); convert: refused (it resumes its own run by itself)")


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
    q.add_argument("--sensor", default="velodyne_hdl64e_s2", choices=list(SENSORS),
                   help="the frames' sensor (default velodyne_hdl64e_s2, KITTI's); fitted to each held-out frame")
    q.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS), choices=list(METHODS),
                   help=f"methods (default {' '.join(DEFAULT_METHODS)})")
    q.add_argument("--grid-from", choices=list(GRID_SOURCES), default="target",
                   help="where each held-out frame's scoring grid (row elevations, column count) is fitted: target "
                        "(default) its own points, others the other frames of its window (strictly leak-free)")
    q = ssub.add_parser("convert", help="re-simulate every frame as another sensor (SemanticKITTI layout)",
                        description="each frame re-simulated from the union of its window as another sensor, at "
                                    "its pose (and --offset); resumable, parallel")
    _common(q)
    q.add_argument("-o", "--output", required=True, help="output directory (a rerun with the same settings resumes)")
    q.add_argument("--sensor", required=True, choices=list(SENSORS), help="the target sensor")
    q.add_argument("--estimator", default="nearest", choices=list(CONVERT_ESTIMATORS),
                   help="per-pulse rule (default nearest; rays: the target table's own rays onto the union's "
                        "planes; embree-sources needs --source-sensor)")
    q.add_argument("--source-sensor", choices=list(SENSORS),
                   help="the input frames' own sensor (fitted to each frame whose beams are known: a ring field "
                        "or a KITTI .bin's order), for --remove-moving visibility and --estimator embree-sources")
    q.add_argument("--offset", nargs=3, type=A.finite_float, default=[0.0, 0.0, 0.0], metavar=("DX", "DY", "DZ"),
                   help="the target sensor's offset in each frame's own axes (m)")
    q.add_argument("--target-poses", help="a trajectory of target poses (one a frame) instead of the frames' poses")
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
    st = None
    if how in ("visibility", "both"):
        if source_sensor is None:
            raise InputValueError(f"--remove-moving {how} casts the frames' own rays: name their sensor "
                                  "(--source-sensor)")
        if not args.visibility_margin >= 0:
            raise InputValueError(f"--visibility-margin must be metres >= 0, got {args.visibility_margin}")
        st = SeeThrough(source_sensor, args.visibility_margin, args.visibility_votes)
    return how in ("labels", "both"), st


def _load(args):
    seq = read_sequence(args.sequence if len(args.sequence) > 1 else args.sequence[0], args.poses,
                        args.input_format, args.origins, args.scan_field)
    if args.register and (args.poses or args.origins):
        raise InputValueError("--register with --poses or --origins: give one")
    if seq.poses is None and not args.register:
        raise InputValueError(f"{seq.root or seq.paths[0]}: the sequence has no poses: give --poses FILE "
                              "or --register")
    return seq


def _poses_of(args, seq):
    regs = []
    if args.register:
        seq, regs = register_chain(seq, progress=not args.quiet)
    return seq, regs


def _csv(rows) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(dict.fromkeys(k for r in rows for k in r)), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def _write(path, text) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def sequence(args):
    # refused before anything is read or written
    args.moving = _moving(args, args.sensor if args.sequence_cmd == "evaluate" else args.source_sensor)
    if args.sequence_cmd == "convert" and args.estimator == "embree-sources" and args.source_sensor is None:
        raise InputValueError("--estimator embree-sources sizes discs from each frame's own pulse grid: name "
                              "the frames' sensor (--source-sensor)")
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
            args.half, args.radius = None, None  # the scene is every other frame
        if args.every:
            holdout += list(range(1, len(seq), args.every))
        if not holdout:
            raise InputValueError("name the held-out frames: --holdout I [J ...] or --every N")
        holdout = sorted(set(holdout))
        bad = [h for h in holdout if not 0 <= h < len(seq)]
        if bad:
            raise InputValueError(f"--holdout {bad}: not in a sequence of {len(seq)} frames (0 to {len(seq) - 1})")
        names = ("evaluation.json", "table.md", "table.csv") + (("poses.txt",) if args.register else ())
        _check_evaluate_output(out, args.force)
        for name in names:
            plan.write(out / name, sidecars=False)
        with plan:
            _evaluate(args, seq, holdout, out)
    else:
        if args.force:
            raise InputValueError("sequence convert has no --force: it resumes its own run by itself and never "
                                  "writes over what it did not write; write elsewhere, or remove the directory "
                                  "to start again")
        for name in ("manifest.json", "poses.txt", "calib.txt", "journal.jsonl"):
            plan.write(out / name, sidecars=False, resumed=True)
        with plan:
            _convert(args, seq, out)


def _check_evaluate_output(out: Path, force: bool) -> None:
    """``sequence evaluate`` writes into a new or empty directory; ``--force``: among other
    files (its own of an earlier run replaced, never an input)."""
    if force or not out.is_dir():
        return
    held = sorted(p.name for p in out.iterdir() if p.name != LOCK_NAME and ".part" not in p.name)
    if held:
        raise OutputError(f"{out} is not empty ({', '.join(held[:3])}{', ...' if len(held) > 3 else ''}): "
                          "sequence evaluate writes into a new or empty directory; write elsewhere, or give "
                          "--force to write among these files (replacing evaluation.json, table.md, table.csv)")


def _evaluate(args, seq, holdout, out):
    seq, regs = _poses_of(args, seq)
    drop, st = args.moving
    res = evaluate_sequence(seq, holdout, args.sensor, args.methods, args.half, args.radius,
                            drop_moving=drop, progress=not args.quiet, gap=args.fpa_gap, see_through=st,
                            grid_from=args.grid_from)
    rows = [r for f in res["frames"] for r in f["table"]] + res["mean"]
    files = {"json": out / "evaluation.json", "markdown": out / "table.md", "csv": out / "table.csv"}
    doc = res | {"protocol": args.protocol, "grid_from": args.grid_from, "registration": regs, "pose_source": seq.pose_source,
                 "inputs": [str(p) for p in seq.paths], "table": rows}
    _write(files["json"], compact_json(json_safe(doc)) + "\n")
    cols = LIDAR4D_COLUMNS if args.protocol == "lidar4d" else COLUMNS
    _write(files["markdown"], markdown_table(rows, [c for c in cols if c in rows[0]]) + "\n")
    _write(files["csv"], _csv(rows))
    if args.register:
        files["poses"] = out / "poses.txt"
        with atomic_path(files["poses"]) as tmp:
            write_kitti_poses(tmp, seq.poses)
    emit({"output_dir": str(out), "files": {k: str(v) for k, v in files.items()}, "frames": len(seq),
          "holdout": [seq.names[h] for h in holdout], "pose_source": seq.pose_source,
          "seconds": res["seconds"], "mean": res["mean"]})


def _convert(args, seq, out):
    seq, regs = _poses_of(args, seq)
    target = read_trajectory(args.target_poses, len(seq)) if args.target_poses else None
    drop, st = args.moving
    res = convert_sequence(seq, out, args.sensor, estimator=args.estimator, half=args.half, radius=args.radius,
                           offset=tuple(args.offset), poses=target, drop_moving=drop, fmt=args.format,
                           fpa_gap=args.fpa_gap, workers=args.workers, progress=not args.quiet, see_through=st,
                           source_sensor=args.source_sensor, scheduler=args.scheduler,
                           inputs={"sequence": [str(p) for p in seq.paths], "poses": args.poses,
                                   "register": bool(args.register)})
    emit(res | {"pose_source": seq.pose_source, "registration": regs})
