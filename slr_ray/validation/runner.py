"""Running (or resuming) a validation: primaries, positions, pairs.

For each scene of a config: the scene's primary scan from the origin, the
secondary positions drawn on it (the paper's grid method), and at each
position the true scan (one per truth semantics) and the SLR scan of the
primary (one per backend), compared by :func:`~slr_ray.metrics.agreement`
(coverage, the paper's similarity, with precision and F-score). The same
config and seed give the same rows.
"""

from __future__ import annotations

import math
import shutil
import time
from dataclasses import asdict
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..backends import Backend, prepare, scanner_class
from ..io import atomic_path
from ..meshscan import scan_mesh
from ..io.outputs import OutputPlan
from ..pattern import ScanPattern
from ..positions import select_positions
from ..scenes import scene_from_spec
from ..metrics import agreement
from .config import ValidationConfig
from .planning import ScenePlan, load_positions, plan, positions_file, positions_tag
from .report import headline
from ..progress import bar as progress_bar
from .results import ResultsWriter, StageLog, check_settings, peak_rss_gib, read_rows, row_key
from .truths import TruthCache

__all__ = ["run_validation", "PAPER_BACKEND", "PAPER_TRUTH", "spill_primary", "available_memory"]

#: the paper's own rows: its subsampling (binning) against its truth (the pulse-centre scan)
PAPER_BACKEND = Backend.BINNING
PAPER_TRUTH = "center"

#: bytes a point the embree backend holds beyond the float64 points (16 vertex + 12 normal
#: + 33 Embree BVH, which is its builder's 32-byte PrimRef array kept as the tree's storage;
#: measured on 5 M discs and in benchmarks/bench_validation_memory.py) and the transients
#: of its preparation
EMBREE_BYTES_PER_POINT = 67
#: a primary of this many points or more is memory-mapped before its discs are built, fitting
#: or not: its pages are then file cache the kernel can drop, not 24 B a point of the process's
#: own memory (rect-1000's 0.00576 deg primary: 4.7 GB of 209 M points)
MAPPED_PRIMARY_POINTS = 10_000_000
#: share of the available memory a primary and its discs may take before the points are
#: moved to a memory-mapped file
_MEMORY_SHARE = 0.85


