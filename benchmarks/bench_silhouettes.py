"""The silhouette rule away from the primary's origin (issue #38: "keep what was won").

    PYTHONPATH=. nice python benchmarks/bench_silhouettes.py [--primary-resolution 0.1] [--positions 3]

Scenes ``ground-only`` and ``rect-1000`` (bench_tradeoff's), primary = pulse-centre scan of the mesh
from the origin at ``--primary-resolution`` degrees (0.1: bench_tradeoff's, 3-4 M points); secondary
positions 3-30 m away (bench_tradeoff's angles and distances, the first ``--positions``), 0.144 deg,
60 m; truth = the exact pulse-centre scan of the mesh there. Embree with the primary's origin and
resolution (pulse-grid discs, ``grid_spacing='step'``) with ``silhouettes=True`` (the default) and
False (before), and binning. Coverage and precision at 10 cm (``slr_ray.agreement``), points out,
cast seconds, and prepare seconds (medians over positions / runs). Saves results/bench_silhouettes.json.

First, the step edge of tests/test_embree_silhouettes.py (a wall 5 m in front of one 10 m away, 0.5 deg,
zenith 70-110, scanned exactly with ``scan_mesh`` from the origin): pulses returned more than 0.5 m off
the exact scan of the mesh at the origin and 1 m away, binning and embree with ``primary_image=False``
(the discs themselves) with and without ``silhouettes``; then the same for the scene mirrored across y.

``--pulse-cells`` adds ``pulse_cells=True`` (on top of the silhouettes) as a setting of both parts.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save  # noqa: E402

from slr_ray import ScanPattern, agreement, prepare, scan_mesh  # noqa: E402
from slr_ray.scenes import scene_from_spec  # noqa: E402


def _quad(x, y0, y1, z0, z1):
    import trimesh

    v = np.array([[x, y0, z0], [x, y1, z0], [x, y1, z1], [x, y0, z1]], float)
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def step_edge(cells: bool = False) -> list[dict]:
    import trimesh

    mesh = trimesh.util.concatenate([_quad(5.0, -1.0, 0.0, -1.0, 1.0), _quad(10.0, -4.0, 4.0, -3.0, 3.0)])
    rows = _step_edge(mesh, "", cells)
    # the scene mirrored across y: the rule has no side (its counts at +y and -y swap)
    mirror = trimesh.Trimesh(mesh.vertices * [1, -1, 1], mesh.faces[:, ::-1], process=False)
    return rows + _step_edge(mirror, "mirrored scene, ", cells)


def _step_edge(mesh, scene: str, cells: bool = False) -> list[dict]:
    pat = ScanPattern(resolution=0.5, zenith_range=(70, 110))
    pts = scan_mesh(mesh, [0, 0, 0], pat).points
    grid = {"primary_origin": [0.0, 0.0, 0.0], "primary_resolution": 0.5, "primary_image": False}
    scanners = {"binning": prepare(pts, "binning"), "embree, silhouettes": prepare(pts, "embree", **grid),
                "embree, no silhouettes": prepare(pts, "embree", silhouettes=False, **grid)}
    if cells:
        scanners["embree, silhouettes + pulse cells"] = prepare(pts, "embree", pulse_cells=True, **grid)
    rows = []
    if not scene:
        print("| position | " + " | ".join(scanners) + " |")
    for label, off in (("origin", (0, 0, 0)), ("1 m above", (0, 0, 1)), ("1 m aside +y", (0, 1, 0)),
                       ("1 m aside -y", (0, -1, 0)), ("1 m forward", (1, 0, 0))):
        truth = scan_mesh(mesh, off, pat)
        t = dict(zip(map(tuple, truth.pulses.tolist()), truth.ranges))
        row = {"position": scene + label, "pulses": len(pts)}
        for name, sc in scanners.items():
            s = sc.scan(off, pat)
            row[name] = int(sum(abs(r - t[p]) > 0.5 for p, r in zip(map(tuple, s.pulses.tolist()), s.ranges)
                                if p in t))
        rows.append(row)
        print(f"| {scene}{label} | " + " | ".join(str(row[n]) for n in scanners) + " |", flush=True)
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="ground-only,rect-1000")
    ap.add_argument("--primary-resolution", type=float, default=0.1)
    ap.add_argument("--positions", type=int, default=3)
    ap.add_argument("--pulse-cells", action="store_true", help="add pulse_cells=True as a setting")
    ap.add_argument("--name", default="bench_silhouettes", help="results/<name>.json")
    args = ap.parse_args(argv)
    edge = step_edge(args.pulse_cells)
    rng = np.random.default_rng(0)  # bench_tradeoff's positions
    n = 6
    dist = np.linspace(3, 30, n)
    ang = rng.uniform(0, 2 * np.pi, n)
    positions = np.column_stack([dist * np.cos(ang), dist * np.sin(ang), np.zeros(n)])[:args.positions]
    pattern = ScanPattern(0.144, max_range=60.0)
    grid = {"primary_origin": [0.0, 0.0, 0.0], "primary_resolution": args.primary_resolution}
    out = []
    for name in args.scenes.split(","):
        scene = scene_from_spec(name)
        pts = scan_mesh(scene, [0, 0, 0], ScanPattern(args.primary_resolution, max_range=100.0)).points
        truths = [scan_mesh(scene, p, pattern).points for p in positions]
        settings = {"binning": ("binning", {}), "embree, silhouettes (new)": ("embree", {**grid}),
                    "embree, no silhouettes (before)": ("embree", {**grid, "silhouettes": False})}
        if args.pulse_cells:
            settings["embree, silhouettes + pulse cells"] = ("embree", {**grid, "pulse_cells": True})
        for label, (backend, opts) in settings.items():
            t0 = time.perf_counter()
            sc = prepare(pts, backend, **opts)
            prep = time.perf_counter() - t0
            cov, prec, npts, cast = [], [], [], []
            for p, truth in zip(positions, truths):
                t0 = time.perf_counter()
                s = sc.scan(p, pattern)
                cast.append(time.perf_counter() - t0)
                a = agreement(truth, pts[s.indices])
                cov.append(a.coverage)
                prec.append(a.precision)
                npts.append(len(s.indices))
            row = {"scene": name, "setting": label, "primary_points": len(pts), "prepare_seconds": prep,
                   "coverage": float(np.mean(cov)), "precision": float(np.mean(prec)), "points": npts,
                   "cast_seconds_median": float(np.median(cast)), "per_position": {"coverage": cov, "precision": prec}}
            out.append(row)
            print(f"| {name} | {label} | {row['coverage']:.1%} | {row['precision']:.1%} | {sum(npts):,} | "
                  f"{prep:.2f} | {row['cast_seconds_median']:.2f} |", flush=True)
    save(args.name, {"machine": machine(), "inputs": vars(args), "positions": positions.tolist(),
                               "step_edge": edge, "results": out})


if __name__ == "__main__":
    main()
