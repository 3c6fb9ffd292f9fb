"""Argument groups shared by the ``slr-ray`` subcommands.

Each group is declared once and its choices come from the library (backend
enum, pattern presets, mesh-scan modes, backend option fields), so a new
backend, preset or option shows up on the command line without a second list.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re

from .. import paper
from ..backends import BACKENDS, Backend, require_rays, scanner_class
from ..effects import Effects
from ..effects.stages import EFFECT_FLAGS, FLAGS as EFFECT_FLAG_SPECS
from ..errors import InputValueError
from ..pattern import PRESETS, ScanPattern, preset
from ..sensors import SENSORS, read_sensor_file, sensor

__all__ = ["add_pattern", "pattern_from", "add_backend", "backend_from", "add_ground", "ground_from",
           "add_input_format", "add_effects", "effects_from", "check_effects", "finite_float", "positive_float",
           "positive_int", "non_negative_int"]


def finite_float(text: str) -> float:
    """An argparse type: a finite number."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return v


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    v = finite_float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return v


def non_negative_int(text: str) -> int:
    """An argparse type: an integer >= 0."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return v


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text!r}")
    return v


def add_input_format(p) -> None:
    p.add_argument("--input-format", metavar="EXT", help="input format, overriding the extension (bin: KITTI, "
                   "pcd.bin: nuScenes)")


# --- scan pattern -------------------------------------------------------------------------------------------

def add_pattern(p, origin: str = "optional", resolution_default: float | None = None) -> None:
    """Scanner origin(s) and scan pattern.

    ``origin``: 'required', 'optional' (default: the input's recorded origin),
    'many' (repeatable, at least one) or 'none'.
    """
    g = p.add_argument_group("scanner and pattern")
    if origin == "many":
        g.add_argument("--origin", nargs=3, type=finite_float, action="append", required=True,
                       metavar=("X", "Y", "Z"), help="a scanner position (repeat for several)")
    elif origin != "none":
        g.add_argument("--origin", nargs=3, type=finite_float, metavar=("X", "Y", "Z"),
                       required=origin == "required",
                       help="scanner position, in the cloud's coordinates" + (
                           " (default: the input's recorded origin)" if origin == "optional" else ""))
    g.add_argument("--resolution", type=positive_float, metavar="DEG", default=resolution_default,
                   help="angular resolution, both axes (degrees)"
                   + (f"; default {resolution_default:g}" if resolution_default else ""))
    g.add_argument("--preset", choices=sorted(PRESETS), help="a pattern of the paper (other options override it)")
    g.add_argument("--sensor", type=sensor_name, metavar="NAME",
                   help="a sensor's beam table instead of a uniform pattern: " + SENSOR_HELP)
    g.add_argument("--sensor-file", metavar="PATH",
                   help="a calibration: Ouster metadata .json, Velodyne .yaml, or a beam table .json "
                        "as slr_ray/data/sensors/*.json")
    g.add_argument("--columns", type=positive_int, metavar="N",
                   help="columns per revolution of a sensor (azimuth steps)")
    g.add_argument("--zenith-range", nargs=2, type=finite_float, metavar=("A", "B"),
                   help="zenith field of view (degrees, 0 = up; default 0 180)")
    g.add_argument("--min-range", type=finite_float, metavar="M", help="nearest range returned (m; default: any)")
    g.add_argument("--max-range", type=finite_float, metavar="M", help="farthest range returned (m; default: any)")


#: The pattern's argument names in its errors, as the flags a user types.
_PATTERN_FLAGS = {"azimuth_resolution": "--resolution", "zenith_resolution": "--resolution",
                  "zenith_range": "--zenith-range", "min_range": "--min-range", "max_range": "--max-range"}


def pattern_from(args):
    """The pattern of the pattern group's flags: a :class:`ScanPattern` or a
    :class:`~slr_ray.sensors.BeamPattern` (``--sensor``, ``--sensor-file``);
    its errors name the flags (``--zenith-range``), not the library's arguments."""
    try:
        return _pattern_from(args)
    except InputValueError as exc:
        exc.flags = {**_PATTERN_FLAGS, **exc.flags}
        raise


def _pattern_from(args):
    if getattr(args, "sensor", None) or getattr(args, "sensor_file", None):
        if args.sensor and args.sensor_file:
            raise InputValueError("give --sensor or --sensor-file, not both")
        if args.resolution is not None or args.preset or args.zenith_range:
            raise InputValueError("--sensor/--sensor-file set the angles: drop --resolution, --preset and "
                                  "--zenith-range")
        changes = {k: v for k, v in (("columns", args.columns), ("min_range", args.min_range),
                                     ("max_range", args.max_range)) if v is not None}
        if args.sensor:
            return sensor(args.sensor, **changes)
        return read_sensor_file(args.sensor_file, **changes)  # Ouster .json, Velodyne .yaml or a table .json
    if getattr(args, "columns", None) is not None:
        raise InputValueError("--columns goes with --sensor or --sensor-file")
    if args.preset:
        base = preset(args.preset)
        changes = {k: v for k, v in (("resolution", args.resolution),
                                     ("zenith_range", tuple(args.zenith_range) if args.zenith_range else None),
                                     ("max_range", args.max_range), ("min_range", args.min_range)) if v is not None}
        return base.with_(**changes) if changes else base
    if args.resolution is None:
        raise InputValueError("give --resolution DEG or --preset NAME")
    return ScanPattern(resolution=args.resolution,
                       zenith_range=tuple(args.zenith_range) if args.zenith_range else (0.0, 180.0),
                       min_range=args.min_range, max_range=args.max_range)


# --- backend and its options ---------------------------------------------------------------------------------

#: Option fields not settable from the command line (arrays a point).
_NOT_ON_CLI = {"normals", "primary_beams"}


def _boolean(text: str) -> bool:
    """``true``/``false`` (or yes/no, 1/0), any case."""
    t = text.strip().lower()
    if t in ("true", "yes", "1", "on"):
        return True
    if t in ("false", "no", "0", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def _option_type(name: str, typ: str):
    """argparse type and nargs of one option field, from its numpydoc type."""
    if name == "radius":
        def radius(text):
            try:
                v = float(text)
            except ValueError:
                return text  # a mode name, checked by the options class
            if not (math.isfinite(v) and v > 0):  # a number, not a mode: say what a radius must be
                raise argparse.ArgumentTypeError(f"a disc radius must be a finite number of metres > 0 (or "
                                                 f"'spacing', 'footprint'), got {text!r}")
            return v
        return radius, None
    if typ.startswith("(3,)"):
        return finite_float, 3
    if typ.startswith("bool"):
        return _boolean, None
    if typ.startswith("int"):
        return int, None
    if typ.startswith("float"):
        return finite_float, None
    return str, None


_OPTION_CLASSES = {str(b): entry.options for b, entry in BACKENDS.items()}

#: One line of ``--help`` (and a metavar) per backend option. The option classes'
#: docstrings hold the whole story and docs/backends.md "Options" its figures; a
#: field missing here shows its docstring's first sentence.
OPTION_HELP = {
    "n_threads": ("N", "threads (default: all cores)"),
    "radius": ("R", "disc radius (m), 'spacing' (default) or 'footprint'"),
    "radius_scale": ("S", "multiplies every radius (default 1)"),
    "k": ("K", "neighbours of 'spacing' radii and normals"),
    "orientation": (None, "discs along the normal, facing the ray or the primary"),
    "engine": (None, "exact discs, or polygon fans (cross-checks)"),
    "segments": ("N", "rim vertices of a fan engine's disc (>= 3)"),
    "ties": ("W", "tie window in disc radii, 0 off (default 1 or 3)"),
    "primary_origin": (("X", "Y", "Z"), "the primary scanner's position"),
    "primary_resolution": ("DEG", "the primary's uniform resolution (degrees)"),
    "primary_pattern": ("NAME", "the primary's sensor or preset, if not uniform"),
    "min_radius": ("M", "floor of computed radii (default 0.1 x median spacing)"),
    "fallback_radius": ("M", "radius when the cloud has no spacing"),
    "chunk": ("N", "points per neighbour query (about 100 bytes a point)"),
    "neighbours": (None, "neighbours: k nearest, or the primary's pulse grid"),
    "max_incidence": ("DEG", "turn discs edge-on to the primary to this angle"),
    "grid_gate": ("F", "pulse-grid neighbours within this fraction of range"),
    "grid_spacing": (None, "pulse-grid spacing: mean distance or axis step"),
    "primary_image": (None, "a scan from the primary's origin returns the primary's own point in each pulse"),
    "silhouettes": (None, "pulse-grid discs kept within the pulses next to their point's, as the primary saw"),
    "pulse_cells": (None, "each disc cut to its own point's pulse of the primary, reaching its centre ray"),
}


def _first_sentence(text: str) -> str:
    """A docstring description's first sentence, without its reST markup."""
    text = text.replace("``", "")
    depth = 0
    for i, c in enumerate(text):  # never inside parentheses: "(the primary saw through there; ..." goes on
        depth += (c == "(") - (c == ")")
        if c in ".;" and depth <= 0 and (i + 1 == len(text) or text[i + 1].isspace()):
            return text[:i]
    return text.rstrip(".;")


def add_backend(p, default: str = Backend.BINNING.value, choose: bool = True) -> None:
    """``--backend`` and every backend's option flags, generated from the option
    classes' fields (a field shared by several backends is one flag), grouped by
    the backends they apply to; the help is one line each, the details a link.
    ``choose=False``: the option flags only (a command that runs every backend)."""
    if choose:
        p.add_argument("--backend", default=default, choices=list(_OPTION_CLASSES),
                       help=f"subsampling backend (default {default}; docs/backends.md)")
    else:
        p.set_defaults(backend=default)
    seen: dict = {}
    for backend, cls in _OPTION_CLASSES.items():
        for name, (typ, text) in cls.describe().items():
            if name not in _NOT_ON_CLI:
                seen.setdefault(name, (cls, typ, text, []))[3].append(backend)
    groups: dict = {}
    for name, (cls, typ, text, backends) in seen.items():
        key = tuple(backends)
        if key not in groups:
            title = " and ".join(backends) + " options"
            groups[key] = p.add_argument_group(title, "details: docs/backends.md \"Options\"" if
                                               len(backends) < len(_OPTION_CLASSES) else None)
        kind, nargs = _option_type(name, typ)
        choices = cls.choices().get(name)
        metavar, short = OPTION_HELP.get(name, (None, _first_sentence(text or typ)))
        if kind is _boolean:  # its values, and its default, said
            default = {f.name: f.default for f in dataclasses.fields(cls)}.get(name)
            metavar, short = "{true,false}", f"{short} (default {str(default).lower()})"
        groups[key].add_argument(
            "--" + name.replace("_", "-"), dest=f"opt_{name}", type=kind, nargs=nargs, choices=choices,
            default=None, metavar=None if choices else metavar or name.split("_")[-1].upper(),
            # argparse formats help with %: a docstring's "85 %" must not read as a conversion
            help=short.replace("%", "%%"))


def backend_from(args, backend: str | None = None) -> dict:
    """The options given for ``backend`` (default ``args.backend``); flags of another backend are an error."""
    backend = backend or args.backend
    fields = set(_OPTION_CLASSES[backend].describe())
    given, foreign = {}, []
    for key, value in vars(args).items():
        if key.startswith("opt_") and value is not None:
            name = key[4:]
            if name in fields:
                given[name] = tuple(value) if isinstance(value, list) else value
            else:
                foreign.append("--" + name.replace("_", "-"))
    if foreign:
        raise InputValueError(f"{', '.join(foreign)} do(es) not apply to --backend {backend}")
    return given


# --- ground labels -------------------------------------------------------------------------------------------

def add_ground(p) -> None:
    """Where ground labels come from (:func:`slr_ray.positions.ground_labels`)."""
    g = p.add_argument_group("ground labels", "default: the input's is_ground, LAS class 2 or label 0; "
                             "without them, found by CSF (said on stderr)")
    g.add_argument("--ground-attribute", metavar="NAME", help="per-point attribute holding ground labels")
    g.add_argument("--ground-value", type=int, metavar="V", help="its ground value (default 2, LAS ground; needs --ground-attribute)")
    g.add_argument("--csf", action="store_true", help="find ground by CSF even when the input has labels")
    g.add_argument("--cloth-resolution", type=positive_float, default=0.5, metavar="M", help="CSF cloth cell (m, default 0.5)")


def ground_from(args) -> dict:
    """Keywords of :func:`slr_ray.positions.ground_labels` from the ground group."""
    if args.ground_value is not None and not args.ground_attribute:
        raise InputValueError(f"--ground-value {args.ground_value} needs --ground-attribute NAME (the attribute "
                              "holding it): alone it would be ignored")
    return {"attribute": args.ground_attribute, "value": args.ground_value, "csf": True if args.csf else None,
            "cloth_resolution": args.cloth_resolution}


def _count_or_auto(text: str):
    """An argparse type: an integer >= 1, or 'auto'."""
    return text if text == "auto" else positive_int(text)


def add_positions(p) -> None:
    """The grid method's settings (:func:`slr_ray.positions.select_positions`)."""
    g = p.add_argument_group("positions (the paper's grid method)")
    g.add_argument("--seed", type=int, default=0, metavar="N", help="random seed of the draw (default 0)")
    g.add_argument("--min-ground-points", type=_count_or_auto, default="auto", metavar="N|auto",
                   help=f"ground points a position needs within 5 m; 'auto' (default): the paper's "
                        f"{paper.MIN_GROUND_POINTS:,} (for its 0.036 deg scans) scaled by the cloud's density, "
                        "0.2545%% of the best cell's count (docs/positions.md); give "
                        f"{paper.MIN_GROUND_POINTS} for the paper's number")
    g.add_argument("--scanner-height", type=positive_float, default=paper.SCANNER_HEIGHT, metavar="M",
                   help=f"scanner height above the ground (m, default {paper.SCANNER_HEIGHT})")


# --- sensor effects ------------------------------------------------------------------------------------------

def sensor_name(text: str) -> str:
    """An argparse type: a shipped sensor's name or a sensor card's path (``.json``; read, and refused in one
    line if it is not a card, when the command uses it)."""
    if text in SENSORS or text.lower().endswith(".json"):
        return text
    raise argparse.ArgumentTypeError(f"{text!r} is neither a shipped sensor ({', '.join(SENSORS)}) nor a "
                                     "sensor card (.json: `slr-ray sensor fit` writes one)")


#: the help of a flag that takes a sensor
SENSOR_HELP = "a shipped sensor (" + ", ".join(SENSORS) + ") or a sensor card .json (`slr-ray sensor fit`)"


def _number_or_sensor(text: str):
    """An argparse type: a finite number, or 'sensor' (the sensor table's value)."""
    return text if text == "sensor" else finite_float(text)


def add_effects(p) -> None:
    """Sensor effects (:class:`~slr_ray.effects.Effects`, docs/effects.md): a file and flags for the common ones."""
    g = p.add_argument_group("sensor effects", "all off by default; a flag overrides --effects; docs/effects.md")
    g.add_argument("--effects", metavar="FILE", help="effect options, a TOML or JSON file")
    types = {"number-or-sensor": _number_or_sensor, "int": int, "text": None}
    for f in EFFECT_FLAG_SPECS:  # generated from the stages' options (slr_ray.effects.stages)
        g.add_argument(f.flag, metavar=f.metavar, help=f.help, choices=f.choices, nargs=f.nargs,
                       **({"type": types[f.kind]} if types[f.kind] else {}))

def effects_from(args) -> Effects | None:
    """The effects of the effects group: ``--effects FILE`` with each flag
    given over it; None when neither is given. A bad value is an error that
    names its flag (or the file)."""
    base = Effects.load(args.effects) if args.effects is not None else None  # "" too: an unset variable
    changes = {}
    for name, flag in EFFECT_FLAGS.items():
        value = getattr(args, flag[2:].replace("-", "_"))
        if value is None:
            continue
        value = tuple(value) if isinstance(value, list) else value
        try:
            Effects(**{name: value})  # alone, so that the error is this flag's
        except InputValueError as exc:
            raise InputValueError(f"{flag}: {exc}") from None
        changes[name] = value
    if base is None and not changes:
        return None
    eff = dataclasses.replace(base or Effects(), **changes)
    try:
        eff.check_needs()
    except InputValueError as exc:  # an option that needs another, off: name the flags
        msg = str(exc)
        for name, flag in EFFECT_FLAGS.items():
            msg = re.sub(rf"\b{name}\b", flag, msg)
        raise InputValueError(f"--effects {args.effects}: {msg}" if base is not None else msg) from None
    if eff.motion:
        where = f"--effects {args.effects}" if args.effects else "the effects"
        raise InputValueError(f"{where}: motion needs the sensor's poses over the sweep, which the command line "
                              "does not take (slr_ray.effects.simulate(..., poses=) does)")
    return eff


def check_effects(eff: Effects | None, backend: str, pattern) -> Effects | None:
    """``eff`` with its 'sensor' values read from ``pattern``, checked against the
    backend; None when no effect is on (a seed alone: the ideal scan)."""
    if eff is None or not eff.any:
        return None
    if eff.divergence_mrad:
        require_rays(scanner_class(backend), "--divergence-mrad (divergence_mrad)")
    return eff.resolve(pattern)
