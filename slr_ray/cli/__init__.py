"""The ``slr-ray`` command.

Results go to stdout as one line of JSON; logs and progress go to stderr, and
every warning as one line, ``slr-ray: warning: ...`` or, for what slr_ray decided
(:class:`~slr_ray.errors.SlrNote`), ``slr-ray: note: ...``. An
error of the input or the settings (:class:`~slr_ray.errors.SlrError`) or of
the system (``OSError``: no such file, no permission, disk full) exits with
status 2 and one line ``slr-ray: error: ...`` on stderr, and leaves no output
file behind. Anything else is a bug of slr_ray: the full traceback, a request
to report it, and status 1.

``arguments``
    argument groups shared by subcommands (pattern, backend and its options,
    ground labels, positions), their choices taken from the library.
``commands``
    one function per subcommand: flags in, library call, JSON out.
"""

from __future__ import annotations

import argparse
import functools
import signal
import sys
import threading
import traceback
import warnings

from .. import __version__, paper
from ..errors import SlrError, SlrNote, SlrWarning
from ..backends import Backend
from ..io import FORMATS
from ..progress import say_compiling
from ..meshscan import MESH_MODES
from ..scenes import SCENES_DIR
from . import arguments as A
from .commands import COMMANDS
from ..evaluate import METHODS as EVALUATE_METHODS
from ..registration import REGISTRATION_BOUNDS
from .evaluate_command import evaluate as evaluate_command
from .effects_command import RING_SOURCES
from .effects_command import effects as effects_command
from .sequence_command import add_sequence_parser
from .sensor_command import add_sensor_parser

__all__ = ["main", "build_parser"]

_FORMATS = ", ".join(f"{e} (KITTI)" if e == ".bin" else e for e in FORMATS)  # io.FORMATS: the one list


class _Parser(argparse.ArgumentParser):
    """argparse with the command's error contract: one line on stderr, status 2 (``--help`` has the usage)."""

    def error(self, message):
        where = self.prog.removeprefix("slr-ray").strip()  # '' for slr-ray itself: no 'slr-ray: slr-ray:'
        for action in self._actions:  # a subcommand by what the user types: 'cmd' is argparse's dest
            if not isinstance(action.choices, dict):
                continue
            if {action.dest, action.metavar} & set(message.split(": ", 1)[-1].split(", ")):
                message = f"a command is needed: {', '.join(action.choices)}"
            for name in {action.dest, action.metavar} - {None}:
                if message.startswith(f"argument {name}: invalid choice: "):
                    message = "unknown command " + message.removeprefix(f"argument {name}: invalid choice: ")
        self.exit(2, f"slr-ray: error: {where + ': ' if where else ''}{message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):
        # a subcommand refuses what it does not know itself: argparse would hand it up to
        # "slr-ray", whose error could not say which command's --help lists the flags
        namespace, extra = super().parse_known_args(args, namespace)
        if extra and self.prog != "slr-ray" and not any(
                isinstance(a, argparse._SubParsersAction) for a in self._actions):
            self.error(f"unrecognized arguments: {' '.join(extra)}")
        return namespace, extra

    def format_usage(self):
        return self.format_help().split("\n\n", 1)[0] + "\n"

    def format_help(self):
        # a command with many flags: the usage names what is required and "[options]"
        # for the rest (each listed below), not a wall of every flag and choice
        if self.usage is None and not any(isinstance(a, argparse._SubParsersAction) for a in self._actions):
            self.usage = " ".join(["%(prog)s", *filter(None, map(_usage_word, self._actions)), "[options]"])
        return super().format_help()


def _usage_word(action) -> str:
    """``action`` in a short usage line: a positional or a required option, else ''."""
    if action.option_strings and not action.required:
        return ""
    meta = action.metavar or (action.dest.upper() if action.option_strings else action.dest)
    meta = " ".join(meta) if isinstance(meta, tuple) else meta
    if action.nargs == "+":
        meta = f"{meta} [{meta} ...]"
    return f"{action.option_strings[0]} {meta}" if action.option_strings else meta


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="slr-ray", description=(
        "Simulated LiDAR Repositioning: simulate the scans an ideal static scanner "
        "would record from new positions, using only points of one cloud."))
    ap.add_argument("--version", action="version", version=f"slr-ray {__version__}")
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="command")

    def command(name, help_text):
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(func=COMMANDS[name])
        return p

    _scan_parser(command)
    _compare_parser(command)
    _positions_parser(command)
    _profile_parser(command)
    _validate_parser(command)
    _distances_parser(command)
    _augment_parser(command)
    _demo_parser(command)
    _evaluate_parser(sub)
    _effects_parser(sub)
    add_sequence_parser(sub)  # sequence: its parser and handlers live in .sequence_command
    add_sensor_parser(sub)  # sensor: its parser and handlers live in .sensor_command
    _scene_parser(command)
    return ap


