"""``slr-ray evaluate``: a real pair of frames, B re-simulated from A at B's pose
(:mod:`slr_ray.evaluate`). Kept apart from :mod:`.commands` so that the
subcommand stands alone: flags in, library call, files and one JSON line out."""

from __future__ import annotations


import numpy as np

from ..errors import InputValueError
from ..evaluate import EVALUATION_FILES, evaluate_pair, evaluation_table, write_evaluation
from ..io import read_cloud
from ..outputs import OutputPlan
from .commands import emit

__all__ = ["evaluate"]


def evaluate(args):
    plan = OutputPlan(force=args.force)
    for path in (args.a, args.b):
        plan.read(path, fmt=args.input_format)  # --input-format bin reads a .label beside any name
    plan.read(args.transform, sidecars=False)  # a text matrix: nothing is read beside it
    out = plan.directory(args.output)
    for name in EVALUATION_FILES.values():
        plan.write(out / name)
    with plan:
        _evaluate(args, out)


def _evaluate(args, out):
    transform = None
    if args.transform:
        try:
            transform = np.loadtxt(args.transform, dtype=np.float64, ndmin=2)
        except (ValueError, UnicodeDecodeError) as exc:  # text that is not numbers, a binary file
            raise InputValueError(f"--transform {args.transform}: not a 4 x 4 text matrix ({exc})") from None
        if transform.shape != (4, 4) or not np.isfinite(transform).all():
            raise InputValueError(f"--transform {args.transform}: expected a finite 4 x 4 matrix, got "
                                  f"{transform.tolist() if transform.size <= 16 else transform.shape}")
    clouds = [read_cloud(p, args.input_format, allow_empty=False) for p in (args.a, args.b)]
    frames = []  # each in its sensor's frame: a file that records its scanner's position (.npz, .pcd, .e57)
    for c in clouds:  # holds world coordinates, moved to that position in float64
        frames.append(c.points - np.asarray(c.origin, np.float64) if c.origin is not None else c.points)
    beams = []
    for c in clouds:  # a 'ring' field where the file has one, else the scan order (KITTI .bin), or none
        ring = c.attributes.get("ring")
        beams.append(np.asarray(ring, np.int64) if ring is not None and args.beams == "auto" else
                     ("scan-order" if args.beams in ("auto", "scan-order") else None))
    res = evaluate_pair(frames[0], frames[1], a_beams=beams[0], b_beams=beams[1], sensor=args.sensor,
                        methods=args.methods, transform=transform, seen_threshold=args.seen_threshold,
                        min_fitness=args.min_fitness, progress=not args.quiet)
    paths = write_evaluation(res, out, force=True,  # the plan checked --force file by file
                             inputs={"a": str(args.a), "b": str(args.b), "sensor": args.sensor, "beams": args.beams,
                                     "origins": [None if c.origin is None else np.asarray(c.origin).tolist()
                                                 for c in clouds]})
    emit({"a": str(args.a), "b": str(args.b), "output_dir": str(out), "files": paths,
          "registration": res["registration"], "unseen_share": res["unseen_share"], "seconds": res["seconds"],
          "table": evaluation_table(res)})
