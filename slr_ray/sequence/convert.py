"""A sequence re-simulated as another sensor, written as a SemanticKITTI sequence.

Each frame ``i``: the frames of its window (itself included) accumulated in
the world frame, moved into the target sensor's frame at frame ``i``'s pose
(times ``offset``, a translation in the frame's own axes; or a pose of a
given trajectory), one return per pulse of the target sensor by an estimator
(:mod:`~slr_ray.sequence.estimators`), written in the sensor's scan order
(beam by beam, highest first; each beam by azimuth from the front,
counter-clockwise) with the intensity and SemanticKITTI labels of the union
point each return stands for. A KITTI ``.bin`` holds no ring: its order is
the ring (row ``k // columns``); other formats (``fmt``) carry a ``ring``
attribute.

The output directory holds ``velodyne/NNNNNN.EXT``, ``labels/NNNNNN.label``
(where the input has labels), ``poses.txt`` (the target poses, velodyne
frame), ``calib.txt`` (``Tr`` the identity: the poses are the velodyne's) and
``manifest.json`` (the settings). A rerun with the same settings resumes: the
frames a journal records as written are kept; other settings are refused.

Estimators: those of a union (:data:`~slr_ray.sequence.estimators.ESTIMATORS`)
and ``embree-sources`` (discs from each source frame's own pulse grid, one
scene a frame reused by the targets that hold it:
:func:`~slr_ray.sequence.union.discs_of_frames`); moving objects left out by
their labels and/or by see-through (:class:`~slr_ray.sequence.sources.SeeThrough`,
which needs the frames' own sensor). Blocks of frames run in local worker
processes or on a ``dask.distributed`` scheduler's workers.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import multiprocessing
import os
import queue
import re
import shutil
import signal
import warnings
from contextlib import ExitStack
from dataclasses import dataclass
import threading
import time
import uuid
from collections.abc import Sequence as SequenceABC
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..errors import InputValueError, MissingDependencyError, OutputError, SlrError, SlrWarning
from ..io import PointCloud, atomic_path, check_format, write_cloud
from ..io.outputs import (LOCK_NAME, clean_stale_parts, content_digest, hold_directory, input_sidecars, label_path,
                          link_new)
from ..options import Options
from ..sensors import SENSORS, conversion_reach, sensor as shipped_sensor
from .estimators import FPA_GAP
from .frames import Sequence, write_kitti_poses
from .methods import REGISTRY, TargetFrame, method, method_options, methods_with
from .sources import SeeThrough, base_pattern, source_sensor_problem
from .union import FrameCache, Keep, window

__all__ = ["ConvertOptions", "convert_sequence", "check_source_frame", "target_poses", "MANIFEST", "JOURNAL", "CONVERT_ESTIMATORS"]



class _ConvertEstimators(SequenceABC):
    """The names of the registered methods with the ``convert`` capability, read when asked."""

    def __getitem__(self, i):
        return tuple(methods_with("convert"))[i]

    def __len__(self):
        return len(methods_with("convert"))

    def __repr__(self):
        return repr(tuple(methods_with("convert")))


#: convert's per-pulse rules: the registered methods that work in a conversion
#: (:data:`slr_ray.sequence.methods.REGISTRY`, the ``convert`` capability): those of a union
#: (:data:`~slr_ray.sequence.estimators.ESTIMATORS`), ``rays`` (the target table's own rays, a
#: simulated sensor's pulse centres, no motion, onto the union's planes) and ``embree-sources``
#: (discs from each source frame's own pulse grid)
CONVERT_ESTIMATORS = _ConvertEstimators()

MANIFEST = "manifest.json"
JOURNAL = "journal.jsonl"
#: a run's staging directory in the output directory (``.convert-TOKEN``): its workers write there only,
#: and the run itself gives each frame its final name once the journal lists it
STAGE_PREFIX = ".convert-"
_STAGE = re.compile(r"^\.convert-[0-9a-f]{32}$")
_STATE: dict = {}
#: the fewest frames of a worker's run of consecutive frames (:func:`_spans`): a run's first frames
#: read and mesh the window behind them, which the worker before held
_SPAN_LEAST = 16


CARRIED = ("intensity", "semantic", "instance")  # what a converted frame carries of the union's points


def target_poses(poses, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Each pose moved by ``offset`` in its own axes: ``T_i @ translate(offset)``."""
    P = np.array(poses, np.float64)
    off = np.asarray(offset, np.float64)
    if off.shape != (3,) or not np.all(np.isfinite(off)):
        raise InputValueError(f"the offset must be three finite numbers, got {offset!r}")
    P[:, :3, 3] = P[:, :3, 3] + P[:, :3, :3] @ off
    return P