def available_memory() -> float:
    """Bytes of memory available to new allocations (``MemAvailable`` of
    /proc/meminfo); infinite where it cannot be read."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return math.inf


def spill_primary(primary: np.ndarray, folder: Path, extra_bytes_per_point: float,
                  available: float | None = None) -> np.ndarray:
    """``primary``, or the same points memory-mapped from a file: when it has
    :data:`MAPPED_PRIMARY_POINTS` points or more, or when they and
    ``extra_bytes_per_point`` (what will be built on them: the embree
    backend's discs) would take more than 85 % of the available memory.

    A memory-mapped primary lets the kernel drop its pages under pressure and
    read them back when needed (a scan then costs more, it does not fail):
    rect-2000's 0.00576 deg primary is 253 M points, 6.1 GB, with ~17 GB of
    discs on a 24 GB machine. Mapped, the points are file pages: the
    embree backend releases them before Embree's build
    (:func:`~slr_ray.arrays.release_pages`), and a binning scan releases
    each chunk it has read, so neither counts them in the process's memory
    while it allocates its own. The file is unlinked as soon as it is mapped,
    so nothing is left behind, even when the run is killed. The caller must
    drop its own reference to the in-memory array.
    """
    n = len(primary)
    avail = available_memory() if available is None else available
    fits = primary.nbytes + n * extra_bytes_per_point <= _MEMORY_SHARE * (avail + primary.nbytes)
    if n < MAPPED_PRIMARY_POINTS and fits:
        return primary
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f".primary-{time.time_ns()}.npy"
    try:
        np.save(path, primary)
        mapped = np.load(path, mmap_mode="r")
    finally:
        path.unlink(missing_ok=True)
    return mapped


def run_validation(config: ValidationConfig, outdir, progress: bool = True, then=None) -> dict:
    """Run (or resume) a validation; returns a summary.

    Writes ``outdir/results.csv`` (a row per pair, appended as made; see
    :mod:`slr_ray.validation.results`), ``outdir/positions/<scene>.csv`` (the
    drawn positions), ``outdir/stages.csv`` (seconds and peak memory of
    every primary scan, position draw, disc preparation and position loop)
    and ``outdir/settings.json`` (the settings its rows depend on: a resume
    with other values raises :class:`~slr_ray.errors.InputValueError`).
    ``outdir`` is locked while the run writes there: a second run into it is
    refused (:class:`~slr_ray.errors.OutputError`). ``then(outdir, summary)``,
    if given, runs once the rows are in, still under the lock: what is made
    from the rows (the command's reports and figures) is never written beside
    another run's rows.
    """
    config.check()
    plan = OutputPlan()  # resumable files; the directory locked while this run writes
    out = plan.directory(outdir)
    for name in ("results.csv", "stages.csv", "settings.json"):
        plan.write(out / name, resumed=True)
    for entry in config.scenes:
        spec = config.scene_entry(entry)[0]
        if Path(spec).suffix:  # a path (any extension), not a shipped name
            plan.read(spec, sidecars=False)
    own = [out / n for n in ("results.csv", "stages.csv", "settings.json", "positions")]
    fresh = not any(p.exists() for p in own)
    with plan:
        try:
            res = _run_validation(config, out, progress)
        except BaseException:
            if fresh and _no_rows(out / "results.csv"):  # failed before its first row: leave nothing
                for p in own:
                    if p.is_dir():
                        shutil.rmtree(p, ignore_errors=True)
                    else:
                        p.unlink(missing_ok=True)
            raise
        if then is not None:
            then(out, res)
        return res


def _no_rows(csv_path) -> bool:
    try:
        return not read_rows(csv_path)
    except Exception:  # unreadable: keep it, someone may want to look
        return False


def _run_validation(config: ValidationConfig, out: Path, progress: bool) -> dict:
    check_settings(out, config)
    csv_path = out / "results.csv"
    done = read_rows(csv_path)
    plans = plan(config, done)
    t_all = time.perf_counter()
    bar = None
    if progress:
        bar = progress_bar(total=sum(len(p.resolutions) for p in plans) * config.positions, desc=config.name,
                           unit="position", leave=True)
    n_new = 0
    try:
        with ResultsWriter(csv_path) as results, StageLog(out / "stages.csv") as stages:
            for p in plans:
                if p.done:
                    _advance(bar, config.positions * len(p.resolutions))
                    continue
                n_new += _run_scene(config, p, out, done, results, stages, bar)
            stages.add("(all)", "", "run", time.perf_counter() - t_all, n_new)
    finally:
        if bar is not None:
            bar.close()
    rows = list(read_rows(csv_path).values())
    return {"config": asdict(config), "csv": str(csv_path), "rows": len(rows), "new_rows": n_new,
            "seconds": round(time.perf_counter() - t_all, 2), "peak_rss_gib": round(peak_rss_gib(), 2),
            "headline": headline(rows)}


def _advance(bar, n):
    if bar is not None and n:
        bar.update(n)


def _run_scene(config, p: ScenePlan, out: Path, done, results, stages, bar) -> int:
    scene = scene_from_spec(p.spec)
    secondary = ScanPattern(config.secondary_resolution)
    pos_path = positions_file(out, p.spec)
    positions = load_positions(pos_path, config)
    truths = TruthCache(scene, secondary, config.nearest_supersample,
                        out / ".truths" / Path(p.spec).stem if len(p.resolutions) > 1 else None)
    n_new = 0
    for r_index, res in enumerate(p.passes()):
        wanted_here = res in p.resolutions
        if not p.todo.get(res) and (positions is not None or r_index > 0):
            _advance(bar, config.positions if wanted_here else 0)
            continue
        t0 = time.perf_counter()
        scan = scan_mesh(scene, [0, 0, 0], ScanPattern(res), mode=config.primary_semantics,
                         spacing=config.dense_spacing)
        # keep the points and the ground mask only: the scan's ranges, pulses and int64
        # labels are 32 of its 56 bytes a point (6.7 GB of a 0.00576 deg primary)
        primary, ground = scan.points, scan.labels == 0
        del scan
        stages.add(p.spec, res, "primary scan", time.perf_counter() - t0, len(primary))
        if positions is None:
            t0 = time.perf_counter()
            positions = select_positions(primary, ground, config.positions,
                                         seed=config.seed, min_ground_points=config.min_ground_points,
                                         allow_fewer=True)
            truths.clear()  # true scans of other positions
            pos_path.parent.mkdir(exist_ok=True)
            with atomic_path(pos_path) as tmp:
                np.savetxt(tmp, positions, delimiter=",", fmt="%.17g",
                           header=positions_tag(config, config.positions)[2:])
            stages.add(p.spec, res, "positions", time.perf_counter() - t0, len(positions))
        ground = None  # only the positions need it (1 B a point through the pairs otherwise)
        if wanted_here:
            # only when embree rows remain to be made (a resumed run whose discs are done does not spill)
            if any(scanner_class(b).costly_prepare and row_key(p.spec, res, i, b, t) not in done
                   for i in range(len(positions)) for b, t in config.wanted(res, i, p.backends)):
                t0 = time.perf_counter()
                spilled = spill_primary(primary, out, EMBREE_BYTES_PER_POINT)
                if spilled is not primary:
                    primary = spilled
                    stages.add(p.spec, res, "primary to a mapped file", time.perf_counter() - t0, len(primary))
                del spilled
            n_new += _pairs(config, p, _Primary(scene, res, primary, positions, secondary, truths), done, results,
                            stages, bar)
            _advance(bar, config.positions - len(positions))
        del primary, ground
    truths.clear()
    return n_new


class _Primary(NamedTuple):
    """One primary scan and what its rows are made from."""

    scene: object
    resolution: float
    points: np.ndarray
    positions: np.ndarray
    secondary: object
    truths: object


def _pairs(config, p: ScenePlan, primary_scan: _Primary, done, results, stages, bar) -> int:
    """The rows of one primary (its ``(n, 3)`` points): every wanted (backend, truth) at every position.

    Logs two stages: ``pairs`` (the paper's rows: binning against the
    pulse-centre truth) and ``extras`` (the nearest-in-pulse truth and the
    embree backend), each the seconds spent on its own true scans, SLR scans
    and comparisons, so the paper's part of a run is timed apart from what
    this project adds.
    """
    scene, res, primary, positions, secondary, truths = primary_scan
    scanners = {}
    spent = {"pairs": 0.0, "extras": 0.0}

    def part(backend, truth=None):
        return "pairs" if backend == PAPER_BACKEND and truth in (None, PAPER_TRUTH) else "extras"

    def scanner(backend):
        if backend not in scanners:
            t0 = time.perf_counter()
            # the primary was scanned from the origin at ``res``: footprint radii,
            # pulse-grid neighbours and degenerate normals use that
            options = {**scanner_class(backend).primary_options([0.0, 0.0, 0.0], res),
                       **config.backend_options.get(backend, {})} or None
            scanners[backend] = prepare(primary, backend, options)
            scanners[backend].release_mapped = True  # a spilled primary's pages: not kept beside the discs
            if scanner_class(backend).costly_prepare:
                stages.add(p.spec, res, f"{backend} discs", time.perf_counter() - t0, len(primary))
            else:
                spent[part(backend)] += time.perf_counter() - t0
        return scanners[backend]

    n_new = 0
    for i, pos in enumerate(positions):
        rows = [(b, t) for b, t in config.wanted(res, i, p.backends) if row_key(p.spec, res, i, b, t) not in done]
        true = {}
        for t in sorted({t for _, t in rows}):
            t0 = time.perf_counter()
            true[t] = truths(i, pos, t)
            spent["pairs" if t == PAPER_TRUTH else "extras"] += time.perf_counter() - t0
        for b in sorted({b for b, _ in rows}):
            s = scanner(b)
            t0 = time.perf_counter()
            scan = s.scan(pos, secondary)
            seconds = time.perf_counter() - t0
            slr = primary[scan.indices]
            spent[part(b)] += time.perf_counter() - t0
            for t in [t for bb, t in rows if bb == b]:
                t0 = time.perf_counter()
                a = agreement(true[t], slr, config.threshold)
                spent[part(b, t)] += time.perf_counter() - t0
                results.add({"scene": p.spec, "n_rectangles": scene.n_rectangles, "scene_seed": scene.params["seed"],
                             "primary_resolution": res, "position": i, "x": pos[0], "y": pos[1], "z": pos[2],
                             "distance_m": float(math.hypot(pos[0], pos[1])), "backend": b, "truth": t,
                             "similarity": a.coverage, "precision": a.precision, "fscore": a.fscore,
                             "true_points": len(true[t]), "slr_points": len(scan), "seconds": seconds})
                n_new += 1
        _advance(bar, 1)
    for name, seconds in spent.items():
        if seconds:
            stages.add(p.spec, res, name, seconds, len(positions))
    return n_new
