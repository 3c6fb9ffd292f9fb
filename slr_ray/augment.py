"""Many simulated scans from one real scan: ``slr-ray augment``.

Ground labels (the input's, or CSF), candidate positions by the grid method,
and one SLR scan per position and scanner height, each written in the input's
format (every attribute carried through the indices) under a temporary name
and renamed, so an interrupted run never leaves a half-written scan. A
manifest (``manifest.json``, rewritten atomically every few seconds, with a
journal line per scan in between) records the settings, each position, the
pattern, counts, timings and the software version; a rerun with the same
settings skips the scans it lists whose files exist, so it resumes to the
same result, and a rerun with other settings is refused.

Scans run in parallel: local worker processes by default (the cloud is sent
to each worker once, when it starts, and prepared once per worker; the cores
are shared out between them), or the workers of a Dask cluster
(``scheduler=ADDRESS`` of a running ``dask.distributed`` scheduler; the cloud
is scattered to the workers once). In one process (``workers=1``) each file
is written by a thread while the next scan runs.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import multiprocessing
import os
import re
import signal
import tempfile
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import __version__
from .backends import (enclosed_note, options_for, prepare, primary_from_cloud, require_rays, require_streamable,
                       scanner_class)
from .effects import Effects, effect_cloud, simulate
from .errors import InputValueError, MissingDependencyError, OutputError, SlrError, SlrWarning, refuse_memory
from .io import PointCloud, atomic_path, check_format, read_cloud, write_cloud
from .io.manifest import (JOURNAL, MANIFEST, append_journal, refuse_strangers, refuse_theirs, resumable,
                          same_settings)
from .io.outputs import OutputPlan, content_digest, label_destinations, link_new, output_sidecars, part_prefix
from .paper import MIN_GROUND_POINTS, SCANNER_HEIGHT, SECONDARY_RESOLUTION
from .pattern import ScanPattern, as_pattern
from .positions import ground_labels, require_positions, select_positions
from .progress import bar as progress_bar
from .io.streaming import STREAMED_FORMATS
from .streaming import las_positions, scan_las_many

__all__ = ["augment", "AugmentConfig", "MANIFEST", "JOURNAL"]

_WORKER = {}


#: Seconds between rewrites of manifest.json during a run.
MANIFEST_EVERY = 10.0


#: the signals that stop a run: the parent's to act on (it terminates its workers), never a worker's
_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


class _WorkerProcess(multiprocessing.context.SpawnProcess):
    """A worker started with SIGINT and SIGTERM blocked (the mask a child
    inherits), so that a worker interrupted while it starts (Ctrl-C reaches
    the whole process group; the pool terminates its workers) never prints a
    traceback of its half-read start-up data: :func:`_init_worker` ignores
    SIGINT and lets SIGTERM in. The parent's signals stay blocked while it
    sends a worker its start-up data, and arrive once it is sent."""

    def start(self):
        # the mask holds for this thread only: a signal another thread (numba's, tqdm's) takes still runs
        # the parent's Python handler in the main thread, which raised KeyboardInterrupt in the middle of
        # sending the start-up data (the worker then printed EOFError). In the main thread the handlers
        # are deferred too, and the signals said once the worker has all it needs.
        deferred, handlers = [], {}
        if threading.current_thread() is threading.main_thread():
            handlers = {s: signal.signal(s, lambda signum, frame: deferred.append(signum)) for s in _STOP_SIGNALS}
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        try:
            super().start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
            for s, h in handlers.items():
                signal.signal(s, h)
            for s in dict.fromkeys(deferred):
                signal.raise_signal(s)


class _WorkerContext(multiprocessing.context.SpawnContext):
    Process = _WorkerProcess


def _init_worker(points, attributes, origin, meta):
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides, and terminates the pool
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)  # a SIGTERM sent meanwhile ends it here
    _WORKER["cloud"] = PointCloud(points, attributes, origin, meta)


def _remove_temporaries(jobs) -> None:
    """Temporary files of ``jobs``: those of workers killed mid-write (the pool
    terminates its workers with SIGTERM, which no worker code outlives), and
    scans staged but not published (:func:`_write_job`), labels included. One
    listing of each directory, however many jobs."""
    wanted = {}
    for job in jobs:
        path = Path(job["path"])
        for d in {path.parent, *(p.parent for p in output_sidecars(path))}:
            wanted.setdefault(d, set()).add(path.name)
    for d, names in wanted.items():
        if not d.is_dir():
            continue
        for p in d.iterdir():
            m = _TEMPORARY.match(p.name)  # a stage, or a stage's own temporary (..NAME...)
            if m is not None and m["name"] in names:
                p.unlink(missing_ok=True)


_TEMPORARY = re.compile(r"^\.\.?(?P<name>.+?)\.\d+@[A-Za-z0-9_-]+\.[^.]+\.part")


def _scanner(cloud, backend, options):
    """The cloud prepared for ``backend``, once per process (a worker keeps it
    for all its scans: the embree backend's neighbours and BVH are built once)."""
    key = (id(cloud), backend, json.dumps(options, sort_keys=True))
    cache = _WORKER.setdefault("scanners", {})
    if key not in cache:
        cache.clear()  # one cloud at a time
        cache[key] = prepare(cloud.points, backend, options)
    return cache[key]


def _scan_job(job, cloud):
    """The scan of one job: ``(subset cloud, manifest entry, start time)``."""
    t0 = time.perf_counter()
    pattern = as_pattern(job["sensor"]) if job.get("sensor") else ScanPattern.from_dict(job["pattern"])
    scanner = _scanner(cloud, job["backend"], job["options"])
    if job.get("effects"):
        intensity = cloud.attributes.get("intensity")
        scan = simulate(scanner, job["origin"], pattern, job["effects"],  # resolved once, by the parent
                        intensity=intensity if intensity is not None and np.ndim(intensity) == 1 else None,
                        primary_origin=cloud.origin)
        sub = effect_cloud(scan, cloud)
    else:
        scan = scanner.scan(job["origin"], pattern)
        sub = cloud.subset(scan.indices)
    sub.origin = np.asarray(job["origin"], float)
    entry = {"file": Path(job["path"]).name, "position": job["position"], "height": job["height"],
             "origin": list(job["origin"]), "points": len(scan)}
    note = enclosed_note(scan, job["path"])
    if note:  # said by the run, once for all such scans (_Told), as the writer's warnings are
        entry["_warnings"] = [(note, SlrWarning)]
    return sub, entry, t0


def _write_job(job, sub, entry, t0):
    """Write a job's scan, complete, under a hidden staging name beside its own
    (a ``.bin``'s labels too); its manifest entry, with ``"_staged"``: the
    ``(staged, final)`` pairs that :func:`_publish` renames once the run has
    recorded the scan. Staged, not renamed here: a worker's file under a final
    name before the run records it would be, after an interruption, a file
    the run cannot tell from another program's."""
    final = Path(job["path"])
    fd, stage = tempfile.mkstemp(prefix=part_prefix(final), suffix=".part" + final.suffix, dir=final.parent)
    os.close(fd)
    stage = Path(stage)
    labels = label_destinations(stage)[0] if final.suffix.lower() == ".bin" else None
    try:
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            write_cloud(stage, sub)
        # about the scan the user will see, not its staging name; said by the run, once for all scans
        told = [(str(w.message).replace(str(stage), str(final)), w.category) for w in said]
    except BaseException as exc:
        for p in (stage, labels):
            if p is not None:
                p.unlink(missing_ok=True)
        if isinstance(exc, (OSError, SlrError)) and str(stage) in str(exc):  # the scan's name, not its stage's
            if isinstance(exc, OSError) and exc.errno is not None:
                raise OSError(exc.errno, str(exc.strerror).replace(str(stage), str(final))) from exc
            raise type(exc)(str(exc).replace(str(stage), str(final))) from exc
        raise
    staged = [(str(stage), str(final))]
    if labels is not None and labels.exists():
        staged.insert(0, (str(labels), str(label_destinations(final)[0])))
    return {**entry, "seconds": round(time.perf_counter() - t0, 4), "_staged": staged,
            "_warnings": entry.get("_warnings", []) + told}


def _publish(staged, ext) -> list:
    """Give a scan's staged files their final names, never over a file: one
    there now (another program's, written into the directory during the run) is
    an :class:`~slr_ray.errors.OutputError` naming it, left as it is, and the
    scan's staged files are removed; so is a ``.label`` a reader would pair with
    a ``.bin`` scan written without labels. Returns the paths published."""
    final = Path(staged[-1][1])
    finals = {Path(f) for _, f in staged}
    unpaired = [p for p in output_sidecars(final, ext) if p not in finals and os.path.lexists(p)]
    published = []
    try:
        if unpaired:
            raise FileExistsError(unpaired[0])
        for stage, dest in staged:
            link_new(stage, dest)
            published.append(Path(dest))
    except FileExistsError as exc:
        for p in published:  # this scan's own, just linked
            p.unlink(missing_ok=True)
        for stage, _ in staged:
            Path(stage).unlink(missing_ok=True)
        theirs = exc.filename or exc.args[0]
        raise OutputError(f"{theirs} appeared in the output directory during the run (this run did not write it): "
                          "left as it is, and the run stopped; move it away and rerun to resume") from None
    return published


def _scan_one(job, cloud=None):
    """One SLR scan staged for ``job['path']`` (in a worker); returns its manifest
    entry, with ``"_warnings"``: what the scan warned, for the parent to say (a
    worker's stderr would print Python's warning text, not the caller's)."""
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        entry = _write_job(job, *_scan_job(job, cloud if cloud is not None else _WORKER["cloud"]))
    return {**entry, "_warnings": [(str(w.message), w.category) for w in said] + entry["_warnings"]}


class _Told:
    """What the scans warned, each distinct warning said once: a scan's own
    name in it stands for all of them (``.../scan_*.xyz: ... (in 2,000 scans)``),
    where one line a scan would bury the rest of stderr."""

    def __init__(self, out: Path, ext: str):
        self.every = str(out / f"scan_*{ext}")
        self.seen = {}  # (message with the scan's name replaced, category) -> [first message, count]

    def add(self, warned, final) -> None:
        for message, category in warned:
            key = (message.replace(str(final), self.every), category)
            self.seen.setdefault(key, [message, 0])[1] += 1

    def say(self) -> None:
        for (general, category), (first, count) in self.seen.items():
            warnings.warn(first if count == 1 else f"{general} (in {count:,} scans)", category, stacklevel=3)
        self.seen.clear()


def _run_streamed(jobs, path, pattern, chunk, per_pass, done, progress=False) -> None:
    """The jobs on a LAS/LAZ file read in chunks, ``per_pass`` positions per
    pass over it; ``done(entry)`` in job order."""
    for b in range(0, len(jobs), per_pass):
        batch = jobs[b:b + per_pass]
        t0 = time.perf_counter()
        scans = scan_las_many(path, [j["origin"] for j in batch], pattern, chunk=chunk, progress=progress)
        for j, (sub, scan) in zip(batch, scans):
            sub.origin = np.asarray(j["origin"], float)
            entry = {"file": Path(j["path"]).name, "position": j["position"], "height": j["height"],
                     "origin": list(j["origin"]), "points": len(scan)}
            done(_write_job(j, sub, entry, t0))


def _run_serial(jobs, cloud, done) -> None:
    """The jobs in this process, each file written by a thread while the next
    scan runs (at most one write pending, so at most two scans in memory).
    ``done(entry)`` is called in job order; an interruption still waits for the
    pending write, which is complete or absent, and records it."""
    with ThreadPoolExecutor(1) as writer:
        pending = None
        try:
            for j in jobs:
                scanned = _scan_job(j, cloud)
                if pending is not None:
                    entry, pending = pending.result(), None
                    done(entry)
                pending = writer.submit(_write_job, j, *scanned)
            if pending is not None:
                entry, pending = pending.result(), None
                done(entry)
        finally:
            if pending is not None and pending.exception() is None:
                done(pending.result())


def _scan_on_dask(job, cloud):
    return _scan_one(job, cloud)


@dataclass
class AugmentConfig:
    """What :func:`augment` makes, and how it runs.

    What the scans are (a rerun into the same directory resumes only when
    these agree: ``n`` may grow, the rest must be equal):

    n : int
        Positions to draw (the grid method, :func:`~slr_ray.positions.select_positions`);
        fewer is an error unless ``allow_fewer``.
    resolution : float
        Degrees between pulses, both axes, of the uniform pattern (default
        the paper's 0.036). Not used with ``sensor``.
    sensor : str, optional
        A shipped sensor's beam table (:data:`slr_ray.sensors.SENSORS`)
        instead of a uniform ``resolution``.
    heights : sequence of float, optional
        Scanner heights above the local ground, one scan each per position
        (default: ``scanner_height`` alone).
    scanner_height : float
        The height the positions are drawn at (m above the ground; the
        paper's 1.65), and the default scan height.
    backend : {'binning', 'embree'}
    backend_options : dict
        Fields of the backend's options class
        (:class:`~slr_ray.backends.BinningOptions`, :class:`~slr_ray.backends.EmbreeOptions`);
        checked, and resolved once, by :meth:`check`.
    fmt : str, optional
        Output extension, e.g. ``'.laz'`` (default: the input's).
    seed : int
        Seed of the position draw: the same seed, the same positions.
    min_ground_points : int
        Ground points a position needs within 5 m (the paper's 200,000 for
        0.036 deg scans).
    allow_fewer : bool
        Accept fewer than ``n`` positions when cells run out, with a warning
        naming both counts (default False: an error, as
        :func:`~slr_ray.positions.select_positions` has it).
    effects : Effects or dict, optional
        Sensor effects of every scan (:class:`~slr_ray.effects.Effects`;
        default none, the ideal scans). Each scan draws from its own seed,
        derived from ``effects.seed``, its position and its height, so a
        resumed run makes the same files. Not with ``chunk_size``.

    How it runs (free to change between a run and its resume):

    workers : int, optional
        Local worker processes (default all cores; 1 runs in this process).
        Each gets ``cores // workers`` threads unless ``backend_options``
        sets ``n_threads``.
    scheduler : str, optional
        Address of a ``dask.distributed`` scheduler to run the scans on.
    chunk_size : int, optional
        Stream a LAS/LAZ input ``chunk_size`` points at a time instead of
        reading it whole (clouds larger than memory; binning, uniform
        patterns): positions from the ground points and one point per cell
        (:func:`slr_ray.streaming.las_positions`, two passes), then
        ``per_pass`` scans per pass over the file
        (:func:`slr_ray.streaming.scan_las_many`).
        The same positions and files as a whole read, in memory of a chunk,
        the ground points and ``per_pass`` scans; runs in this process
        (``workers`` is not used, ``scheduler`` is refused).
    per_pass : int
        Positions reduced together in one pass over a streamed file.
    """

    n: int
    resolution: float = SECONDARY_RESOLUTION
    sensor: str | None = None
    heights: tuple | None = None
    scanner_height: float = SCANNER_HEIGHT
    backend: str = "binning"
    backend_options: dict = field(default_factory=dict)
    fmt: str | None = None
    seed: int = 0
    min_ground_points: int = MIN_GROUND_POINTS
    allow_fewer: bool = False
    effects: object = None
    workers: int | None = None
    scheduler: str | None = None
    chunk_size: int | None = None
    per_pass: int = 8

    def with_(self, **changes) -> "AugmentConfig":
        """A copy with ``changes``."""
        return dataclasses.replace(self, **changes)

    @property
    def scan_heights(self) -> tuple:
        """The heights scanned at each position (``heights``, else ``scanner_height``)."""
        return tuple(float(h) for h in (self.heights if self.heights is not None else (self.scanner_height,)))

    def check(self):
        """Raise :class:`~slr_ray.errors.InputValueError` on a bad field; return
        ``(pattern, options)``: the scan pattern and the backend's options object,
        each built once (:meth:`settings` also gives the resolved effects)."""
        return self.settings()[:2]

    def settings(self) -> tuple:
        """:meth:`check`, and ``(pattern, options, effects)``: the effects resolved once
        for the pattern (:meth:`effects_for`), which every scan then runs with."""
        if not (isinstance(self.n, (int, np.integer)) and self.n >= 1):
            raise InputValueError(f"n must be an integer >= 1, got {self.n!r}")
        heights = self.scan_heights
        if not heights or not all(np.isfinite(heights)) or min(heights) <= 0:
            raise InputValueError(f"heights must be finite numbers > 0, got {list(heights)}",
                                  flags={"heights must": "--heights must"})
        repeated = sorted({h for h in heights if heights.count(h) > 1})
        if repeated:
            raise InputValueError(f"heights repeat {repeated}: each height is one scan per position",
                                  flags={"heights repeat": "--heights repeats"})
        if not (np.isfinite(self.scanner_height) and self.scanner_height > 0):
            raise InputValueError(f"scanner_height must be a finite number > 0, got {self.scanner_height!r}")
        if self.chunk_size is not None and (int(self.chunk_size) != self.chunk_size or self.chunk_size < 1
                                            or int(self.per_pass) != self.per_pass or self.per_pass < 1):
            raise InputValueError(f"chunk_size and per_pass must be integers >= 1, got {self.chunk_size!r}, "
                                  f"{self.per_pass!r}")
        pattern = as_pattern(self.sensor) if self.sensor else ScanPattern(self.resolution)
        options = options_for(self.backend, self.backend_options or None)
        if self.chunk_size is not None:
            require_streamable(scanner_class(self.backend), pattern, "a streamed augment (chunk_size)")
            if self.scheduler:
                raise InputValueError("a streamed augment runs in this process: chunk_size or scheduler, not both")
        return pattern, options, self.effects_for(pattern)

    def effects_for(self, pattern) -> Effects | None:
        """The scans' effects, their 'sensor' values read from ``pattern``; None
        when none is on. Raises :class:`~slr_ray.errors.InputValueError` on
        effects this run cannot make."""
        if self.effects is None:
            return None
        eff = (self.effects if isinstance(self.effects, Effects) else Effects.from_dict(self.effects)).check_needs()
        if not eff.any:
            return None
        if eff.motion:
            raise InputValueError("augment's scans stand still: effects with motion need poses "
                                  "(slr_ray.effects.simulate)")
        if eff.divergence_mrad:
            require_rays(scanner_class(self.backend), "beam divergence (divergence_mrad)")
        if self.chunk_size is not None:
            raise InputValueError("a streamed augment (chunk_size) makes ideal scans: no effects")
        return eff.resolve(pattern)


def _scan_seed(seed: int, position: int, height: int) -> int:
    """The effects' seed of one scan: its own stream, the same on every run."""
    return int(np.random.SeedSequence([int(seed) % 2**63, position, height]).generate_state(1, np.uint64)[0] >> 1)


def _scan_name(i: int, h: float, ext: str) -> str:
    return f"scan_{i:04d}_h{h:g}{ext}"


def augment(input_path, outdir, config: AugmentConfig, *, ground=None, progress: bool = True,
            reads=(), force: bool = False) -> dict:
    """Write ``config.n`` positions x heights SLR scans of ``input_path`` into ``outdir``.

    Parameters
    ----------
    input_path : path
        The cloud (any format :func:`~slr_ray.io.read_cloud` reads; LAS/LAZ
        can be streamed, ``config.chunk_size``).
    outdir : path
        Created if missing, and locked while the run writes there (a second
        run into it is refused). A fresh run goes into a new or empty
        directory: one holding files of no augment run is refused, naming a
        few, unless ``force`` (then it writes among them, never over one). A
        rerun with the same settings and the same
        input *content* (:func:`~slr_ray.outputs.content_digest`) resumes;
        anything else is refused with the differences named. A run that
        fails before its first scan leaves nothing behind.
    config : AugmentConfig
    ground : (n,) bool or dict, optional
        Ground labels, or keywords of :func:`~slr_ray.positions.ground_labels`
        (``attribute``, ``value``, ``csf``, ``cloth_resolution``) to label the
        input once it is read; default the input's (``is_ground``, LAS class
        2, ``label`` 0), else found by CSF, with a note saying so
        (:func:`~slr_ray.positions.ground_labels`). A streamed input
        (``chunk_size``) must have labels, or be given them.
    progress : bool
        A progress bar on stderr.
    reads : iterable of paths (None skipped)
        Other files the caller read the settings from (an effects file, a
        ray-drop model): planned as inputs, so that no file of the run
        (its manifest included) may be one of them.
    force : bool
        Write a fresh run into a directory of other files (never over one).

    Returns
    -------
    dict
        The manifest.
    """
    pattern, options, effects = config.settings()  # bad settings fail before any work or file
    if config.scheduler:
        if importlib.util.find_spec("dask") is None or importlib.util.find_spec("dask.distributed") is None:
            raise MissingDependencyError('augment on a scheduler needs dask: pip install "slr_ray[dask]"')
    input_path = Path(input_path)
    heights = config.scan_heights
    ext = check_format(input_path, config.fmt)
    if config.chunk_size is not None and input_path.suffix.lower() not in STREAMED_FORMATS:
        raise InputValueError(f"chunk_size streams {'/'.join(STREAMED_FORMATS)} inputs, not {input_path.suffix!r}")
    plan = OutputPlan()
    plan.read(input_path)
    for path in reads:
        plan.read(path, sidecars=False)  # settings files: nothing is read beside them
    out = plan.directory(outdir)  # absolute before any path is sent to a worker or a cluster
    refuse_memory(1024.0 * config.n * len(heights), f"an augment of {config.n:,} x {len(heights)} scans "
                  "(about 1 KB a scan: its file plan and manifest)", "ask for fewer scans a run")
    names = [_scan_name(i, h, ext) for i in range(config.n) for h in heights]
    for name in names:
        plan.write(out / name, fmt=ext, resumed=True)
    plan.write(out / MANIFEST, resumed=True)
    plan.write(out / JOURNAL, resumed=True)
    with plan:
        return _augment(input_path, out, config, ground, _Run(pattern, options, effects, ext, names, progress, force))


class _Run(NamedTuple):
    """What :func:`augment` settled before its directory was locked."""

    pattern: object
    options: object
    effects: Effects | None
    ext: str
    names: list
    progress: bool
    force: bool


def share_threads(jobs: list, options, backend_options: dict, n_workers: int) -> list:
    """The jobs of ``n_workers`` processes, the cores shared out between them through
    ``n_threads`` (W processes of W-fold threads on the same cores only contend; results
    do not depend on it): unless the user set it, and only for a backend whose options
    (``options``, typed) have the field."""
    if "n_threads" in backend_options or not hasattr(options, "n_threads"):
        return jobs
    per = max(1, (os.cpu_count() or 1) // n_workers)
    return [{**j, "options": {**j["options"], "n_threads": per}} for j in jobs]


def _augment(input_path, out, config, ground, run: _Run) -> dict:
    """:func:`augment` in its locked directory."""
    pattern, options, effects, ext, names, progress, force = run
    backend_options = dict(config.backend_options or {})
    settings = _settings(input_path, config, ground, run)
    # what is in the directory is checked before the long steps (CSF takes minutes on an airborne tile)
    manifest_path = out / MANIFEST
    fresh = not manifest_path.exists()
    if not fresh:
        old = same_settings(manifest_path, settings, out)
    else:
        refuse_strangers(out, names, ext, force)
    cloud, positions, cells = _positions(input_path, config, ground, effects, progress)
    backend_options = primary_from_cloud(cloud, config.backend, backend_options, input_path)  # as `scan` does
    require_positions(positions, config.n, cells, input_path)  # allow_fewer is fewer, not none
    done = {} if fresh else resumable(old, positions, out)
    if not os.access(out, os.W_OK):
        raise PermissionError(f"cannot write to {out}")
    jobs = _jobs(positions, done, out, config, run, backend_options)
    if not fresh:  # an extension or a resume writes only names no run recorded: any file there is another's
        refuse_theirs(jobs, out, ext)
    manifest = _manifest(settings, input_path, config, pattern, positions, cells, done, backend_options)

    journal = out / JOURNAL
    last_write = [0.0]

    def write_manifest():
        manifest["scans"].sort(key=lambda s: s["file"])
        with atomic_path(manifest_path) as tmp:
            tmp.write_text(json.dumps(manifest, indent=1))
        last_write[0] = time.perf_counter()

    def record(entry):
        # one line appended per scan; the manifest itself is rewritten at most every
        # MANIFEST_EVERY seconds (rewriting it after each of thousands of scans is quadratic)
        entry = {**entry, "done": round(time.perf_counter() - record_start, 3)}  # seconds into this run
        manifest["scans"].append(entry)
        append_journal(journal, entry)
        if time.perf_counter() - last_write[0] > MANIFEST_EVERY:
            write_manifest()
        return entry

    write_manifest()
    record_start = time.perf_counter()
    bar = progress_bar(total=len(jobs), desc="augment", unit="scan", leave=True) if progress else None
    told = _Told(out, ext)

    def done_one(entry):
        # recorded, then published: a scan under its final name is always one the journal lists (an
        # interruption between the two leaves a recorded scan whose file is absent: it is made again)
        staged = entry.pop("_staged")
        told.add(entry.pop("_warnings", ()), staged[-1][1])  # said once each at the end
        entry = record(entry)
        try:
            _publish(staged, ext)
        except OutputError:
            manifest["scans"].remove(entry)
            with open(journal, "a") as f:
                f.write(json.dumps({"file": entry["file"], "withdrawn": True}) + "\n")
            raise
        if bar is not None:
            bar.update()

    failed = False  # an error (exit 2), not an interruption (which keeps what it made, to resume)
    complete = False
    try:
        _run_jobs(jobs, cloud, input_path, config, run, backend_options, done_one)
        complete = True
    except Exception:
        failed = True
        raise
    finally:
        if bar is not None:
            bar.close()
        told.say()
        _clean_up(failed and fresh and not manifest["scans"], complete, jobs, manifest_path, journal, write_manifest)
    journal.unlink(missing_ok=True)
    manifest["seconds"] = round(time.perf_counter() - record_start, 3)
    manifest["new_scans"] = len(jobs)
    return manifest


def _settings(input_path, config, ground, run: _Run) -> dict:
    """The settings a manifest records (a resume must find them the same)."""
    pattern, options, effects, ext = run.pattern, run.options, run.effects, run.ext
    heights, backend = config.scan_heights, config.backend
    ground_setting = "from the input" if ground is None else dict(ground) if isinstance(ground, dict) else "given"
    settings = {"input": str(input_path.resolve()), "input_bytes": input_path.stat().st_size,
                "input_digest": content_digest(input_path), "seed": config.seed,
                "pattern": pattern.to_dict(), "backend": backend, "backend_options": options.to_dict(),
                "min_ground_points": config.min_ground_points, "format": ext, "heights": list(heights),
                "ground": ground_setting}
    if effects is not None:  # only then: a manifest without effects resumes as before
        settings["effects"] = effects.to_dict()
    return settings


def _positions(input_path, config, ground, effects, progress) -> tuple:
    """``(cloud, positions, cells)``: the input (None when streamed) and the positions drawn on its ground."""
    if isinstance(ground, dict) and config.chunk_size is not None:  # labels (CSF) need the whole cloud
        ground = ground_labels(read_cloud(input_path, allow_empty=False), **ground, progress=progress)
    if config.chunk_size is not None:
        cloud = None
        positions, cells, _ = las_positions(input_path, config.n, seed=config.seed, ground=ground,
                                            chunk=int(config.chunk_size), min_ground_points=config.min_ground_points,
                                            allow_fewer=config.allow_fewer, scanner_height=config.scanner_height,
                                            progress=progress)
    else:
        cloud = read_cloud(input_path, allow_empty=False)
        if effects is not None and effects.intensity == "correct" and cloud.origin is None:  # before CSF
            raise InputValueError(f"intensity='correct' needs where {input_path} was scanned from, and it records "
                                  "no scanner origin (use intensity='carry')",
                                  flags={"intensity='correct'": "--intensity correct",
                                         "intensity='carry'": "--intensity carry"})
        if ground is None or isinstance(ground, dict):
            ground = ground_labels(cloud, **(ground or {}), progress=progress)
        positions, cells = select_positions(cloud.points, ground, config.n, seed=config.seed,
                                            min_ground_points=config.min_ground_points,
                                            scanner_height=config.scanner_height,
                                            allow_fewer=config.allow_fewer, return_cells=True)
    return cloud, positions, cells


def _jobs(positions, done, out, config, run: _Run, backend_options) -> list:
    """A job a scan not yet done: its path, position, height, origin, pattern, backend and effects."""
    pattern, effects, ext, heights, backend = run.pattern, run.effects, run.ext, config.scan_heights, config.backend
    jobs = []
    for i, p in enumerate(positions):
        ground_z = p[2] - config.scanner_height  # select_positions puts them scanner_height above ground
        for k, h in enumerate(heights):
            name = _scan_name(i, h, ext)
            if name in done:
                continue
            jobs.append({"path": str(out / name), "position": i, "height": float(h),
                         "origin": [float(p[0]), float(p[1]), float(ground_z + h)],
                         "pattern": pattern.to_dict(), "sensor": config.sensor, "backend": backend,
                         "options": backend_options,
                         "effects": None if effects is None else effects.with_seed(_scan_seed(effects.seed, i, k))})
    return jobs


def _run_jobs(jobs, cloud, input_path, config, run: _Run, backend_options, done_one) -> None:
    """Every job run (streamed, on a dask scheduler, in worker processes or here), ``done_one`` called on each scan."""
    pattern, options, progress = run.pattern, run.options, run.progress
    if cloud is None:  # streamed
        _run_streamed(jobs, input_path, pattern, int(config.chunk_size), int(config.per_pass), done_one,
                      progress)
    elif config.scheduler:
        from dask.distributed import Client, as_completed

        with Client(config.scheduler) as client:
            shared = client.scatter(cloud, broadcast=True)  # once, not once per task
            futures = [client.submit(_scan_on_dask, j, shared, pure=False) for j in jobs]
            for fut in as_completed(futures):
                done_one(fut.result())
    elif (config.workers or os.cpu_count() or 1) > 1 and len(jobs) > 1:
        n_workers = min(len(jobs), config.workers or os.cpu_count() or 1)
        jobs = share_threads(jobs, options, backend_options, n_workers)
        # spawn, not fork: a forked child inherits the parent's thread pools
        # (numba's, the binning backend's) in whatever state they were and can hang.
        # multiprocessing.Pool, not ProcessPoolExecutor: on an interrupt (SIGINT, or
        # SIGTERM turned into one by the CLI) its exit terminates the workers at once
        # instead of running every queued scan first.
        ctx = _WorkerContext()
        with ctx.Pool(n_workers, initializer=_init_worker,
                      initargs=(cloud.points, cloud.attributes, cloud.origin, cloud.meta)) as pool:
            for entry in pool.imap(_scan_one, jobs):
                done_one(entry)
    else:
        _run_serial(jobs, cloud, done_one)


def _manifest(settings, input_path, config, pattern, positions, cells, done, backend_options) -> dict:
    """The manifest of a run, before its new scans: the settings, the positions and the scans done,
    and what the input added to the backend's options (its primary, as `scan` takes it: the settings
    hold the options as given, which with the input's digest decide it; this says what ran)."""
    given = config.backend_options or {}
    return {"software": f"slr_ray {__version__}", "settings": settings, "input": str(input_path),
            "n_requested": config.n, "seed": config.seed, "pattern": pattern.to_dict(), "backend": config.backend,
            "heights": list(config.scan_heights), "effects": settings.get("effects"),
            "positions": positions.tolist(), "stages": cells.stages, "scans": list(done.values()),
            "backend_options_from_input": {k: v for k, v in backend_options.items() if k not in given}}


def _clean_up(nothing_recorded, complete, jobs, manifest_path, journal, write_manifest) -> None:
    """After the scans: a fresh run that failed before recording any leaves nothing; else the
    temporaries of an interrupted run go and the manifest lists every scan written."""
    if nothing_recorded:
        # an error before any scan was recorded: leave nothing (none of these files existed before
        # this run; the plan then removes the directory if it created it)
        _remove_temporaries(jobs)  # no scan was published (each is recorded first): only staged files
        manifest_path.unlink(missing_ok=True)
        journal.unlink(missing_ok=True)
    else:
        if not complete:  # scans staged but never published (an interruption)
            _remove_temporaries(jobs)
        write_manifest()  # complete or interrupted: the manifest lists every scan written
