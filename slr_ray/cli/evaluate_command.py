"""``slr-ray evaluate``: a real pair of frames, B re-simulated from A at B's pose
(:mod:`slr_ray.evaluate`). Kept apart from :mod:`.commands` so that the
subcommand stands alone: flags in, library call, files and one JSON line out."""

from __future__ import annotations

import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from ..arrays import as_rigid_pose
from ..errors import InputValueError, OutputError, SlrError, SlrWarning
from ..evaluate import EVALUATION_FILES, evaluate_pair, evaluation_table, reach_table, rig_extrinsic, write_evaluation
from ..io import read_cloud
from ..io.outputs import LOCK_NAME, OutputPlan
from ..plotting import evaluation_figure, save_figure
from ..registration import REGISTRATION_BOUNDS
from ..sensors import sensor
from .commands import emit

__all__ = ["evaluate", "read_matrix", "read_extrinsic"]

#: frame A's sensor when none is named (KITTI's)
DEFAULT_SENSOR = "velodyne_hdl64e_s2"


def read_matrix(path, flag: str = "--transform") -> np.ndarray:
    """A text matrix: rows of numbers (spaces or commas; ``#`` starts a comment), as float64; one
    line of 12 or 16 numbers is a 3 x 4 (a KITTI poses line) or 4 x 4 matrix, row by row.

    Parsed here, not by numpy, so that an empty or ragged file is one line naming ``flag``
    (numpy's loadtxt warns with its own source line on an empty file)."""
    try:
        text = Path(path).read_text()
    except UnicodeDecodeError:
        raise InputValueError(f"{flag} {path}: not a text matrix (a binary file)") from None
    rows = []
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split("#")[0].replace(",", " ").split()
        if words:
            try:
                rows.append([float(w) for w in words])
            except ValueError:
                raise InputValueError(f"{flag} {path}: line {number} is not numbers: {line.strip()[:60]!r}") from None
    if not rows:
        raise InputValueError(f"{flag} {path}: the file holds no numbers (a 4 x 4 matrix, one row a line)")
    if len({len(r) for r in rows}) != 1:
        raise InputValueError(f"{flag} {path}: rows of {sorted({len(r) for r in rows})} numbers: not a matrix")
    if len(rows) == 1 and len(rows[0]) in (12, 16):  # one line of a KITTI poses file (3 x 4), or 4 x 4 flat
        return np.array(rows[0], np.float64).reshape(-1, 4)
    return np.array(rows, np.float64)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _lists(node):
    """Every list in a parsed JSON document, depth first."""
    if isinstance(node, list):
        yield node
    for v in node.values() if isinstance(node, dict) else node if isinstance(node, list) else ():
        yield from _lists(v)


def _matrices(doc) -> list:
    """Every 4 x 4 (or 3 x 4) list of numbers in a parsed JSON document, depth first."""
    return [n for n in _lists(doc) if len(n) in (3, 4) and all(isinstance(r, list) and len(r) == 4
                                                                and all(map(_number, r)) for r in n)]


def _has_flat16(doc) -> bool:
    """Whether a parsed JSON document holds a flat list of 16 numbers (a ROS-style matrix)."""
    return any(len(n) == 16 and all(map(_number, n)) for n in _lists(doc))


def read_extrinsic(path, flag: str = "--extrinsic") -> np.ndarray:
    """A rig's extrinsic: a text matrix (:func:`read_matrix`), or a JSON document holding exactly one 4 x 4
    (or 3 x 4) list of numbers, wherever it is (SensorsCalibration's ``param.sensor_calib.data``)."""
    try:
        text = Path(path).read_text()
    except UnicodeDecodeError:
        raise InputValueError(f"{flag} {path}: not a matrix (a binary file)") from None
    if not text.lstrip().startswith(("{", "[")):
        return read_matrix(path, flag)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputValueError(f"{flag} {path}: not JSON ({exc})") from None
    found = _matrices(doc)
    if len(found) != 1:
        flat = " (a flat list of 16 numbers is not read: its order, by rows or by columns, is not known; give the "\
            "matrix as 4 lists of 4, rows first)" if not found and _has_flat16(doc) else ""
        raise InputValueError(f"{flag} {path}: holds {len(found)} 4 x 4 matrices of numbers, not one{flat}")
    return np.array(found[0], np.float64)


