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

import json
import multiprocessing
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from tqdm import tqdm

from . import __version__
from .backends import options_for, prepare
from .errors import InputValueError, MissingDependencyError
from .io import PointCloud, atomic_path, check_format, read_cloud, write_cloud
from .paper import MIN_GROUND_POINTS, SCANNER_HEIGHT, SECONDARY_RESOLUTION
from .pattern import ScanPattern, as_pattern
from .positions import ground_labels, select_positions
from .streaming import STREAMED_FORMATS, las_positions, scan_las_many

__all__ = ["augment"]

_WORKER = {}


#: Scans finished since the manifest was last written, one JSON line each (removed when a run completes).
JOURNAL = "manifest.scans.jsonl"
#: Seconds between rewrites of manifest.json during a run.
MANIFEST_EVERY = 10.0


def _resumable(manifest_path: Path, settings: dict, positions, out: Path) -> dict:
    """The scans of an earlier run into ``out`` that this run may keep.

    A run resumes only one with the same settings (input, seed, pattern,
    backend and options, ground threshold, format) whose positions agree with
    this run's as far as both go (a run for more positions extends one for
    fewer). Anything else is refused with the differences named: a rerun with
    other settings never mixes its scans with the old ones.
    """
    try:
        old = json.loads(manifest_path.read_text())
    except ValueError:
        raise InputValueError(f"{manifest_path} is not a manifest slr_ray can read: write elsewhere") from None
    before = old.get("settings")
    if before is None:
        raise InputValueError(f"{manifest_path} was written by an older slr_ray without its settings: "
                              "write elsewhere (or remove the directory)")
    diff = [f"{k}: {before.get(k)!r} -> {v!r}" for k, v in settings.items() if before.get(k) != v]
    k = min(len(positions), len(old.get("positions", [])))
    if not np.array_equal(np.asarray(old.get("positions", []))[:k].reshape(-1, 3), positions[:k]):
        diff.append("positions differ")
    if diff:
        raise InputValueError(f"{out} holds a run with other settings ({'; '.join(diff)}): "
                              "write elsewhere, or remove it to start again")
    scans = {s["file"]: s for s in old.get("scans", [])}
    journal = out / JOURNAL
    if journal.exists():  # scans recorded since the manifest was last written (an interrupted run)
        for line in journal.read_text().splitlines():
            try:
                entry = json.loads(line)
            except ValueError:
                continue  # a line cut short by the interruption
            scans[entry["file"]] = entry
    return {k: v for k, v in scans.items() if (out / k).exists()}


def _init_worker(points, attributes, origin, meta):
    _WORKER["cloud"] = PointCloud(points, attributes, origin, meta)


def _remove_temporaries(jobs) -> None:
    """Temporary files of ``jobs`` left by workers killed mid-write (the pool
    terminates its workers with SIGTERM, which no worker code outlives)."""
    for job in jobs:
        path = Path(job["path"])
        for tmp in path.parent.glob(f".{path.name}.*.part*"):
            tmp.unlink(missing_ok=True)


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
    scan = _scanner(cloud, job["backend"], job["options"]).scan(job["origin"], pattern)
    sub = cloud.subset(scan.indices)
    sub.origin = np.asarray(job["origin"], float)
    entry = {"file": Path(job["path"]).name, "position": job["position"], "height": job["height"],
             "origin": list(job["origin"]), "points": len(scan)}
    return sub, entry, t0


def _write_job(job, sub, entry, t0):
    """Write a job's scan (atomic: a temporary file renamed into place); its manifest entry."""
    write_cloud(Path(job["path"]), sub)
    return {**entry, "seconds": round(time.perf_counter() - t0, 4)}


def _scan_one(job, cloud=None):
    """One SLR scan written to ``job['path']``; returns its manifest entry."""
    return _write_job(job, *_scan_job(job, cloud if cloud is not None else _WORKER["cloud"]))