def _scan_parser(command) -> None:
    """The ``scan`` command's arguments."""
    p = command("scan", "simulate one scan of a point cloud from a position")
    p.add_argument("input", help=f"input cloud ({_FORMATS})")
    p.add_argument("-o", "--output", required=True, help="output cloud (same formats)")
    A.add_pattern(p, origin="optional")
    p.add_argument("--origin-relative", choices=["centre", "scanner"],
                   help="--origin (default 0 0 0) from the cloud's centre or its recorded scanner origin")
    A.add_backend(p)
    p.add_argument("--format", help="output format, overriding the extension")
    A.add_input_format(p)
    p.add_argument("--keep-range", action="store_true", help="add a 'range' attribute")
    p.add_argument("--keep-ring", action="store_true", help="add 'ring' (beam or zenith row) and 'column'")
    p.add_argument("--range-image", metavar="NPZ", help="also write the scan as a range image (.npz)")
    p.add_argument("--png", help="also draw the range image (PNG)")
    p.add_argument("--chunk-size", type=A.positive_int, default=2_000_000, metavar="N",
                   help="points read at a time from LAS/LAZ (default 2,000,000)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--force", action="store_true", help="overwrite the output")
    p.add_argument("--print-config", action="store_true", help="print the resolved settings (JSON) and stop")
    A.add_effects(p)


def _compare_parser(command) -> None:
    """The ``compare`` command's arguments."""
    p = command("compare", "run both backends on a cloud and report where they differ")
    p.add_argument("input", help=f"input cloud ({_FORMATS})")
    A.add_pattern(p, origin="many")
    p.add_argument("--tolerance", type=A.positive_float, default=paper.SIMILARITY_THRESHOLD, metavar="M",
                   help=f"see-through tolerance (m, default {paper.SIMILARITY_THRESHOLD})")
    A.add_backend(p, default="embree", choose=False)  # both run: no --backend, the embree options
    A.add_input_format(p)
    p.add_argument("--png", help="also write a figure")
    p.add_argument("--quiet", action="store_true", help="no progress")
    p.add_argument("--force", action="store_true", help="overwrite an existing --png")


def _positions_parser(command) -> None:
    """The ``positions`` command's arguments."""
    p = command("positions", "choose secondary scanner positions (the paper's grid method)")
    p.add_argument("input", help=f"input cloud ({_FORMATS})")
    p.add_argument("--n", type=A.positive_int, required=True, help="positions to draw")
    p.add_argument("-o", "--output", required=True, help="positions and per-stage counts (JSON)")
    A.add_positions(p)
    A.add_ground(p)
    p.add_argument("--cell-size", type=A.positive_float, default=paper.CELL_SIZE, metavar="M",
                   help=f"grid cell size (m, default {paper.CELL_SIZE:g})")
    p.add_argument("--ground-count-radius", type=A.positive_float, default=paper.GROUND_COUNT_RADIUS, metavar="M",
                   help=f"radius of the ground point count (m, default {paper.GROUND_COUNT_RADIUS:g})")
    p.add_argument("--ground-height-radius", type=A.positive_float, default=paper.GROUND_HEIGHT_RADIUS, metavar="M",
                   help=f"radius of the ground height (m, default {paper.GROUND_HEIGHT_RADIUS:g})")
    p.add_argument("--profile", default="none", metavar="P",
                   help="azimuth minimum profile: none (default), default, or a JSON path")
    p.add_argument("--allow-fewer", action="store_true", help="accept fewer positions than --n (a warning names both)")
    p.add_argument("--png", help="also write a top view of the cells kept and removed")
    p.add_argument("--quiet", action="store_true", help="no progress (CSF, the azimuth test)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs (never an input)")
    A.add_input_format(p)


