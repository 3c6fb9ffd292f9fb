"""Where the embree backend's prepare and scan time goes on a dense primary.

    python benchmarks/profile_embree_prepare.py [--resolution 0.0144] [--scene rect-1000]

On the cached dense primary of bench_embree_primary.py (58 M points at
0.0144 deg; made by that script first), each stage of a pulse-grid prepare
is timed on its own: pulse keys (and the same kernel again into the
now-resident arrays, on one and two threads), the line sort, the fused spacing + normals
pass (and the spacing-only walk), radii, bounds, the vertex fill and Embree's
build. Then the disc radii with the range gate fixed at 10 % and at its
default (``grid_gate``): how many exceed 1 m, the largest, where they stand;
and one 0.144 deg cast with and without the tie rule on the default discs.
Each stage's peak anonymous and file-backed resident memory is sampled
(:mod:`memwatch`; the cloud is memory-mapped, so its pages are the file
part, released before Embree's build as ``RayScene.discs`` does).
Saves results/profile_embree_prepare.json.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_embree_primary import ORIGIN, cache_path  # noqa: E402
from common import machine, save  # noqa: E402
from memwatch import MemWatch  # noqa: E402


#: peaks of anonymous and file-backed resident memory by stage (the cloud is memory-mapped)
WATCH = MemWatch()


def _timed(fn, name=None):
    WATCH.mark("(between stages)")
    t0 = time.perf_counter()
    out = fn()
    seconds = time.perf_counter() - t0
    if name:
        WATCH.mark(name)
    return seconds, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="rect-1000")
    ap.add_argument("--resolution", type=float, default=0.0144)
    args = ap.parse_args(argv)
    path = cache_path(args.scene, args.resolution)
    if not path.exists():
        raise SystemExit(f"{path} is missing: run bench_embree_primary.py --resolutions {args.resolution:g} first")

    from slr_ray import ScanPattern
    from slr_ray.arrays import bounds
    from slr_ray.backends.embree import disc_radii
    from slr_ray.backends.embree import pulsegrid as E
    from slr_ray.core import pulse_ids
    from slr_ray.pattern import as_pattern, pulse_rays
    from slr_ray.raycast import RayScene
    from slr_ray.raycast.scene import _fill_vertices

    pts = np.ascontiguousarray(np.load(path, mmap_mode="r"))
    WATCH.__enter__()
    res, o = args.resolution, np.zeros(3)
    E.pulse_grid_spacing_normals(pts[:5000], o, res, dtype=np.float32)  # compile outside the timings
    pat = as_pattern(res)
    nv, nh = pat.n_zenith, pat.n_azimuth
    stages = {}
    stages["pulse keys"], (keys, ranges) = _timed(lambda: pulse_ids(pts, o, pat), "pulse keys")
    # the same kernel again into the same (now resident) arrays: the first pass pays for
    # touching ~16 bytes a point of fresh memory, this one only for the arithmetic
    from concurrent.futures import ThreadPoolExecutor

    from slr_ray.core.grid import block_keys_range as _block_keys_range, kernel_params as _kernel_params

    params = _kernel_params(o, pat)
    n = len(pts)
    for parts in (1, 2):
        cuts = [n * i // parts for i in range(parts + 1)]
        with ThreadPoolExecutor(parts) as pool:
            stages[f"pulse keys, warm arrays, {parts} thread(s)"], _ = _timed(lambda: list(pool.map(
                lambda i: _block_keys_range(pts, *params, keys, ranges, cuts[i], cuts[i + 1]), range(parts))))
    rows_up, cols_up = E._runs(keys, nv, nh)
    transposed = cols_up > rows_up
    if transposed:
        E._transpose_keys(keys, nv, nh)
    lines, line_len = (nh, nv) if transposed else (nv, nh)
    stages["line sort"], (order, sk, ls) = _timed(lambda: E._line_sort(keys, line_len, lines), "line sort")
    keys = None  # freed (not del: the lambdas above name it)
    gate = E.grid_gate(res)
    tasks = E._row_tasks(ls, 0, len(ls) - 1)
    sp = np.zeros(len(pts))
    nr = E.padded_rows(len(pts), np.float32)
    cos_min, step = math.cos(math.radians(80.0)), E._spacing_code("mean")  # EmbreeOptions defaults
    stages["spacing only"], _ = _timed(lambda: E._grid_fused(pts, ranges, sk, order, ls, tasks, line_len, transposed,
                                                              gate, o, True, False, sp, nr, cos_min, step), "spacing only")
    stages["spacing and normals"], _ = _timed(lambda: E._grid_fused(pts, ranges, sk, order, ls, tasks, line_len,
                                                                     transposed, gate, o, True, True, sp, nr,
                                                                     cos_min, step), "spacing and normals")
    ranges = sk = order = None  # freed (not del: the lambdas above name them)
    stages["radii"], r = _timed(lambda: disc_radii(pts, "spacing", spacing=sp).astype(np.float32), "radii")
    stages["bounds"], (lo, hi) = _timed(lambda: bounds(pts), "bounds")
    centre = 0.5 * (lo + hi)
    v = np.empty((len(pts), 4), np.float32)
    stages["vertex fill"], _ = _timed(lambda: _fill_vertices(pts, centre, r, v), "vertex fill")
    v = None
    stages["embree build (RayScene.discs)"], scene = _timed(lambda: RayScene.discs(pts, r, nr, centre=centre),
                                                            "embree build (RayScene.discs)")
    for k, s in stages.items():
        print(f"{k:<32} {s:7.2f} s", flush=True)
    WATCH.__exit__()
    memory = [r for r in WATCH.stages if not r["stage"].startswith("(")]
    print(f"{'stage':<32} {'anon GiB':>9} {'file GiB':>9} {'anon B/pt':>9} (peaks; the cloud mapped, "
          f"{pts.nbytes / 2**30:.2f} GiB)")
    for r in memory:
        r["anon_bytes_per_point"] = (r["anon_gib"] - WATCH.stages[0]["anon_gib"]) * 2**30 / len(pts)
        print(f"{r['stage']:<32} {r['anon_gib']:>9.2f} {r['file_gib']:>9.2f} {r['anon_bytes_per_point']:>9.1f}")

    radii = {}
    for name, g in (("gate 0.1", 0.1), (f"default gate {gate:.4f}", None)):
        s, _ = E.pulse_grid_spacing_normals(pts, o, res, g, True, False)
        big = s > 1.0
        radii[name] = {"gate": E.grid_gate(res, g), "spacing_percentiles_50_99_99.9_99.99":
                       np.percentile(s, [50, 99, 99.9, 99.99]).round(4).tolist(),
                       "max": float(s.max()), "over_1m": int(big.sum()),
                       "z_of_over_1m_10_50_90": np.percentile(pts[big, 2], [10, 50, 90]).round(2).tolist()
                       if big.any() else None}
        print(name, json.dumps(radii[name]), flush=True)

    dirs, _, _ = pulse_rays(ScanPattern(0.144))
    d_theta, d_phi = ScanPattern(0.144).pulse_steps
    aspect = d_theta / d_phi
    cast = {}
    for ties in (1.0, 0.0):
        scene.intersect(ORIGIN, dirs[:1000], ties=ties, skip_containing=True, pulse_aspect=aspect)
        best = np.inf
        for _ in range(2):
            t, h = _timed(lambda: scene.intersect(ORIGIN, dirs, ties=ties, skip_containing=True, pulse_aspect=aspect))
            best = min(best, t)
        cast[f"ties {ties:g}"] = {"seconds": best, "rays_hit": int(h.hit.sum())}
        print(f"cast, ties {ties:g}: {best:.2f} s, {int(h.hit.sum()):,} rays hit", flush=True)
    save("profile_embree_prepare", {"inputs": {**vars(args), "points": len(pts)}, "machine": machine(),
                                    "stages_seconds": stages, "memory": memory, "radii": radii, "cast": cast})


if __name__ == "__main__":
    main()