def _run_streamed(jobs, path, pattern, chunk, per_pass, done, progress=False) -> None:
    """The jobs on a LAS/LAZ file read in chunks, ``per_pass`` positions per two
    passes over it; ``done(entry)`` in job order."""
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


def augment(input_path, outdir, n: int, *, backend: str = "binning", resolution: float = SECONDARY_RESOLUTION,
            heights=(SCANNER_HEIGHT,), fmt: str | None = None, seed: int = 0,
            min_ground_points: int = MIN_GROUND_POINTS,
            ground=None, origin=None, workers: int | None = None, scheduler: str | None = None,
            progress: bool = True, backend_options: dict | None = None, allow_fewer: bool = True,
            sensor: str | None = None, chunk_size: int | None = None, per_pass: int = 8) -> dict:
    """Write ``n`` positions x ``heights`` SLR scans of ``input_path`` into ``outdir``.

    Parameters
    ----------
    ground : (n,) bool, optional
        Ground labels; default from the input (:func:`~slr_ray.positions.ground_labels`:
        ``is_ground``, LAS class 2), which must have some (use
        :func:`slr_ray.label_ground` otherwise).
    heights : sequence of float
        Scanner heights above the local ground.
    sensor : str, optional
        A shipped sensor's beam table (:data:`slr_ray.sensors.SENSORS`) instead
        of a uniform ``resolution``.
    fmt : str, optional
        Output extension (default the input's).
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
        (:func:`slr_ray.streaming.las_positions`), then ``per_pass`` scans per
        two passes over the file (:func:`slr_ray.streaming.scan_las_many`).
        The same positions and files as a whole read, in memory of a chunk,
        the ground points and ``per_pass`` scans; runs in this process
        (``workers`` is not used, ``scheduler`` is refused).
    per_pass : int
        Positions reduced together in one pass over a streamed file.

    Returns
    -------
    dict
        The manifest.
    """
    options_for(backend, backend_options)  # bad options fail before any work
    if scheduler:
        try:
            import dask.distributed  # noqa: F401
        except ImportError:
            raise MissingDependencyError('augment on a scheduler needs dask: pip install "slr_ray[dask]"') from None
    input_path = Path(input_path)
    out = Path(outdir).resolve()  # absolute before any path is sent to a worker or a cluster
    heights = tuple(float(h) for h in heights)
    repeated = sorted({h for h in heights if heights.count(h) > 1})
    if repeated:
        raise InputValueError(f"heights repeat {repeated}: each height is one scan per position")
    ext = check_format(input_path, fmt)
    ground_given = ground is not None
    pattern = as_pattern(sensor) if sensor else ScanPattern(resolution)
    if chunk_size is not None:
        if input_path.suffix.lower() not in STREAMED_FORMATS:
            raise InputValueError(f"chunk_size streams {'/'.join(STREAMED_FORMATS)} inputs, not {input_path.suffix!r}")
        if backend != "binning" or not pattern.streamable:
            raise InputValueError("a streamed augment runs the binning backend with a uniform pattern")
        if scheduler:
            raise InputValueError("a streamed augment runs in this process: chunk_size or scheduler, not both")
        if int(chunk_size) != chunk_size or chunk_size < 1 or int(per_pass) != per_pass or per_pass < 1:
            raise InputValueError(f"chunk_size and per_pass must be integers >= 1, got {chunk_size!r}, {per_pass!r}")
        cloud = None
        positions, cells, _ = las_positions(input_path, n, seed=seed, ground=ground, chunk=int(chunk_size),
                                            min_ground_points=min_ground_points, allow_fewer=allow_fewer,
                                            progress=progress)
    else:
        cloud = read_cloud(input_path)  # check everything before creating anything
        if ground is None:
            ground = ground_labels(cloud)
        positions, cells = select_positions(cloud.points, ground, n, seed=seed, min_ground_points=min_ground_points,
                                            allow_fewer=allow_fewer, return_cells=True)
    settings = {"input": str(input_path.resolve()), "input_bytes": input_path.stat().st_size, "seed": seed,
                "pattern": pattern.to_dict(), "backend": backend,
                "backend_options": options_for(backend, backend_options).to_dict(),
                "min_ground_points": min_ground_points, "format": ext, "heights": list(heights),
                "ground": "given" if ground_given else "from the input"}
    manifest_path = out / "manifest.json"
    done = {}
    if manifest_path.exists():
        done = _resumable(manifest_path, settings, positions, out)
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise PermissionError(f"cannot write to {out}")
    jobs = []
    for i, p in enumerate(positions):
        ground_z = p[2] - SCANNER_HEIGHT  # select_positions puts them SCANNER_HEIGHT above ground
        for h in heights:
            name = f"scan_{i:04d}_h{h:g}{ext}"
            if name in done:
                continue
            jobs.append({"path": str(out / name), "position": i, "height": float(h),
                         "origin": [float(p[0]), float(p[1]), float(ground_z + h)],
                         "pattern": pattern.to_dict(), "sensor": sensor, "backend": backend,
                         "options": backend_options or {}})
    manifest = {"software": f"slr_ray {__version__}", "settings": settings, "input": str(input_path),
                "n_requested": n, "seed": seed, "pattern": pattern.to_dict(), "backend": backend,
                "heights": list(heights),
                "positions": positions.tolist(), "stages": cells.stages, "scans": list(done.values())}

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
        with open(journal, "a") as f:
            f.write(json.dumps(entry) + "\n")
        if time.perf_counter() - last_write[0] > MANIFEST_EVERY:
            write_manifest()

    write_manifest()
    record_start = time.perf_counter()
    bar = None
    if progress:
        bar = tqdm(total=len(jobs), unit="scan", desc="augment")
    try:
        if cloud is None:  # streamed
            def done(entry):
                record(entry)
                if bar is not None:
                    bar.update()

            _run_streamed(jobs, input_path, pattern, int(chunk_size), int(per_pass), done, progress)
        elif scheduler:
            from dask.distributed import Client, as_completed

            with Client(scheduler) as client:
                shared = client.scatter(cloud, broadcast=True)  # once, not once per task
                futures = [client.submit(_scan_on_dask, j, shared, pure=False) for j in jobs]
                for fut in as_completed(futures):
                    record(fut.result())
                    if bar is not None:
                        bar.update()
        elif (workers or os.cpu_count() or 1) > 1 and len(jobs) > 1:
            n_workers = min(len(jobs), workers or os.cpu_count() or 1)
            if "n_threads" not in (backend_options or {}):
                # the cores shared out between the workers: W processes of W-fold
                # threads on the same cores only contend (results do not depend on it)
                per = max(1, (os.cpu_count() or 1) // n_workers)
                for j in jobs:
                    j["options"] = {**j["options"], "n_threads": per}
            # spawn, not fork: a forked child inherits the parent's thread pools
            # (numba's, the binning backend's) in whatever state they were and can hang.
            # multiprocessing.Pool, not ProcessPoolExecutor: on an interrupt (SIGINT, or
            # SIGTERM turned into one by the CLI) its exit terminates the workers at once
            # instead of running every queued scan first.
            ctx = multiprocessing.get_context("spawn")
            try:
                with ctx.Pool(n_workers, initializer=_init_worker,
                              initargs=(cloud.points, cloud.attributes, cloud.origin, cloud.meta)) as pool:
                    for entry in pool.imap(_scan_one, jobs):
                        record(entry)
                        if bar is not None:
                            bar.update()
            except BaseException:
                _remove_temporaries(jobs)
                raise
        else:
            def done(entry):
                record(entry)
                if bar is not None:
                    bar.update()

            _run_serial(jobs, cloud, done)
    finally:
        if bar is not None:
            bar.close()
        write_manifest()  # complete or interrupted: the manifest lists every scan written
    journal.unlink(missing_ok=True)
    manifest["seconds"] = round(time.perf_counter() - record_start, 3)
    manifest["new_scans"] = len(jobs)
    return manifest