def _sensor_flags(args) -> None:
    """``--source-sensor`` resolved; ``--sensor``, its old name, said so on one line."""
    if args.old_sensor is not None:
        if args.source_sensor is not None:
            raise InputValueError("--sensor and --source-sensor: give --source-sensor (--sensor is its old name)")
        warnings.warn("evaluate --sensor is --source-sensor now (the old name still works)", SlrWarning, stacklevel=2)
        args.source_sensor = args.old_sensor
    args.source_sensor = args.source_sensor or DEFAULT_SENSOR
    for flag, name in (("--source-sensor", args.source_sensor), ("--target-sensor", args.target_sensor)):
        try:
            if name is not None:
                sensor(name)  # a card that is no card, or no file: one line now, before any frame is read
        except SlrError as exc:
            raise type(exc)(f"{flag}: {exc}") from None
    if args.transform and args.extrinsic:
        raise InputValueError("--transform and --extrinsic: give one (--extrinsic is --transform's inverse)")
    if args.target_sensor not in (None, args.source_sensor) and not (args.transform or args.extrinsic):
        raise InputValueError(f"--target-sensor {args.target_sensor}: another unit sits elsewhere on the rig: give "
                              "B's pose (--transform, B's pose in A's frame, or --extrinsic, A's to B's)")


def _foreign_files(out: Path) -> list:
    """What an existing output directory holds besides the evaluation's own files and the lock."""
    if not out.is_dir():
        return []
    ours = set(EVALUATION_FILES.values()) | {LOCK_NAME}
    return sorted(p.name for p in out.iterdir() if p.name not in ours)


def evaluate(args):
    given = args.min_fitness is not None  # the default is None: a bound given with B's pose is refused
    args.min_fitness = REGISTRATION_BOUNDS["min_fitness"] if args.min_fitness is None else args.min_fitness
    if not 0 <= args.min_fitness <= 1:  # nan too
        raise InputValueError(f"--min-fitness {args.min_fitness}: a share of B's points, in [0, 1]")
    if given and (args.transform or args.extrinsic):
        raise InputValueError(f"--min-fitness with {'--transform' if args.transform else '--extrinsic'}: "
                              "nothing is registered (B's pose is given)")
    if args.accept_registration and (args.transform or args.extrinsic):
        raise InputValueError(f"--accept-registration with {'--transform' if args.transform else '--extrinsic'}: "
                              "nothing is registered (B's pose is given)")
    if len(set(args.methods)) != len(args.methods):
        twice = sorted({m for m in args.methods if args.methods.count(m) > 1})
        raise InputValueError(f"--methods: {', '.join(twice)} given twice (each method is one row)")
    plan = OutputPlan(force=args.force)
    for path in (args.a, args.b):
        plan.read(path, fmt=args.input_format)  # --input-format bin reads a .label beside any name
    _sensor_flags(args)
    plan.read(args.transform, sidecars=False)  # a text matrix: nothing is read beside it
    plan.read(args.extrinsic, sidecars=False)
    poses = _given_poses(args)  # NaN, a scale or shear: one line before any frame is read
    out = plan.directory(args.output)
    for name in EVALUATION_FILES.values():
        plan.write(out / name)
    held = [p for p in (out.iterdir() if out.is_dir() else ()) if p.name != LOCK_NAME
            and not (p.name.startswith(".") and p.name.endswith(".part"))]  # a killed run's: the plan removes them
    if held and not args.force:
        names = sorted(p.name for p in held)
        raise OutputError(f"-o {args.output} exists and is not empty ({len(held)} entries: {', '.join(names[:3])}"
                          f"{', ...' if len(names) > 3 else ''}); --force replaces its evaluation files")
    with plan:
        _evaluate(args, out, *poses)


def _given_poses(args) -> tuple:
    """``(transform, extrinsic)`` read from their files and checked (a rigid pose; a rig's extrinsic taken as
    its nearest rotation, said once), or None each."""
    transform = extrinsic = None
    if args.transform:
        transform = as_rigid_pose(read_matrix(args.transform), f"--transform {args.transform}")
    if args.extrinsic:
        extrinsic = rig_extrinsic(read_extrinsic(args.extrinsic), f"--extrinsic {args.extrinsic}")
    return transform, extrinsic


def _beams(cloud, mode: str, what: str):
    """The ``a_beams``/``b_beams`` of ``--beams``: the 'ring' attribute as stored (its values are checked, not
    truncated), the scan order (strict for ``scan-order``), or none."""
    ring = cloud.attributes.get("ring")
    if mode == "auto" and ring is not None:
        r = np.asarray(ring)
        if r.dtype.kind not in "iu" and (r.dtype.kind != "f" or not np.all(np.isfinite(r))
                                         or np.any(r != np.round(r))):
            raise InputValueError(f"--beams auto: {what}'s 'ring' attribute holds non-integers (dtype {r.dtype}): "
                                  "not beam ids; give --beams scan-order or --beams none")
        return r
    return {"auto": "auto", "scan-order": "scan-order", "none": None}[mode]