def _profile_parser(command) -> None:
    """The ``profile`` command's arguments."""
    p = command("profile", "rebuild the shipped azimuth minimum profile from synthetic scans")
    p.add_argument("--scenes", default=",".join(paper.Q1_SCENES),
                   help=f"shipped scenes, comma-separated (default {','.join(paper.Q1_SCENES)})")
    p.add_argument("--positions-per-scene", type=A.positive_int, default=4, metavar="N",
                   help="positions scanned per scene (default 4)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("-o", "--output", required=True, help="the profile (JSON)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")


def _validate_parser(command) -> None:
    """The ``validate`` command's arguments."""
    p = command("validate", "reproduce the paper's validation (Experiment 1) from a config")
    shipped = sorted(q.stem[len("validate-"):] for q in SCENES_DIR.glob("validate-*.toml"))
    p.add_argument("config", help=f"a shipped config name ({', '.join(shipped)}) or a TOML path")
    p.add_argument("-o", "--output", help="output directory (default slr_ray_validate_NAME); reruns resume")
    p.add_argument("--positions", type=A.positive_int, help="override the number of positions per scene")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--print-config", action="store_true", help="print the resolved config and stop")


def _distances_parser(command) -> None:
    """The ``distances`` command's arguments."""
    p = command("distances", "distance distributions with pulse-sized bins (the paper's Experiment 2)")
    p.add_argument("input", nargs="+", help="input clouds (each one scan; origin from the file or --origin)")
    p.add_argument("-o", "--output", required=True, help="output directory (CSV tables, distances.png)")
    p.add_argument("--origin", nargs=3, type=A.finite_float, metavar=("X", "Y", "Z"),
                   help="scanner origin of every input (over any the files record)")
    p.add_argument("--heights", nargs="+", type=A.positive_float, default=list(paper.SWEEP_HEIGHTS), metavar="M",
                   help=f"scanner heights swept (m, default {' '.join(f'{h:g}' for h in paper.SWEEP_HEIGHTS)})")
    p.add_argument("--positions", type=A.positive_int, default=20, help="SLR positions per input (default 20)")
    p.add_argument("--resolution", type=A.positive_float, default=paper.SECONDARY_RESOLUTION, metavar="DEG",
                   help=f"SLR angular resolution (degrees, default {paper.SECONDARY_RESOLUTION:g})")
    p.add_argument("--max-range", type=A.positive_float, default=120.0, metavar="M",
                   help="farthest range returned (m, default 120)")
    A.add_positions(p)
    A.add_ground(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--force", action="store_true", help="overwrite the tables and figure of an earlier run")


def _augment_parser(command) -> None:
    """The ``augment`` command's arguments."""
    p = command("augment", "many simulated scans of one real scan (resumable, parallel)")
    p.add_argument("input", help=f"input cloud ({_FORMATS})")
    p.add_argument("--n", type=A.positive_int, required=True, help="positions")
    p.add_argument("-o", "--output", required=True, help="output directory (a rerun resumes)")
    p.add_argument("--resolution", type=A.positive_float, default=paper.SECONDARY_RESOLUTION, metavar="DEG",
                   help=f"angular resolution (degrees, default {paper.SECONDARY_RESOLUTION:g})")
    p.add_argument("--heights", nargs="+", type=A.positive_float, metavar="M",
                   help="scanner heights above ground, a scan each (default: --scanner-height)")
    p.add_argument("--format", help="output extension (default: the input's)")
    p.add_argument("--sensor", type=A.sensor_name, metavar="NAME",
                   help="a sensor's beam table instead of --resolution: " + A.SENSOR_HELP)
    A.add_backend(p)
    A.add_positions(p)
    A.add_ground(p)
    p.add_argument("--workers", type=A.positive_int, metavar="N", help="local worker processes (default: all cores)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a dask.distributed scheduler to run on")
    p.add_argument("--chunk-size", type=A.positive_int, metavar="N",
                   help="stream a LAS/LAZ input N points at a time (docs/augment.md)")
    p.add_argument("--per-pass", type=A.positive_int, default=8, metavar="N",
                   help="positions per pass over a streamed input (default 8)")
    p.add_argument("--allow-fewer", action="store_true", help="accept fewer positions than --n (a warning names both)")
    p.add_argument("--force", action="store_true",
                   help="a fresh run into a directory of other files (written among them, never over one)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    A.add_effects(p)


def _demo_parser(command) -> None:
    """The ``demo`` command's arguments."""
    p = command("demo", "the main job on a built-in scene: scene, primary scan, SLR scans by both backends, report")
    p.add_argument("-o", "--output", default="slr_ray_demo", help="output directory (default slr_ray_demo)")
    p.add_argument("--rectangles", type=int, default=200, help="rectangles in the scene (default 200)")
    p.add_argument("--positions", type=A.positive_int, default=4, help="SLR positions (default 4)")
    p.add_argument("--seed", type=int, default=0, help="seed of the scene and positions (default 0)")
    backends = [b.value for b in Backend]
    p.add_argument("--backends", nargs="+", default=backends, choices=backends,
                   help=f"backends run at each position (default all: {' '.join(backends)})")
    p.add_argument("--quick", action="store_true", help="a coarser, faster run (for tests)")
    p.add_argument("--quiet", action="store_true", help="no progress (the report is still printed)")
    p.add_argument("--force", action="store_true", help="overwrite the files of an earlier demo")


def _evaluate_parser(sub) -> None:
    """The ``evaluate`` command's arguments."""
    # evaluate: its handler lives in .evaluate_command (self-contained)
    help_text = "re-simulate frame B from frame A at B's pose and score it against the real B (novel-view metrics)"
    p = sub.add_parser("evaluate", help=help_text, description=help_text)
    p.set_defaults(func=evaluate_command)
    p.add_argument("a", help=f"frame A, the primary, in its sensor's frame ({_FORMATS})")
    p.add_argument("b", help="frame B, the real scan to re-simulate, in its sensor's frame")
    p.add_argument("-o", "--output", required=True, help="a new or empty directory for the tables and figure")
    p.add_argument("--source-sensor", type=A.sensor_name, metavar="NAME",
                   help=f"frame A's sensor: {A.SENSOR_HELP} (default velodyne_hdl64e_s2, KITTI's; --sensor, its "
                        "old name, still works)")
    p.add_argument("--sensor", dest="old_sensor", type=A.sensor_name, metavar="NAME", help=argparse.SUPPRESS)
    p.add_argument("--target-sensor", type=A.sensor_name, metavar="NAME",
                   help="frame B's sensor when it is another unit (default the source's): B is re-simulated as "
                        "that unit at its pose (--transform or --extrinsic; docs/cross_sensor.md)")
    p.add_argument("--beams", default="auto", choices=["auto", "scan-order", "none"],
                   help="each point's beam: auto (a 'ring' field, else the scan order of a KITTI .bin), "
                        "scan-order, or none (elevation bands of the shipped table)")
    p.add_argument("--methods", nargs="+", default=list(EVALUATE_METHODS), choices=list(EVALUATE_METHODS),
                   metavar="M", help=f"methods scored (default all: {', '.join(EVALUATE_METHODS)})")
    p.add_argument("--transform", metavar="FILE", help="B's pose in A's frame (4 x 4 text) instead of registering")
    p.add_argument("--extrinsic", metavar="FILE",
                   help="B's pose as a rig's extrinsic from A's sensor to B's: a 4 x 4 (text, or JSON holding one, "
                        "as SensorsCalibration writes) mapping A's coordinates into B's frame, the inverse of "
                        "--transform")
    p.add_argument("--seen-threshold", type=A.positive_float, default=paper.SIMILARITY_THRESHOLD, metavar="M",
                   help="B's point is seen from A within this (m, default 0.1)")
    p.add_argument("--min-fitness", type=float, default=None, metavar="F",  # None: not given (see evaluate)
                   help="refuse a registration fitting worse: share of B's points with an A point within 0.2 m "
                        f"(default {REGISTRATION_BOUNDS['min_fitness']:g}; the other checks: --accept-registration)")
    p.add_argument("--accept-registration", action="store_true",
                   help="score at the pose registration finds even when it fails the gate (fitness, reverse fitness, "
                        "inlier RMSE, tilt; docs/evaluation.md 'Registration gate')")
    A.add_input_format(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true", help="replace the evaluation files of an existing directory")


def _effects_parser(sub) -> None:
    """The ``effects`` command and its subcommands' arguments."""
    # effects: its handler lives in .effects_command (self-contained)
    help_text = "sensor effects' tools: fit-drop (a ray-drop model from a real frame)"
    p = sub.add_parser("effects", help=help_text, description=help_text)
    p.set_defaults(func=effects_command)
    esub = p.add_subparsers(dest="effects_cmd", required=True, metavar="command")
    q = esub.add_parser("fit-drop", help="fit the ray-drop model of a real frame; writes the JSON --ray-drop reads",
                        description="fit the ray-drop model of a real frame (a spinning sensor's, in its scan "
                                    "order or with a 'ring' attribute); writes the JSON --ray-drop reads")
    q.add_argument("frame", help=f"the frame, in its sensor's frame ({_FORMATS}; a KITTI .bin as written)")
    q.add_argument("-o", "--output", required=True, help="the model (.json)")
    q.add_argument("--origin", nargs=3, type=A.finite_float, metavar=("X", "Y", "Z"),
                   help="the sensor's position (default: the frame's recorded origin; a KITTI .bin's is 0 0 0)")
    q.add_argument("--rings", default="auto", choices=list(RING_SOURCES),
                   help="each point's ring: auto (a 'ring' attribute, else the scan order) or scan-order")
    q.add_argument("--max-gap", type=A.positive_int, default=16,
                   help="longer runs of missing pulses are not counted as drops (sky; default 16)")
    q.add_argument("--column-step-deg", type=A.positive_float,
                   help="azimuth step between firings (default: the median step within a ring)")
    q.add_argument("--no-intensity", action="store_true", help="fit without the intensity term")
    q.add_argument("--intensity-scale", type=A.positive_float, default=1.0,
                   help="the intensity value of reflectivity 1 (default 1, KITTI's; 255 for 8-bit)")
    q.add_argument("-k", type=A.positive_int, default=10, help="neighbours of the PCA normals (default 10)")
    A.add_input_format(q)
    q.add_argument("--force", action="store_true", help="overwrite an existing output")


def _scene_parser(command) -> None:
    """The ``scene`` command and its subcommands' arguments."""
    p = command("scene", "synthetic rectangle scenes: info, build, scan")
    ssub = p.add_subparsers(dest="scene_cmd", required=True, metavar="command")
    spec_help = "a shipped scene name or a scene TOML path (docs/scenes.md)"
    q = ssub.add_parser("info", help="counts of a scene spec (shipped name or path)")
    q.add_argument("spec", help=spec_help)
    q = ssub.add_parser("build", help="write the scene's mesh")
    q.add_argument("spec", help=spec_help)
    q.add_argument("-o", "--output", required=True, help="the mesh (.ply, .obj, ...)")
    q.add_argument("--force", action="store_true", help="overwrite an existing output")
    q = ssub.add_parser("scan", help="ground-truth scan of a scene (with the effects its [effects] table requires)")
    q.add_argument("spec", help=spec_help)
    A.add_pattern(q, origin="required")
    q.add_argument("--mode", default="center", choices=list(MESH_MODES),
                   help="ray per pulse: center (default), nearest of k x k, or a dense grid")
    q.add_argument("--supersample", type=A.positive_int, default=4, help="k for --mode nearest (k x k rays a pulse)")
    q.add_argument("--spacing", type=A.positive_float, default=paper.DENSE_SPACING,
                   help=f"grid spacing for --mode dense (m, default {paper.DENSE_SPACING})")
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    q.add_argument("--no-effects", action="store_true",
                   help="the ideal scan, without the scene's [effects]")
    q.add_argument("-o", "--output", required=True, help="the scan (a cloud)")
    q.add_argument("--force", action="store_true", help="overwrite an existing output")


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that every ``finally`` runs (temporary files
    removed, worker pools terminated) before the command exits with 143."""


def _on_sigterm(signum, frame):
    raise _Terminated()


def _show_warning(message, category, filename, lineno, file=None, line=None, *, show=None):
    """slr_ray's own warnings as one line, ``slr-ray: warning: ...`` (``note:`` for what
    slr_ray decided on the user's behalf); any other (numpy's, Python's) goes to ``show``,
    the showwarning in place before: at a terminal Python's, which prints through
    :func:`_one_line_warning`; in a caller that records warnings, its recorder."""
    if not issubclass(category, SlrWarning):
        return show(message, category, filename, lineno, file, line)
    kind = "note" if issubclass(category, SlrNote) else "warning"
    print(f"slr-ray: {kind}: {' '.join(str(message).split())}", file=sys.stderr, flush=True)


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    """A warning as the command says it: ``slr-ray: warning: MESSAGE`` on one line, never
    Python's file, line and source; one not a plain UserWarning (numpy's, say) with its category."""
    text = " ".join(str(message).split())
    if category is not UserWarning and not issubclass(category, SlrWarning):
        text = f"{category.__name__}: {text}"
    return f"slr-ray: warning: {text}\n"


def main(argv=None) -> int:
    # warnings.formatwarning, not showwarning: a caller recording warnings (pytest, catch_warnings) still
    # gets them whole; restored on the way out (main runs inside a test's or another program's process)
    formatted = warnings.formatwarning
    warnings.formatwarning = _one_line_warning
    try:
        return _main(argv)
    finally:
        warnings.formatwarning = formatted


def _main(argv) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # argparse: 0 for --help/--version, 2 for a usage error
        return int(exc.code or 0)
    with warnings.catch_warnings():
        warnings.simplefilter("always", SlrWarning)  # each said, even when a run says the same twice
        warnings.showwarning = functools.partial(_show_warning, show=warnings.showwarning)
        return _run(args)


def _run(args) -> int:
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    if not getattr(args, "quiet", False):
        say_compiling()  # a first run's 30-40 s of numba compiling, said once (not blamed on a phase)
    try:
        args.func(args)
    except _Terminated:
        print("slr-ray: terminated", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print("slr-ray: interrupted", file=sys.stderr)
        return 130
    except (SlrError, OSError) as exc:
        text = exc.for_cli() if isinstance(exc, SlrError) else str(exc)  # flags, not library arguments
        msg = text.splitlines()[0] if text else type(exc).__name__
        print(f"slr-ray: error: {msg}", file=sys.stderr)
        return 2
    except Exception:  # not a deliberate error: a bug, which the user should see whole and report
        traceback.print_exc()
        print(f"slr-ray: internal error (a bug in slr_ray {__version__}): please report it with the command "
              "line and the traceback above", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


