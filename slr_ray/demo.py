"""``slr-ray demo``: the main job on a built-in scene, with no input file.

1. a synthetic rectangle scene (the paper's Experiment 1, fewer rectangles);
2. its primary scan from the origin (exact ray casting, pulse centres);
3. secondary positions drawn on the primary by the paper's grid method, and at
   each: the true scan of the scene and the SLR scans of the primary cloud by
   both backends (binning, the paper's rule; embree, discs hit by one ray per
   pulse);
4. coverage (the paper's similarity: true points with an SLR point within
   10 cm) and precision (SLR points with a true point within 10 cm) of each
   pair, files, a figure and a one-screen report.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import paper
from .backends import Backend, available_backends, prepare, scanner_class
from .errors import refuse_memory
from .io import PointCloud, atomic_path, write_cloud
from .meshscan import scan_mesh
from .io.outputs import OutputPlan
from .options import Options
from .pattern import ScanPattern, preset
from .plotting import demo_figure, save_figure
from .positions import select_positions
from .progress import bar, phase
from .scenes import rectangle_scene
from .metrics import agreement

__all__ = ["DemoOptions", "run_demo", "demo_files"]


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


@dataclass(frozen=True)
class DemoOptions(Options):
    """What :func:`run_demo` runs.

    Attributes
    ----------
    n_rectangles : int
        The scene's rectangles (:func:`~slr_ray.scenes.rectangle_scene`).
    n_positions : int
        Secondary positions drawn by the grid method (fewer when the scene has
        fewer valid cells).
    seed : int
        The scene's and the positions' seed.
    quick : bool
        A coarse primary (0.12 deg) and secondary (0.36 deg): seconds, for tests.
    primary_resolution : float or None
        Degrees (default 0.036, the SYNS scans'; 0.12 with ``quick``).
    backends : sequence of str or None
        Backends run at every position (default: every :class:`~slr_ray.backends.Backend`;
        one whose library is missing is left out, with a note).
    """

    n_rectangles: int = 200
    n_positions: int = 4
    seed: int = 0
    quick: bool = False
    primary_resolution: float | None = None
    backends: tuple | None = None


def run_demo(outdir="slr_ray_demo", options: DemoOptions | None = None, *, force: bool = False,
             progress: bool | None = None, **keywords) -> dict:
    """Run the demo and return its summary (the full report is written to ``outdir/report.json``).

    Parameters
    ----------
    outdir : path
        Created if missing; the demo writes only its own files there.
    options : DemoOptions or dict, optional
        The scene, the positions, the resolutions and the backends
        (:class:`DemoOptions`); each field may also be given as a keyword
        (``n_positions=2, quick=True``).
    force : bool
        Replace the files of an earlier demo in ``outdir`` (without it, an
        existing one is an :class:`~slr_ray.errors.OutputError` before any work).
    progress : bool, optional
        Progress on stderr (scans, preparing the backends; default: not ``quick``).
        The report table is printed either way.
    """
    o = DemoOptions.of(options, **keywords)
    n_positions = o.n_positions
    backends = [b.value for b in Backend] if o.backends is None else list(o.backends)
    refuse_memory(1024.0 * n_positions * (1 + len(backends)), f"a demo of {n_positions:,} positions "
                  "(about 1 KB a file: its file plan)", "ask for fewer positions")
    plan = OutputPlan(force=force)
    out = plan.directory(outdir)
    for name in demo_files(n_positions, backends):
        plan.write(out / name)
    with plan:
        return _run_demo(Path(outdir), o, backends, not o.quick if progress is None else bool(progress))


def demo_files(n_positions: int, backends) -> list:
    """The files :func:`run_demo` may write (fewer when fewer positions are found); positions are
    numbered from 1, as in the demo's table and figure."""
    return ["demo.png", "report.json"] + [f"position_{i:02d}_{kind}.ply" for i in range(1, n_positions + 1)
                                         for kind in ["true", *(f"slr_{b}" for b in backends)]]


def _run_demo(out, o: DemoOptions, backends, progress) -> dict:
    n_rectangles, n_positions, seed, quick, primary_resolution = (o.n_rectangles, o.n_positions, o.seed, o.quick,
                                                                  o.primary_resolution)
    t_all = time.perf_counter()
    primary_res = float(primary_resolution or (0.12 if quick else paper.SYNS_RESOLUTION))
    secondary = ScanPattern(0.36) if quick else preset("slr")
    scene = rectangle_scene(n_rectangles, seed=seed)
    _log(f"scene: {scene.n_present} of {n_rectangles} rectangles present, {len(scene.mesh.faces)} faces")

    origin = np.zeros(3)
    primary = scan_mesh(scene, origin, ScanPattern(primary_res, max_range=120.0), progress=progress)
    _log(f"primary scan at {primary_res} deg: {len(primary):,} points in {primary.seconds:.1f} s")
    # the primary (27 M points, 0.7 GB) is not written: `slr-ray scene scan` makes it on its own

    # the paper's ground-support threshold is for 0.036 deg scans: scaled by the pulse density
    min_ground = max(100, round(paper.MIN_GROUND_POINTS * (paper.SYNS_RESOLUTION / primary_res) ** 2))
    positions = select_positions(primary.points, primary.labels == 0, n_positions, seed=seed,
                                 min_ground_points=min_ground, allow_fewer=True)
    _log(f"{len(positions)} positions by the grid method (>= {min_ground:,} ground points within 5 m)")

    missing = [b for b in backends if b not in available_backends()]
    if missing:
        _log(f"left out (library missing): {missing}")
    scanners = {}
    for b in [b for b in backends if b not in missing]:
        # a primary of known origin and resolution: the cheapest options that use it (embree: discs of
        # the pulse footprint facing the primary scanner need no neighbour search, the dearest part)
        options = scanner_class(b).primary_options(origin, primary_res, fast=True) or None
        with phase(f"{b}: preparing {len(primary):,} points", progress=progress):
            scanners[b] = prepare(primary.points, b, options)

    rows = []
    for i, pos in enumerate(bar(positions, "true and SLR scans", "position", progress=progress), 1):
        truth = scan_mesh(scene, pos, secondary)
        name = f"position_{i:02d}"
        write_cloud(out / f"{name}_true.ply", PointCloud(truth.points, {"label": truth.labels.astype(np.int32)}))
        for b, scanner in scanners.items():
            slr = scanner.scan(pos, secondary)
            a = agreement(truth.points, primary.points[slr.indices])
            write_cloud(out / f"{name}_slr_{b}.ply", PointCloud(
                primary.points[slr.indices], {"label": primary.labels[slr.indices].astype(np.int32)}))
            rows.append({"number": i, "position": pos.round(3).tolist(), "distance_m": round(float(np.hypot(*pos[:2])), 3),
                         "backend": b, "slr_points": len(slr), "true_points": len(truth),
                         "similarity": round(a.coverage, 4), "precision": round(a.precision, 4),
                         "slr_seconds": round(slr.seconds, 3), "true_seconds": round(truth.seconds, 3)})

    save_figure(demo_figure(primary, positions, rows, scene.n_present), out / "demo.png")
    report = {
        "scene": scene.info(), "primary": {**primary.summary(), "resolution_deg": primary_res},
        "secondary_pattern": secondary.to_dict(), "min_ground_points": min_ground,
        "prepare_seconds": {b: round(s.prepare_seconds, 3) for b, s in scanners.items()}, "pairs": rows,
        "files": sorted(p.name for p in out.iterdir()), "output_dir": str(out),
        "seconds": round(time.perf_counter() - t_all, 2),
    }
    with atomic_path(out / "report.json") as tmp:
        tmp.write_text(json.dumps(report, indent=2))
    _log("")
    _log(f"{'position':>8} {'x, y (m)':>14} {'dist m':>7} {'backend':>8} {'SLR pts':>9} {'true pts':>9} "
         f"{'coverage':>9} {'precision':>9}")
    for r in rows:
        xy = f"{r['position'][0]:.1f}, {r['position'][1]:.1f}"
        _log(f"{r['number']:>8} {xy:>14} {r['distance_m']:>7.1f} {r['backend']:>8} {r['slr_points']:>9,} "
             f"{r['true_points']:>9,} {r['similarity']:>9.1%} {r['precision']:>9.1%}")
    _log(f"\nfiles in {out}/ ; figure {out / 'demo.png'} ; {report['seconds']} s in all")
    summary = {}
    for b in scanners:
        rr = [r for r in rows if r["backend"] == b]
        summary[b] = {"mean_similarity": round(float(np.mean([r["similarity"] for r in rr])), 4) if rr else None,
                      "mean_precision": round(float(np.mean([r["precision"] for r in rr])), 4) if rr else None}
    return {"output_dir": str(out), "positions": len(positions), "backends": summary,
            "mean_similarity": summary.get("binning", {}).get("mean_similarity"), "seconds": report["seconds"]}
