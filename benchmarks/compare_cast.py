"""The embree cast of this checkout against another's, casts taken in turn in one process.

    python benchmarks/compare_cast.py OTHER_CHECKOUT [--points 5000000] [--rounds 9] [--threads 1] [--pcu]
                                     [--origin X Y Z] [--skip]

The inputs of ``bench_pcu.py`` (the first N points of the benchmark cloud,
their radii and normals, 3.1 M pulse rays from 14 m away). The other
checkout's ``slr_ray`` is copied into a temporary folder under another name
and imported beside this one, so both build a disc scene in the same process
and cast in turn (with and without the tie rule; ``--pcu``: point-cloud-utils
too), ``--rounds`` times: on a machine shared with other jobs the drift hits
both alike. With ``--threads 1`` (the default) the times are the CPU time of
the casting thread, which does not count the time other jobs hold the core;
otherwise wall-clock. ``--origin``: cast from there instead (e.g. ``0 0 1.5``,
inside the cloud, as the embree backend's scans are); ``--skip``: with
``skip_containing`` and the tie rule in pulse units, as the backend casts.
Checks that both give the same answers. Prints medians
and minima; saves results/compare_cast.json.
"""

from __future__ import annotations

import argparse
import importlib
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_pcu import ORIGIN, inputs  # noqa: E402
from common import machine, save  # noqa: E402

NAME = "slr_ray_other"


def _other_package(checkout: Path, tmp: str):
    """The other checkout's slr_ray, imported as ``slr_ray_other`` (its imports are relative)."""
    shutil.copytree(checkout / "slr_ray", Path(tmp) / NAME, ignore=shutil.ignore_patterns("__pycache__"))
    sys.path.insert(0, tmp)
    return importlib.import_module(NAME + ".raycast")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", help="the other checkout (its root)")
    ap.add_argument("--points", type=int, default=5_000_000)
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--threads", type=int, default=1, help="threads of each cast (0: the default, all cores)")
    ap.add_argument("--pcu", action="store_true", help="point-cloud-utils' cast too (wall-clock, its own threads)")
    ap.add_argument("--origin", type=float, nargs=3, default=list(ORIGIN), help="ray origin (default: bench_pcu's)")
    ap.add_argument("--skip", action="store_true", help="skip_containing and pulse-unit ties, as the embree backend")
    args = ap.parse_args(argv)
    other = Path(args.other).resolve()
    if not (other / "slr_ray").is_dir():
        ap.error(f"{other} has no slr_ray package")
    import slr_ray
    from slr_ray import ScanPattern
    from slr_ray.pattern import pulse_rays
    from slr_ray.raycast import RayScene

    pts, radii, normals = inputs(args.points)
    dirs, _, _ = pulse_rays(ScanPattern(0.144))
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    with tempfile.TemporaryDirectory() as tmp:
        theirs = _other_package(other, tmp).RayScene.discs(pts, radii, normals, centre=centre)
        ours = RayScene.discs(pts, radii, normals, centre=centre)
        n_threads = args.threads or None
        origin = np.array(args.origin)
        extra = {"skip_containing": True, "pulse_aspect": 1.0} if args.skip else {}
        clock = time.thread_time if n_threads == 1 else time.perf_counter
        casts = {}
        for ties in (1.0, 0.0):
            tag = "ties" if ties else "no ties"
            casts[f"other, {tag}"] = lambda s=theirs, w=ties: s.intersect(origin, dirs, ties=w, n_threads=n_threads,
                                                                          **extra)
            casts[f"this, {tag}"] = lambda s=ours, w=ties: s.intersect(origin, dirs, ties=w, n_threads=n_threads,
                                                                       **extra)
        if args.pcu:
            import point_cloud_utils as pcu

            isect = pcu.RaySurfelIntersector((pts - centre).astype(np.float32), normals.astype(np.float32),
                                             r=radii.astype(np.float32))
            o = np.repeat((origin - centre).astype(np.float32)[None], len(dirs), axis=0)
            d32 = dirs.astype(np.float32)
            casts["pcu"] = lambda: isect.intersect_rays(o, d32)
        first = {k: f() for k, f in casts.items()}  # compiled (or loaded from numba's cache) untimed
        same = {tag: all(np.array_equal(getattr(first[f"other, {tag}"], f), getattr(first[f"this, {tag}"], f))
                         for f in ("primitives", "owners", "distances")) for tag in ("ties", "no ties")}
        del first
        times = {k: [] for k in casts}
        for r in range(args.rounds):
            for k, f in casts.items():
                t0 = clock() if k != "pcu" else time.perf_counter()
                f()
                times[k].append((clock() if k != "pcu" else time.perf_counter()) - t0)
            print(f"round {r + 1}/{args.rounds}", file=sys.stderr, flush=True)
    med = {k: float(np.median(v)) for k, v in times.items()}
    low = {k: float(np.min(v)) for k, v in times.items()}
    ratio = {tag: med[f"other, {tag}"] / med[f"this, {tag}"] for tag in ("ties", "no ties")}
    clock_name = "CPU time of the casting thread" if n_threads == 1 else "wall-clock"
    print(f"{'cast':<16} {'median s':>9} {'min s':>7}   ({clock_name}, {args.rounds} rounds, threads: "
          f"{n_threads or 'default'})")
    for k in casts:
        print(f"{k:<16} {med[k]:>9.4f} {low[k]:>7.4f}")
    print("this checkout {:.2f}x faster with ties, {:.2f}x without; same answers: {}".format(
        ratio["ties"], ratio["no ties"], same))
    save("compare_cast", {"machine": machine(), "inputs": {**vars(args), "this": slr_ray.__file__, "other": str(other)},
                          "clock": clock_name, "median_seconds": med, "min_seconds": low, "seconds": times,
                          "x_faster": ratio, "same_answers": same})


if __name__ == "__main__":
    main()