def _frame_cloud(seq, i, pose, pattern, settings, cache) -> PointCloud:
    frames = window(seq, i, settings["half"], settings["radius"], include_target=True)
    m = REGISTRY[settings["estimator"]]
    source = settings.get("source_sensor")
    frame = TargetFrame(seq, frames, pose, pattern, cache, Keep(settings["drop_moving"], _see_through(settings)),
                        None if source is None else base_pattern(source))
    ret, carried = m.convert_frame(frame, m.options.from_flat(_flat_options(settings)))
    attrs = {n: carried[n] for n in CARRIED if n in carried}
    if settings["format"] != "bin":
        attrs["ring"] = pattern.beam_of_row[ret.keys // pattern.columns].astype(np.int32)
    return PointCloud(ret.points, attrs, np.zeros(3))


def _say_not_carried(seq, fmt: str, attributes) -> None:
    """One warning naming frame 0's per-point fields a converted frame does not carry (an E57's
    colour, a PCD's normals, a LAS's extra dimensions): only intensity and the labels are (hostile pass:
    they were dropped without a word); ``attributes``: frame 0's."""
    if fmt == "bin" and "intensity" not in attributes:  # KITTI's fourth column filled, not said (hostile pass)
        warnings.warn(f"frame {seq.names[0]}: no intensity field: the converted .bin frames hold 0 as intensity",
                      SlrWarning, stacklevel=3)
    dropped = sorted(n for n, v in attributes.items()  # all 0 (a LAS's unused flags): nothing lost
                     if n not in CARRIED and np.ndim(v) >= 1 and np.any(np.asarray(v) != 0))
    if dropped:
        ring = "" if fmt == "bin" else ", and the target's own ring"
        warnings.warn(f"frame {seq.names[0]}: fields not carried into the converted frames: {', '.join(dropped)} "
                      f"(a return carries the intensity and labels of the point it stands for{ring})", SlrWarning,
                      stacklevel=3)


def _flat_options(settings) -> dict:
    """The methods' options by flat key: ``fpa_gap`` and the other ``method_options`` of the settings."""
    return method_options({"fpa_gap": settings["fpa_gap"]} | settings.get("method_options", {}))


def _see_through(settings) -> SeeThrough | None:
    st = settings.get("see_through")
    return None if st is None else SeeThrough(settings["source_sensor"], st["margin_m"], st["votes"], st["half"])


def _cache_frames(settings, st) -> int:
    """Frames a worker's cache holds: a window of ``half`` frames either side (its frames' see-through
    neighbours too) slid one frame a target needs ``2 * half + 1`` (and ``2 * st.half`` more), one spare;
    a window of a radius, of no known width, 16 more than twice ``cache``. A frame held beyond its
    window only costs memory (with embree-rays its mesh's Embree scene: 20 frames held for
    ``--half 2`` peaked at 1.46 GiB a process)."""
    extra = 2 * st.half if st else 0
    if settings["radius"] is None and settings["half"] is not None:
        return 2 * int(settings["half"]) + 2 + extra
    return 2 * settings["cache"] + 16 + extra


def _init(seq, poses, settings, state=None):
    """Set up a process's conversion state (``state``: a Dask worker thread's own instead)."""
    _SAID.clear()  # a conversion's writer warnings said once each (_write_frame)
    st = _see_through(settings)
    (_STATE if state is None else state).update(seq=seq, poses=poses, settings=settings, pattern=shipped_sensor(settings["sensor"]),
                  cache=FrameCache(seq, _cache_frames(settings, st), local=False))


def _init_worker(seq, poses, settings, done=None):
    """A pool worker's start: Ctrl-C reaches the whole process group, and the parent decides (its pool's
    exit terminates the workers): a worker ignores SIGINT, never printing a KeyboardInterrupt's traceback.
    It starts with SIGINT and SIGTERM blocked (the parent's mask while it starts the pool), let in here.
    ``done``: the queue a span's frames are reported on as each is written (:func:`_span_job`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    _init(seq, poses, settings)
    _STATE["done"] = done


def _spans(todo, workers: int, least: int) -> list:
    """``todo`` (frame indices, ascending) cut into runs of consecutive frames for ``workers`` processes:
    a worker converts a run in order, so each frame of it is read and meshed once by that worker (its
    window slides) where blocks handed out in turn made each worker read and mesh every frame of its
    blocks' windows anew (twice the frames with ``half`` 2 and blocks of 4). The runs shrink as the
    work left does (a run is a ``2 * workers``-th of what is left, at least ``least`` frames): a fast
    worker never waits long on a slow one's last run. A gap in ``todo`` (frames resumed) ends a run."""
    out, k, n = [], 0, len(todo)
    while k < n:
        size = max(int(least), -(-(n - k) // (2 * max(1, int(workers)))))
        run = [todo[k]]
        while len(run) < size and k + len(run) < n and todo[k + len(run)] == run[-1] + 1:
            run.append(todo[k + len(run)])
        out.append(run)
        k += len(run)
    return out


def _span_job(span, out, token) -> int:
    """A pool worker converts the consecutive frames of ``span`` (:func:`_spans`) one at a time, putting
    each frame's entries on the run's queue as it is written (the parent records them: progress a
    frame, not a run); returns how many."""
    for i in span:
        _STATE["done"].put(_job([i], out, token))
    return len(span)


#: a Dask worker thread's own conversion state (:func:`_dask_job`)
_THREAD = threading.local()


def _dask_job(block, out, seq, poses, settings, token, after=None) -> list:
    """A block on a Dask worker: the worker thread's state set up by its first block of this conversion
    (``token``), then kept (its frames cache) for the next blocks it gets; ``after``: the block
    before it in its chain (:func:`_dask_chains`), whose result is not used. Each thread of a worker
    (``--nthreads``) holds its own state: one frames cache (not thread-safe) shared by its threads was
    cleared, set up and read by two blocks at once (two conversions' too)."""
    state = getattr(_THREAD, "state", None)
    if state is None or state.get("token") != token:
        state = {}
        _init(seq, poses, settings, state)
        state["token"] = token
        _THREAD.state = state
    return _job(block, out, token, state)


def _dask_chains(blocks, workers: int, size: int) -> list:
    """The blocks as chains of consecutive frames, one a worker (``workers``; :func:`_spans` runs, in
    blocks of ``size``): on Dask each block of a chain is submitted depending on the one before, so the
    scheduler runs it where that one ran (its result is there) and the worker's cache slides along
    the chain (each frame read and meshed once by it), where blocks free to go anywhere had each
    block's window read and meshed anew by whichever worker got it. A block's entries are recorded
    as it ends: progress a block."""
    todo = [i for b in blocks for i in b]
    per = max(size, -(-len(todo) // max(1, int(workers))))  # one chain a worker: with more, a worker
    # freed took the head of another chain before the next block of its own (its window meshed anew)
    return [[run[k:k + size] for k in range(0, len(run), size)] for run in _spans(todo, workers, per)]


def _stage(out, token) -> Path:
    """The staging directory of the run ``token`` in ``out``."""
    return Path(out) / f"{STAGE_PREFIX}{token}"


def _job(block, out, token, state=None) -> list:
    """Convert the frames of ``block`` into the run's staging directory (never under a final
    name: a worker of an interrupted run that goes on writing writes only there, and that
    directory is gone or never published). Each entry says what to publish (``_staged``)."""
    s = _STATE if state is None else state  # (a Dask worker thread's own: _dask_job)
    stage = _stage(out, token)
    fmt = s["settings"]["format"]
    done = []
    for i in block:
        t0 = time.perf_counter()
        cloud = _frame_cloud(s["seq"], i, s["poses"][i], s["pattern"], s["settings"], s["cache"])
        frame = s["seq"].names[i]
        if len(cloud) == 0:
            raise OutputError(f"frame {frame}: no pulse of the target sensor returns from its window (is the "
                              "target pose far from the frames, an --offset or --target-poses away?): nothing "
                              "to write")
        name = f"velodyne/{frame}.{fmt}"
        _write_frame(stage / name, cloud, fmt, frame, Path(out) / "velodyne" / f"*.{fmt}")
        entry = {"frame": int(i), "file": name, "points": int(len(cloud)),
                 "seconds": round(time.perf_counter() - t0, 3)}
        staged = [(str(stage / name), name)]
        label = f"labels/{frame}.label"
        if fmt == "bin" and "semantic" in cloud.attributes and (stage / label).is_file():
            entry["label"] = label
            staged.insert(0, (str(stage / label), label))  # the labels first: a frame is never without them
        entry["_staged"] = staged
        done.append(entry)
    return done


_SAID: set = set()  # the writer's warnings said in this process (once a conversion's frames, not once a frame)


def _write_frame(path: Path, cloud, fmt, frame, shown=None) -> None:
    """``write_cloud``, its failures (a full disk in a LAS/LAZ or E57 library, which may
    not say it as an OSError) one :class:`OutputError` naming the frame. Its warnings (a field
    the format cannot hold) name ``shown``, the frames' final names, not the hidden staging
    file, and are said once, not once a frame (hostile pass)."""
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        try:
            write_cloud(path, cloud, format=fmt)
        except SlrError:
            raise
        except Exception as exc:  # noqa: BLE001 - a writer library's own exception (laspy, lazrs, pye57)
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc) or type(exc).__name__
            raise OutputError(f"cannot write frame {frame} ({fmt}): {why}") from None
    for w in said:
        text = str(w.message) if shown is None else str(w.message).replace(str(path), str(shown))
        if text not in _SAID:
            _SAID.add(text)
            warnings.warn(text, w.category, stacklevel=2)


def _clean_stages(out: Path) -> None:
    """Remove the staging directories of killed runs (the caller holds ``out``'s lock: no other
    run of ours is live there; a late worker of a dead run that writes into one fails)."""
    for p in out.iterdir():
        if _STAGE.match(p.name) and p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)


def _refuse_foreign(out: Path) -> None:
    """A directory without a manifest: refused unless empty (a killed run's temporaries, its
    staging directory and a lock aside)."""
    held = [p.name for p in out.iterdir()
            if p.name != LOCK_NAME and ".part" not in p.name and not _STAGE.match(p.name)]
    if held:  # not a conversion of ours: its files would be written over or mixed with frames
        held.sort()
        raise OutputError(f"{out} holds files that are not a conversion by slr-ray ({', '.join(held[:3])}"
                          f"{', ...' if len(held) > 3 else ''}): write elsewhere")


def _read_manifest(out: Path, settings: dict) -> None:
    """Refuse a manifest of other settings (or none slr_ray can read), in one line."""
    m = out / MANIFEST
    try:
        old = json.loads(m.read_text())
    except (ValueError, UnicodeDecodeError):
        raise InputValueError(f"{m} is not a manifest slr_ray can read: write elsewhere, or remove the "
                              "directory to start again") from None
    before = old.get("settings") if isinstance(old, dict) else None
    if not isinstance(before, dict):
        raise InputValueError(f"{m} holds no settings slr_ray can read: write elsewhere, or remove the "
                              "directory to start again")
    if before != settings:
        diff = sorted(k for k in set(before) | set(settings) if before.get(k) != settings.get(k))
        what = ", ".join(diff)
        old_frames, new_frames = before.get("frames"), settings["frames"]
        if diff == ["frames"] and isinstance(old_frames, list) and len(old_frames) == len(new_frames):
            k = next(k for k, (a, b) in enumerate(zip(old_frames, new_frames)) if a != b)
            what = f"frames: frame {k}'s content is not the one it converted"
        raise InputValueError(f"{out} holds a conversion with other settings ({what}): write elsewhere, "
                              "or remove it to start again")


def _journal(out: Path, seq, settings: dict) -> dict:
    """The entries of ``out``'s journal by frame (withdrawn ones dropped). A line cut short
    (the last, by an interruption) is skipped; any other line that is not an entry this
    conversion wrote (a hand-edited ``file``) is refused in one line."""
    j = out / JOURNAL
    if not j.exists():
        return {}
    try:
        lines = j.read_text().splitlines()
    except UnicodeDecodeError:
        lines = [None]
    fmt = settings["format"]
    entries = {}
    for n, line in enumerate(lines, 1):
        try:
            e = json.loads(line)
        except (TypeError, ValueError):
            if n == len(lines) and line is not None:
                continue  # a line cut short by an interruption
            e = None
        i = e.get("frame") if isinstance(e, dict) else None
        ok = isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(seq)
        if ok and e.get("withdrawn"):
            entries.pop(i, None)
            continue
        ok = ok and e.get("file") == f"velodyne/{seq.names[i]}.{fmt}" and e.get("label") in (
            None, f"labels/{seq.names[i]}.label") and isinstance(e.get("points"), int)
        if not ok:
            raise InputValueError(f"{j} line {n} is not an entry this conversion wrote (a frame of "
                                  f"{len(seq)}, its file velodyne/NAME.{fmt}): remove the directory to start "
                                  "again, or write elsewhere")
        entries[i] = e
    return entries


def _resume(out: Path, settings: dict, seq, labelled: bool) -> dict:
    """The frames an earlier run of the same settings wrote (the journal lists them, and their
    files, labels included, are there). A listed frame with a file gone is converted again (its
    other files, ours, removed; said in one line). A file under a name this run will write
    that the journal does not list is another's: refused before any work."""
    if not (out / MANIFEST).exists():
        return {}
    _read_manifest(out, settings)
    done = {}
    for i, e in _journal(out, seq, settings).items():
        files = [e["file"]] + ([e["label"]] if "label" in e else [])
        missing = labelled and settings["format"] == "bin" and "label" not in e
        present = [f for f in files if os.path.lexists(out / f)]
        if len(present) == len(files) and not missing:
            done[i] = e
            continue
        for f in present:  # this run's own (the journal lists them): written again with the rest
            (out / f).unlink()
        warnings.warn(f"frame {seq.names[i]}: {', '.join(sorted(set(files) - set(present)) or ['its labels'])} "
                      "gone since it was converted: converting it again", SlrWarning, stacklevel=3)
    fmt = settings["format"]
    theirs = [n for i in range(len(seq)) if i not in done
              for n in [f"velodyne/{seq.names[i]}.{fmt}", *([f"labels/{seq.names[i]}.label"] if fmt == "bin" else [])]
              if os.path.lexists(out / n)]
    if theirs:
        raise OutputError(f"{out} holds {theirs[0]}{f' and {len(theirs) - 1} more' if len(theirs) > 1 else ''}, "
                          f"which its {JOURNAL} does not list: this run would write there; move "
                          f"{'it' if len(theirs) == 1 else 'them'} away, or write elsewhere")
    return done


def _identity(seq) -> list:
    """Each frame's content (digests of its file and the labels read with it): what a resume
    compares, not paths (another sequence at the same path, a frame edited since, the same
    frames by another path)."""
    seen: dict = {}

    def digest(p):
        key = os.fspath(p)
        if key not in seen:
            seen[key] = content_digest(p)
        return seen[key]

    return ["+".join(digest(p) for p in [path, *input_sidecars(path, seq.input_format)]) for path in seq.paths]


def _say_copies(seq, identity) -> None:
    """One warning where two frame files of other paths hold the same content (a frame copied under
    another name: each is accumulated at its own pose, a ghost of the scene; a link is refused as
    the same frame named twice). Not refused: a driver may record one frame twice (hostile pass)."""
    first: dict = {}
    for i, (path, key) in enumerate(zip(seq.paths, identity)):
        j = first.setdefault(key, i)
        if j != i and os.path.realpath(seq.paths[j]) != os.path.realpath(path):
            warnings.warn(f"frames {seq.names[j]} and {seq.names[i]} hold the same content ({seq.paths[j]}, {path}): "
                          "a frame copied? each is accumulated at its own pose", SlrWarning, stacklevel=3)
            return


def _labelled(seq, attributes) -> bool:
    """Whether the frames carry SemanticKITTI ``.label`` files: all or none. One frame without
    them would strip the labels of every output frame its window reaches (a union carries an
    attribute all its frames have) and keep its moving objects: refused, naming it."""
    if (seq.input_format or Path(seq.paths[0]).suffix).lower().lstrip(".") != "bin" or seq.meta.get("split"):
        # labels read with the frames (a .npz's or .ply's semantic field): written as .label too (they were
        # staged beside the .bin and never published: hostile pass)
        return "semantic" in attributes  # frame 0's
    has = [label_path(p) is not None for p in seq.paths]
    if any(has) and not all(has):
        k = has.index(False)
        raise InputValueError(f"{seq.paths[k]}: no labels (.label) where the other frames have them: give "
                              f"frame {seq.names[k]} its labels, or convert a copy without the labels/ "
                              "directory")
    return any(has)


@dataclass(frozen=True)
class ConvertOptions(Options):
    """How :func:`convert_sequence` re-simulates and writes a sequence.

    Attributes
    ----------
    estimator : str
        The return of each pulse (:mod:`~slr_ray.sequence.estimators`: 'nearest', 'fpa'...).
    half : int or None
        Frames each side of a frame accumulated with it (its window).
    radius : float or None
        Or the frames whose poses lie within this many metres.
    offset : (3,) float
        A translation of the target sensor in each frame's own axes.
    drop_moving : bool
        Leave out the points of moving objects (SemanticKITTI's labels).
    fmt : str
        The frames' file format ('bin': KITTI's).
    fpa_gap : float
        The first-peak average's gap (m; ``fpa`` and ``rays``).
    workers : int
        Processes converting frames.
    block : int
        Frames a worker converts at a time.
    see_through : SeeThrough or None
        Leave out of the unions the points other frames saw through (its sensor is the frames' own).
    source_sensor : str or None
        The frames' own sensor (a shipped name), which ``estimator='embree-sources'`` needs
        (``see_through``'s when not given).
    scheduler : str or None
        The address of a ``dask.distributed`` scheduler whose workers convert the blocks of
        frames (they write the frames into ``out``: a file system they share), instead of
        ``workers`` local processes.
    method_options : dict or None
        The registered methods' other options by flat key (``PREFIX_FIELD``:
        :func:`slr_ray.sequence.methods.method_options`); over ``fpa_gap`` where both name it.
    """

    estimator: str = "nearest"
    half: int | None = 2
    radius: float | None = None
    offset: tuple = (0.0, 0.0, 0.0)
    drop_moving: bool = True
    fmt: str = "bin"
    fpa_gap: float = FPA_GAP
    workers: int = 1
    block: int = 4
    see_through: SeeThrough | None = None
    source_sensor: str | None = None
    scheduler: str | None = None
    method_options: dict | None = None


def _input_format(seq) -> str | None:
    """The format the frames are read as (``--input-format``), where it is not the one each frame's name
    says (None: as named): a rerun reading them as another format (a ``.bin`` as nuScenes' five floats,
    not KITTI's four) makes other frames of the same files, so it is a setting a resume compares."""
    if not seq.input_format:
        return None
    fmt = check_format(seq.paths[0], seq.input_format)
    named = []
    for p in seq.paths:
        try:
            named.append(check_format(p))
        except SlrError:
            return fmt
    return None if set(named) == {fmt} else fmt


def check_source_frame(seq: Sequence, estimator: str, source_sensor, given_options=None, frame=None) -> None:
    """Refuse, before any frame is cast or file written, an estimator that can do nothing with the
    sequence's first frame (``frame``, read if not given) of the source sensor ``source_sensor`` (``given_options``: the
    methods' options by flat key)
    (:meth:`~slr_ray.sequence.methods.SequenceMethod.source_problem`): ``embree-rays`` on frames that
    make no ring mesh by the beams it finds (a ring field, the scan order, else the table's elevation
    bands): a terrestrial campaign's scans, which failed late with no pulse returned. Frames not in
    the scan order that fill the bands (a spinning unit's, shuffled) mesh and are not refused."""
    m = method(estimator, "convert", what="estimator")
    if not m.needs_source_sensor or source_sensor is None:
        return
    if frame is None:
        pts, attrs = seq.layout.frame(seq, 0)  # its own axes; no pose needed (before registering)
    else:
        pts, attrs = frame.points, frame.attributes
    base = shipped_sensor(source_sensor)
    why = m.source_problem(pts, attrs, base, m.options.from_flat(method_options(given_options)))
    if why is not None:
        raise InputValueError(f"frame {seq.names[0]} ({seq.paths[0]}): {why}: the {estimator} estimator needs "
                              f"{base.name}'s beams in the frames ({m.source_why}) and would return no pulse; name "
                              "the frames' own sensor (--source-sensor), or use an estimator without it (nearest, "
                              "fpa, embree-knn)")


def convert_sequence(seq: Sequence, out, sensor: str, options: ConvertOptions | None = None, *, poses=None,
                     progress: bool = False, inputs: dict | None = None, **keywords) -> dict:
    """Write ``seq`` re-simulated as ``sensor`` into the directory ``out`` (module docstring).
    ``out`` must exist (the caller plans and locks it). ``options``: a :class:`ConvertOptions`
    (or its fields as keywords); ``poses``: a target trajectory, one pose a frame (default the
    sequence's). Returns a summary."""
    o = ConvertOptions.of(options, **keywords)
    estimator, half, radius, offset, drop_moving, fmt, fpa_gap = (o.estimator, o.half, o.radius, o.offset,
                                                                  o.drop_moving, o.fmt, o.fpa_gap)
    see_through, source_sensor, scheduler = o.see_through, o.source_sensor, o.scheduler
    if scheduler and (importlib.util.find_spec("dask") is None
                      or importlib.util.find_spec("dask.distributed") is None):
        raise MissingDependencyError('convert on a scheduler needs dask: pip install "slr_ray[dask]"')
    if seq.poses is None:
        raise InputValueError("the sequence has no poses: give a trajectory (--poses) or --register")
    out = Path(out)
    base = seq.poses if poses is None else np.asarray(poses, np.float64)
    if base.shape != (len(seq), 4, 4):
        raise InputValueError(f"{len(base)} target poses for {len(seq)} frames")
    P = target_poses(base, offset)
    m = method(estimator, "convert", what="estimator")
    flat = method_options({"fpa_gap": fpa_gap} | dict(o.method_options or {}))
    m.options.from_flat(flat)  # its options checked before anything is written
    settings = {"sensor": sensor, "estimator": estimator, "half": half, "radius": radius,
                "offset": [float(x) for x in offset], "drop_moving": bool(drop_moving), "format": fmt.lstrip("."),
                "fpa_gap": float(flat["fpa_gap"]), "frames": [], "poses": np.round(P, 12).reshape(len(P), -1).tolist(),
                "cache": int(half or 8)}
    given = _input_format(seq)
    if given is not None:  # only where it reads the frames otherwise than their names say (as method options)
        settings["input_format"] = given
    fields = {f.name for f in dataclasses.fields(ConvertOptions)}
    extra = {k: v for k, v in (o.method_options or {}).items() if k not in fields}
    if extra:  # only where given: a manifest written before method options resumes as it was
        settings["method_options"] = extra
    if see_through is not None:
        if source_sensor is not None and source_sensor != see_through.sensor:
            raise InputValueError(f"two source sensors: {source_sensor!r} and see_through's {see_through.sensor!r}")
        if not isinstance(see_through.sensor, str):
            raise InputValueError("convert names the source sensor (a shipped sensor's name), not a table")
        source_sensor = see_through.sensor
        settings["see_through"] = see_through.to_dict()
    if m.needs_source_sensor and source_sensor is None:
        raise InputValueError(f"the {estimator} estimator needs the frames' own sensor (source_sensor, "
                              f"--source-sensor): {m.source_why}")
    probe = seq.read(0) if source_sensor is not None else None
    if source_sensor is not None:
        check_source_frame(seq, estimator, source_sensor, flat, probe)
        why = source_sensor_problem(probe.points, probe.attributes, shipped_sensor(source_sensor))
        if why is not None:  # its rays (see-through) and pulse grids (embree-sources) are then the table's
            warnings.warn(f"frame {seq.names[0]}: {why}: are the frames of this sensor (source_sensor, "
                          "--source-sensor)?", SlrWarning, stacklevel=2)
        settings["source_sensor"] = source_sensor
    shipped_sensor(sensor)  # an unknown name or format is refused before anything is written
    for key in ("sensor", "source_sensor"):  # a card's content, not its path: one edited since is not resumed
        name = settings.get(key)
        if isinstance(name, str) and name not in SENSORS and name.lower().endswith(".json"):
            settings[f"{key}_card"] = content_digest(name)
    check_format(out / "velodyne" / f"000000.{settings['format']}", settings["format"])
    first = probe if probe is not None else seq.read(0)  # read once: fields, labels, the conversion's reach
    _say_not_carried(seq, settings["format"], first.attributes)
    labelled = _labelled(seq, first.attributes)
    settings["frames"] = _identity(seq)
    _say_copies(seq, settings["frames"])
    fresh = not (out / MANIFEST).exists()
    if fresh:
        _refuse_foreign(out)
    _clean_stages(out)
    done: dict = {}
    try:
        with ExitStack() as held:
            # labels/ where they go there (a .bin's): other formats carry them in the frame (no empty labels/)
            for sub in ("velodyne", "labels") if labelled and settings["format"] == "bin" else ("velodyne",):
                (out / sub).mkdir(exist_ok=True)
                # locked as out is: a file written into it by another command meanwhile (scan -o
                # OUT/velodyne/000011.bin) is refused there, not replaced here
                held.enter_context(hold_directory(out / sub))
                clean_stale_parts(out / sub, locked=True)
            done.update(_resume(out, settings, seq, labelled))
            summary = _convert(seq, out, P, settings, done, o, progress, inputs)
        return summary | conversion_reach(shipped_sensor(sensor), first.points, summary["points"])  # (#45)
    except BaseException:
        if fresh and not done:  # nothing converted: leave nothing (none of these files was there before)
            for name in (MANIFEST, JOURNAL, "poses.txt", "calib.txt"):
                (out / name).unlink(missing_ok=True)
            for sub in ("velodyne", "labels"):
                if (out / sub).is_dir() and not any((out / sub).iterdir()):
                    (out / sub).rmdir()
        raise
    finally:
        _STATE.clear()  # the serial run's frames


def _publish(out: Path, staged) -> None:
    """Give a frame's staged files their final names, never over a file: one there now
    (another program's, written meanwhile) is a :class:`FileExistsError` naming it, left as it
    is (and this frame's files just published are taken back)."""
    published = []
    try:
        for src, rel in staged:
            link_new(src, out / rel)
            published.append(out / rel)
    except FileExistsError:
        for p in published:
            p.unlink(missing_ok=True)
        raise


def _run_blocks(seq, out, P, settings, blocks, o: ConvertOptions, token, record) -> None:
    """Convert ``blocks`` (serially, in local processes or on a Dask scheduler), ``record`` each
    block's entries as it comes. On any exit, no worker of this run writes any more: a pool's
    workers are terminated; a scheduler's tasks are cancelled (one already running finishes into
    the staging directory, which :func:`_convert` removes and never publishes)."""
    if o.scheduler:
        from dask.distributed import Client, as_completed, wait

        with Client(o.scheduler) as client:
            shared = client.scatter([seq, P, settings], broadcast=True)  # once, not once a block
            futures = []
            workers = max(1, len(client.scheduler_info().get("workers", {})))
            for chain in _dask_chains(blocks, workers, o.block):
                before = None
                for b in chain:
                    before = client.submit(_dask_job, b, str(out), *shared, token, before, pure=False)
                    futures.append(before)
            try:
                for fut in as_completed(futures):
                    record(fut.result())
            except BaseException:
                client.cancel(futures)
                try:  # those already running: let them end (into the staging directory) before we go on
                    wait(futures, timeout=30)
                except Exception:  # noqa: BLE001 - a timeout: the staging directory is removed anyway
                    pass
                raise
    elif o.workers <= 1 or len(blocks) <= 1:
        _init(seq, P, settings)
        for b in blocks:
            record(_job(b, str(out), token))
    else:
        # spawn, not fork (a forked child inherits numba's thread pools in whatever state they
        # were); multiprocessing.Pool, not ProcessPoolExecutor: on an interrupt (SIGINT, or
        # SIGTERM turned into one by the CLI) its exit terminates the workers at once
        ctx = multiprocessing.get_context("spawn")
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})  # a child's
        try:  # a worker interrupted while it starts prints no traceback of its half-read start-up data
            reports = ctx.Queue()
            pool = ctx.Pool(o.workers, initializer=_init_worker, initargs=(seq, P, settings, reports))
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        with pool:
            todo = [i for b in blocks for i in b]
            runs = [pool.apply_async(_span_job, (span, str(out), token))
                    for span in _spans(todo, o.workers, max(o.block, _SPAN_LEAST))]
            left = len(todo)
            while left:
                try:
                    entries = reports.get(timeout=0.2)
                except queue.Empty:
                    for r in runs:
                        if r.ready() and not r.successful():
                            r.get()  # a worker's exception, raised here
                    continue
                record(entries)
                left -= len(entries)
            for r in runs:
                r.get()


def _convert(seq, out, P, settings, done, o: ConvertOptions, progress, inputs) -> dict:
    labelled = _labelled(seq, seq.read(0).attributes)  # (a ninth parameter would pass convert_sequence's)
    doc = {"settings": settings, "inputs": inputs or {"sequence": [str(p) for p in seq.paths]},
           "pose_source": seq.pose_source}
    for name, text in ((MANIFEST, json.dumps(doc) + "\n"), ("calib.txt", "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")):
        with atomic_path(out / name) as tmp:
            tmp.write_text(text)
    with atomic_path(out / "poses.txt") as tmp:
        write_kitti_poses(tmp, P)
    todo = [i for i in range(len(seq)) if i not in done]
    blocks = [todo[k:k + o.block] for k in range(0, len(todo), o.block)]
    token = uuid.uuid4().hex
    stage = _stage(out, token)
    t0 = time.perf_counter()
    bar = tqdm(total=len(seq), initial=len(done), desc="frames", unit="frame", disable=not progress)
    try:
        for sub in ("velodyne", "labels") if labelled else ("velodyne",):
            (stage / sub).mkdir(parents=True)
        with open(out / JOURNAL, "a") as journal:
            def record(entries):
                # recorded, then published: a frame under its final name is always one the journal lists
                for e in entries:
                    staged = e.pop("_staged")
                    journal.write(json.dumps(e) + "\n")
                    journal.flush()
                    try:
                        _publish(out, staged)
                    except FileExistsError as exc:
                        journal.write(json.dumps({"frame": e["frame"], "withdrawn": True}) + "\n")
                        journal.flush()
                        raise OutputError(f"{exc.filename} appeared in the output directory during the run (this "
                                          "run did not write it): left as it is, and the run stopped; move it "
                                          "away and rerun to resume") from None
                    done[e["frame"]] = e
                    bar.update(1)

            _run_blocks(seq, out, P, settings, blocks, o, token, record)
    finally:
        bar.close()
        shutil.rmtree(stage, ignore_errors=True)  # what was converted and not published (an interruption)
    secs = time.perf_counter() - t0
    return {"output_dir": str(out), "frames": len(seq), "written": len(todo), "resumed": len(seq) - len(todo),
            "points": int(sum(e["points"] for e in done.values())), "seconds": round(secs, 3),
            "seconds_per_frame": round(secs / max(1, len(todo)), 4), "settings": {k: v for k, v in settings.items()
                                                                                 if k not in ("poses", "frames")}}
