"""``slr-ray sensor``: sensor cards (:mod:`slr_ray.sensorfit`, :func:`slr_ray.sensors.read_card`).

``fit``: a spinning unit's card fitted from frames, written as the JSON that
every ``--sensor`` (and ``--source-sensor``, ``sensor("card.json")``) reads;
``show``: a shipped sensor's or a card's table, as one JSON line. Kept apart
from :mod:`.commands`, as :mod:`.effects_command` is."""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

from ..errors import InputValueError, SlrWarning
from ..io import atomic_path
from ..io.outputs import OutputPlan
from ..sensorfit import RING_FIELDS, fit_card, merge_split_beams
from ..sensors import card_dict, sensor
from . import arguments as A
from .commands import emit

__all__ = ["add_sensor_parser", "sensor_command"]


def add_sensor_parser(sub) -> None:
    """The ``sensor`` command and its sub-commands."""
    help_text = "sensor cards: fit a spinning unit's beam table from its frames, show a table"
    p = sub.add_parser("sensor", help=help_text, description=help_text)
    p.set_defaults(func=sensor_command)
    ssub = p.add_subparsers(dest="sensor_cmd", required=True, metavar="command")
    text = ("a spinning unit's card (each beam's elevation, height, azimuth offset, drop rate; columns per turn; "
            "ranges seen) fitted from one or more of its frames, each in the sensor's own axes; a frame that is "
            "not a spinning unit's is refused")
    q = ssub.add_parser("fit", help=text, description=text)
    q.add_argument("frames", nargs="+", help="frames of one unit (any point-cloud format)")
    q.add_argument("-o", "--output", required=True, help="the card, a new .json file")
    q.add_argument("--rings", choices=["auto", "field", "points"], default="auto",
                   help="each point's beam: auto (a ring field, " + "/".join(RING_FIELDS) + ", or a KITTI .bin's "
                        "scan order, where every frame has one; else the points), field (required), points "
                        "(from the points' elevations only)")
    q.add_argument("--name", help="the card's name (default: the output's stem)")
    q.add_argument("--source", help="where the frames came from, kept in the card (default: their paths)")
    q.add_argument("--allow-mixed-frames", action="store_true",
                   help="fit frames that look like two units' (beams one frame hardly returns from holding another's "
                        "points, or rings at other elevations) as one card anyway; refused by default")
    q.add_argument("--merge-split-beams", type=A.positive_float, metavar="DEG",
                   help="merge beams fitted from the points (no ring field) closer than DEG degrees, two at a time "
                        "from the closest, weighted by their points: one beam seen at two elevations in deskewed "
                        "frames (BALM's OS0-64-like frames: 109 beams, 64 at 0.45); off by default")
    A.add_input_format(q)
    q.add_argument("--force", action="store_true", help="overwrite an existing output")
    q = ssub.add_parser("show", help="a shipped sensor's or a card's table, as one JSON line")
    q.add_argument("sensor", type=A.sensor_name, help=A.SENSOR_HELP)


def sensor_command(args):
    if args.sensor_cmd == "fit":
        fit(args)
    elif args.sensor_cmd == "show":
        emit(card_dict(sensor(args.sensor)))
    else:  # argparse's required sub-command leaves no other
        raise InputValueError(f"unknown sensor command {args.sensor_cmd!r}")


def fit(args):
    if Path(args.output).suffix.lower() != ".json":
        raise InputValueError(f"-o {args.output}: a card is written as JSON (.json)")
    seen: dict = {}
    for f in args.frames:  # one frame given twice would weigh its beams' drop rates and ranges twice
        r = Path(f).resolve()
        if r in seen:
            raise InputValueError(f"{f}: named twice among the frames (as {seen[r]})")
        seen[r] = f
    plan = OutputPlan(force=args.force)
    for f in args.frames:
        plan.read(f, fmt=args.input_format)
    plan.write(args.output)
    with plan:
        t0 = time.perf_counter()
        ring = {"auto": "auto", "field": True, "points": False}[args.rings]
        with warnings.catch_warnings():
            if args.merge_split_beams:  # the split-beam warning is what the merge answers: said after it, if any
                warnings.filterwarnings("ignore", message=".*one beam seen twice", category=SlrWarning)
            card = fit_card(list(args.frames), ring=ring, name=args.name or Path(args.output).stem,
                            source=args.source, input_format=args.input_format, allow_mixed=args.allow_mixed_frames)
        if args.merge_split_beams:
            card = merge_split_beams(card, args.merge_split_beams)
            if card.meta["fit"]["split_beams"]:
                warnings.warn(f"--merge-split-beams {args.merge_split_beams:g}: {card.meta['fit']['split_beams']} "
                              f"of the {card.n_beams} beams still lie under a quarter of the gaps beside them from the "
                              "next (a larger bound?)", SlrWarning, stacklevel=2)
        with atomic_path(Path(args.output)) as tmp:
            tmp.write_text(json.dumps(card_dict(card), indent=1) + "\n")
    q = card.meta["fit"]
    emit({"output": str(args.output), "frames": len(args.frames), "beams": card.n_beams, "columns": card.columns,
          "elevation_range_deg": [min(card.elevation_deg), max(card.elevation_deg)],
          "min_range": card.min_range, "max_range": card.max_range, "how": q["how"],
          "median_off_beam_deg": q["median_off_beam_deg"], "share_assigned": q["share_assigned"],
          "split_beams": q["split_beams"], "merged": q.get("merged"),
          "seconds": round(time.perf_counter() - t0, 6)})
