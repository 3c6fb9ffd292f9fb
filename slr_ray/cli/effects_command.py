"""``slr-ray effects``: sensor effects' own tools (:mod:`slr_ray.effects`).

``fit-drop``: the ray-drop model of a real frame (:func:`~slr_ray.effects.frame_pulses`,
:func:`~slr_ray.effects.fit_ray_drop`), written as the JSON that ``--ray-drop``
(and ``ray_drop`` in an effects or scene file) reads. Kept apart from
:mod:`.commands`, as :mod:`.evaluate_command` is: flags in, library call, files
and one JSON line out."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..effects import fit_ray_drop, frame_pulses
from ..effects.raydrop import COLUMN_STEP_RANGE_DEG, INTENSITY_SCALE_RANGE, NORMAL_K_RANGE
from ..errors import InputValueError
from ..io import atomic_path, read_cloud
from ..io.outputs import OutputPlan
from .commands import emit

__all__ = ["effects", "RING_SOURCES"]

#: Where fit-drop takes each point's ring from.
RING_SOURCES = ("auto", "scan-order")


def effects(args):
    if args.effects_cmd == "fit-drop":
        fit_drop(args)
    else:  # argparse's required sub-command leaves no other
        raise InputValueError(f"unknown effects command {args.effects_cmd!r}")


def fit_drop(args):
    if Path(args.output).suffix.lower() != ".json":
        raise InputValueError(f"-o {args.output}: the model is written as JSON (.json)")
    lo, hi = NORMAL_K_RANGE
    if not lo <= args.k <= hi:
        raise InputValueError(f"-k {args.k}: a PCA normal takes {lo} to {hi} neighbours ({lo}: a plane)")
    lo, hi = INTENSITY_SCALE_RANGE
    if not lo <= args.intensity_scale <= hi:
        raise InputValueError(f"--intensity-scale {args.intensity_scale:g}: the intensity of reflectivity 1 lies in "
                              f"[{lo:g}, {hi:g}] (1 KITTI's, 255 8-bit, 65535 16-bit)")
    lo, hi = COLUMN_STEP_RANGE_DEG
    if args.column_step_deg is not None and not lo <= args.column_step_deg <= hi:
        raise InputValueError(f"--column-step-deg {args.column_step_deg:g}: a spinning unit's step between "
                              f"firings lies in [{lo:g}, {hi:g}] deg")
    plan = OutputPlan(force=args.force)
    plan.read(args.frame, fmt=args.input_format)
    plan.write(args.output)
    with plan:
        t0 = time.perf_counter()
        cloud = read_cloud(args.frame, args.input_format, allow_empty=False)
        origin = args.origin if args.origin is not None else cloud.origin
        if origin is None:
            raise InputValueError(f"{args.frame} records no scanner origin: give --origin X Y Z")
        ring = cloud.attributes.get("ring")
        if args.rings == "auto" and ring is not None:
            rings, source = np.asarray(ring), "the 'ring' attribute"  # checked, not truncated, by frame_pulses
        else:
            rings, source = None, "the scan order"  # frame_pulses: rings_from_scan_order
        intensity = None if args.no_intensity else cloud.attributes.get("intensity")
        if intensity is not None and np.ndim(intensity) != 1:
            intensity = None
        if len(cloud) < args.k + 1:
            raise InputValueError(f"-k {args.k}: {args.frame} has {len(cloud)} points, too few for {args.k} "
                                  "neighbours a point")
        try:  # the rings are checked before the normals (PCA of -k neighbours about the origin) are estimated
            fp = frame_pulses(cloud.points, origin, rings=rings, intensity=intensity,
                              column_step_deg=args.column_step_deg, max_gap=args.max_gap, k=args.k)
        except InputValueError as exc:  # a frame that is not a scan: say the flag and the frame
            raise InputValueError(f"--rings {args.rings}: {args.frame}: {exc}") from None
        info = {"source": Path(args.frame).name, "rings": source, "max_gap": args.max_gap, "k": args.k,
                "column_step_deg": fp["column_step_deg"], "rings_counted": int(len(np.unique(fp["ring"])))}
        try:
            model = fit_ray_drop(fp["range"], fp["incidence"], fp["dropped"], fp["intensity"],
                                 intensity_scale=args.intensity_scale, info=info)
        except InputValueError as exc:  # e.g. a frame with no dropped pulse: say which frame
            raise InputValueError(f"{args.frame}: {exc}") from None
        with atomic_path(Path(args.output)) as tmp:
            tmp.write_text(json.dumps(model.to_dict(), indent=1))
    emit({"frame": str(args.frame), "output": str(args.output), "pulses": model.info["pulses"],
          "dropped": model.info["dropped"], "drop_rate": model.info["drop_rate"],
          "uses_intensity": model.uses_intensity, "rings": source, "column_step_deg": fp["column_step_deg"],
          "coef": dict(zip(model.names, model.coef)), "seconds": round(time.perf_counter() - t0, 6)})
