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

import importlib.util
import json
import multiprocessing
import signal
from dataclasses import dataclass
import time
import uuid
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..errors import InputValueError, MissingDependencyError, OutputError
from ..io import PointCloud, atomic_path, check_format, write_cloud
from ..io.outputs import LOCK_NAME, clean_stale_parts
from ..options import Options
from ..sensors import sensor as shipped_sensor
from .estimators import ESTIMATORS, FPA_GAP, estimate
from .frames import Sequence, write_kitti_poses
from .rays import cast_rays
from .sources import SeeThrough, base_pattern
from .union import FrameCache, accumulate, discs_of_frames, nearest_of_frames, to_frame, window

__all__ = ["ConvertOptions", "convert_sequence", "target_poses", "MANIFEST", "JOURNAL", "CONVERT_ESTIMATORS"]

#: convert's per-pulse rules: those of a union (:data:`~slr_ray.sequence.estimators.ESTIMATORS`),
#: ``rays`` (the target table's own rays, a simulated sensor's pulse centres, no motion, onto the
#: union's planes) and ``embree-sources`` (discs from each source frame's own pulse grid)
CONVERT_ESTIMATORS = (*ESTIMATORS, "rays", "embree-sources")

MANIFEST = "manifest.json"
JOURNAL = "journal.jsonl"
_STATE: dict = {}


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
    st = _see_through(settings)
    if settings["estimator"] == "nearest":  # a frame at a time: the union is never held whole
        ret, carried = nearest_of_frames(seq, frames, pose, pattern, settings["drop_moving"], cache, st)
    elif settings["estimator"] == "embree-sources":  # a scene a frame, reused by the targets that hold it
        ret, carried = discs_of_frames(cache, frames, pose, pattern, base_pattern(settings["source_sensor"]),
                                       settings["drop_moving"], st)
    else:
        union = accumulate(seq, frames, drop_moving=settings["drop_moving"], cache=cache, see_through=st)
        u = to_frame(union.points, pose)
        if settings["estimator"] == "rays":
            ret = cast_rays(u, pattern, gap=settings["fpa_gap"])
        else:
            ret = estimate(u, pattern, settings["estimator"], gap=settings["fpa_gap"])
        carried = {n: v[ret.index] for n, v in union.attributes.items()}
    attrs = {n: carried[n] for n in ("intensity", "semantic", "instance") if n in carried}
    if settings["format"] != "bin":
        attrs["ring"] = pattern.beam_of_row[ret.keys // pattern.columns].astype(np.int32)
    return PointCloud(ret.points, attrs, np.zeros(3))


def _see_through(settings) -> SeeThrough | None:
    st = settings.get("see_through")
    return None if st is None else SeeThrough(settings["source_sensor"], st["margin_m"], st["votes"], st["half"])


def _init(seq, poses, settings):
    st = _see_through(settings)
    _STATE.update(seq=seq, poses=poses, settings=settings, pattern=shipped_sensor(settings["sensor"]),
                  cache=FrameCache(seq, 2 * settings["cache"] + 16 + (2 * st.half if st else 0), local=False))


def _init_worker(seq, poses, settings):
    """A pool worker's start: Ctrl-C reaches the whole process group, and the parent decides (its pool's
    exit terminates the workers): a worker ignores SIGINT, never printing a KeyboardInterrupt's traceback.
    It starts with SIGINT and SIGTERM blocked (the parent's mask while it starts the pool), let in here."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    _init(seq, poses, settings)


def _dask_job(block, out, seq, poses, settings, token) -> list:
    """A block on a Dask worker: the worker's state set up by its first block of this conversion
    (``token``), then kept (its frames cache) for the next blocks it gets."""
    if _STATE.get("token") != token:
        _STATE.clear()
        _init(seq, poses, settings)
        _STATE["token"] = token
    return _job(block, out)


def _job(block, out) -> list:
    s = _STATE
    done = []
    for i in block:
        t0 = time.perf_counter()
        cloud = _frame_cloud(s["seq"], i, s["poses"][i], s["pattern"], s["settings"], s["cache"])
        name = f"velodyne/{s['seq'].names[i]}.{s['settings']['format']}"
        write_cloud(Path(out) / name, cloud, format=s["settings"]["format"])
        done.append({"frame": int(i), "file": name, "points": int(len(cloud)),
                     "seconds": round(time.perf_counter() - t0, 3)})
    return done


def _resume(out: Path, settings: dict) -> dict:
    m = out / MANIFEST
    if not m.exists():
        held = sorted(p.name for p in out.iterdir() if p.name != LOCK_NAME and ".part" not in p.name)
        if held:  # not a conversion of ours: its files would be written over or mixed with frames
            raise OutputError(f"{out} holds files that are not a conversion by slr-ray ({', '.join(held[:3])}"
                              f"{', ...' if len(held) > 3 else ''}): write elsewhere")
        return {}
    try:
        old = json.loads(m.read_text())
    except ValueError:
        raise InputValueError(f"{m} is not a manifest slr_ray can read: write elsewhere") from None
    before = old.get("settings") if isinstance(old, dict) else None
    if before != settings:
        diff = sorted(k for k in set(before or {}) | set(settings) if (before or {}).get(k) != settings.get(k))
        raise InputValueError(f"{out} holds a conversion with other settings ({', '.join(diff)}): write elsewhere, "
                              "or remove it to start again")
    done = {}
    j = out / JOURNAL
    if j.exists():
        for line in j.read_text().splitlines():
            try:
                e = json.loads(line)
            except ValueError:
                continue  # a line cut short by an interruption
            if (out / e["file"]).exists():
                done[e["frame"]] = e
    return done


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
        The first-peak average's gap (m).
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
    if estimator not in CONVERT_ESTIMATORS:
        raise InputValueError(f"unknown estimator {estimator!r}; choose from {list(CONVERT_ESTIMATORS)}")
    settings = {"sensor": sensor, "estimator": estimator, "half": half, "radius": radius,
                "offset": [float(x) for x in offset], "drop_moving": bool(drop_moving), "format": fmt.lstrip("."),
                "fpa_gap": float(fpa_gap), "frames": [str(p) for p in seq.paths],
                "poses": np.round(P, 12).reshape(len(P), -1).tolist(), "cache": int(half or 8)}
    if see_through is not None:
        if source_sensor is not None and source_sensor != see_through.sensor:
            raise InputValueError(f"two source sensors: {source_sensor!r} and see_through's {see_through.sensor!r}")
        if not isinstance(see_through.sensor, str):
            raise InputValueError("convert names the source sensor (a shipped sensor's name), not a table")
        source_sensor = see_through.sensor
        settings["see_through"] = see_through.to_dict()
    if estimator == "embree-sources" and source_sensor is None:
        raise InputValueError("the embree-sources estimator needs the frames' own sensor (source_sensor, "
                              "--source-sensor): their discs come from their own pulse grids")
    if source_sensor is not None:
        shipped_sensor(source_sensor)
        settings["source_sensor"] = source_sensor
    shipped_sensor(sensor)  # an unknown name or format is refused before anything is written
    check_format(out / "velodyne" / f"000000.{settings['format']}", settings["format"])
    fresh = not (out / MANIFEST).exists()
    done = _resume(out, settings)
    try:
        return _convert(seq, out, P, settings, done, o, progress, inputs)
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


def _convert(seq, out, P, settings, done, o: ConvertOptions, progress, inputs) -> dict:
    workers, block, scheduler = o.workers, o.block, o.scheduler
    (out / "velodyne").mkdir(exist_ok=True)
    clean_stale_parts(out / "velodyne", locked=True)  # a killed run's temporaries (the caller holds out's lock)
    probe = seq.read(0)
    if "semantic" in probe.attributes:
        (out / "labels").mkdir(exist_ok=True)
    doc = {"settings": settings, "inputs": inputs or {}, "pose_source": seq.pose_source}
    for name, text in ((MANIFEST, json.dumps(doc) + "\n"), ("calib.txt", "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")):
        with atomic_path(out / name) as tmp:
            tmp.write_text(text)
    with atomic_path(out / "poses.txt") as tmp:
        write_kitti_poses(tmp, P)
    todo = [i for i in range(len(seq)) if i not in done]
    blocks = [todo[k:k + block] for k in range(0, len(todo), block)]
    t0 = time.perf_counter()
    bar = tqdm(total=len(seq), initial=len(done), desc="frames", unit="frame", disable=not progress)
    with open(out / JOURNAL, "a") as journal:
        def record(entries):
            for e in entries:
                journal.write(json.dumps(e) + "\n")
                done[e["frame"]] = e
            journal.flush()
            bar.update(len(entries))

        try:
            if scheduler:
                from dask.distributed import Client, as_completed

                with Client(scheduler) as client:
                    token = uuid.uuid4().hex
                    shared = client.scatter([seq, P, settings], broadcast=True)  # once, not once a block
                    futures = [client.submit(_dask_job, b, str(out), *shared, token, pure=False) for b in blocks]
                    for fut in as_completed(futures):
                        record(fut.result())
            elif workers <= 1 or len(blocks) <= 1:
                _init(seq, P, settings)
                for b in blocks:
                    record(_job(b, str(out)))
            else:
                # spawn, not fork (a forked child inherits numba's thread pools in whatever state they
                # were); multiprocessing.Pool, not ProcessPoolExecutor: on an interrupt (SIGINT, or
                # SIGTERM turned into one by the CLI) its exit terminates the workers at once
                ctx = multiprocessing.get_context("spawn")
                mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})  # a child's
                try:  # a worker interrupted while it starts prints no traceback of its half-read start-up data
                    pool = ctx.Pool(workers, initializer=_init_worker, initargs=(seq, P, settings))
                finally:
                    signal.pthread_sigmask(signal.SIG_SETMASK, mask)
                with pool:
                    for entries in pool.imap_unordered(partial(_job, out=str(out)), blocks):
                        record(entries)
        except BaseException:
            for sub in ("velodyne", "labels"):  # what a killed worker left mid-write
                if (out / sub).is_dir():
                    clean_stale_parts(out / sub, locked=True)
            raise
        finally:
            bar.close()
    secs = time.perf_counter() - t0
    return {"output_dir": str(out), "frames": len(seq), "written": len(todo), "resumed": len(seq) - len(todo),
            "points": int(sum(e["points"] for e in done.values())), "seconds": round(secs, 3),
            "seconds_per_frame": round(secs / max(1, len(todo)), 4), "settings": {k: v for k, v in settings.items()
                                                                                 if k not in ("poses", "frames")}}