def _warn_self_check(a, b, clouds) -> None:
    """One line when B is A (the same file, or the same points under another name): a frame scored
    against itself scores perfectly whatever the simulation does. Warned of, not refused: a deliberate
    self-check is one."""
    if os.path.samefile(a, b):
        same = f"the same file ({a})" if os.path.abspath(a) == os.path.abspath(b) else f"the same file ({a}, {b})"
    elif clouds[0].points.shape == clouds[1].points.shape and np.array_equal(clouds[0].points, clouds[1].points):
        same = f"the same points ({a}, {b})"
    else:
        return
    warnings.warn(f"evaluate: frames A and B are {same}: the scores compare a frame with itself and say "
                  "nothing of the simulation (fine as a self-check)", SlrWarning, stacklevel=3)


def _evaluate(args, out, transform, extrinsic):
    clouds = [read_cloud(p, args.input_format, allow_empty=False) for p in (args.a, args.b)]
    frames = []  # each in its sensor's frame: a file that records its scanner's position (.npz, .pcd, .e57)
    for c in clouds:  # holds world coordinates, moved to that position in float64, and turned into the
        # scanner's own axes where the file records them (an E57 pose's rotation: its beams' elevations are
        # about the scanner's axis, not the world's z)
        own = c.points - np.asarray(c.origin, np.float64) if c.origin is not None else c.points
        rot = c.meta.get("e57_rotation")
        frames.append(own @ np.asarray(rot, np.float64) if rot is not None and c.origin is not None else own)
    beams = [_beams(c, args.beams, f"frame {k} ({p})") for c, k, p in zip(clouds, "AB", (args.a, args.b))]
    try:
        res = evaluate_pair(frames[0], frames[1], a_beams=beams[0], b_beams=beams[1],
                            source_sensor=args.source_sensor, target_sensor=args.target_sensor,
                            methods=args.methods, transform=transform, extrinsic=extrinsic,
                            seen_threshold=args.seen_threshold, min_fitness=args.min_fitness,
                            accept_registration=args.accept_registration, progress=not args.quiet)
    except InputValueError as exc:  # the library names a_beams / b_beams: say the flag and the file
        msg = str(exc)
        for key, name, path in (("a_beams", "A", args.a), ("b_beams", "B", args.b)):
            if msg.startswith(key):
                msg = f"--beams {args.beams}: frame {name} ({path}){msg[len(key):]}"
        if msg.startswith("extrinsic"):
            msg = f"--extrinsic {args.extrinsic}{msg[len('extrinsic'):]}"
        raise InputValueError(msg) from None
    _warn_self_check(args.a, args.b, clouds)  # once scored: a refusal stays its one line
    for key, name, path in (("a", "A", args.a), ("b", "B", args.b)):
        how = res["patterns"][key]["beams"]
        if how.startswith("none:"):
            print(f"slr-ray: note: --beams auto: frame {name} ({path}) has no 'ring' attribute and is {how[6:]}; "
                  "its beams are unknown: scored by the shipped table's elevation bands", file=sys.stderr)
    foreign = _foreign_files(out)
    if foreign:
        print(f"slr-ray: note: {out} also holds {len(foreign)} file(s) not written by this run: "
              f"{', '.join(foreign[:5])}{' ...' if len(foreign) > 5 else ''}", file=sys.stderr)
    paths = write_evaluation(res, out, force=True,  # the plan checked --force file by file
                             inputs={"a": str(args.a), "b": str(args.b), "sensor": args.source_sensor,
                                     "target_sensor": args.target_sensor or args.source_sensor,
                                     "transform": args.transform, "extrinsic": args.extrinsic, "beams": args.beams,
                                     "origins": [None if c.origin is None else np.asarray(c.origin).tolist()
                                                 for c in clouds],
                                     "rotations": [c.meta.get("e57_rotation") if c.origin is not None else None
                                                   for c in clouds], "other_files_in_directory": foreign})
    paths["figure"] = str(out / EVALUATION_FILES["figure"])
    save_figure(evaluation_figure(res), paths["figure"])
    emit({"a": str(args.a), "b": str(args.b), "output_dir": str(out), "files": paths,
          "registration": res["registration"], "unseen_share": res["unseen_share"], "seconds": res["seconds"],
          "other_files_in_directory": foreign, "table": evaluation_table(res),
          "source_reach": res["source_reach"], "reach_table": reach_table(res)})
