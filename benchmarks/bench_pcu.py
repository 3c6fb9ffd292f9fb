"""slr_ray's discs against the peer: point-cloud-utils' RaySurfelIntersector.

    python benchmarks/bench_pcu.py [--points 5000000]

The same cloud (the first N points of the 29 M-point benchmark cloud), the same
radii and normals (slr_ray's defaults: kNN spacing radii, PCA normals;
computed once and cached under results/), the same rays (one per pulse centre
of a 0.144 deg pattern from a position 14 m away: 3.1 M rays; the median and
the best of 5 casts after one untimed cast). Each engine runs in its own process: build time, cast
time, peak memory above the loaded inputs (the kernel's high-water mark VmHWM,
reset through /proc/self/clear_refs once the inputs are loaded, minus the RSS
then: C allocations included), rays that hit, distinct points hit. slr_ray's
default (ties, one query) is also cast with the two-query tie rule of earlier
versions in the same process: time and whether every answer is the same. point-cloud-utils is a
benchmark-only dependency (``pip install point-cloud-utils``): it splats each
point as a polygon of ``subdivs`` triangles (default 7) in Embree.
Saves results/bench_pcu.json.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, realistic_cloud, run_isolated, save  # noqa: E402

ORIGIN = np.array([12.3, -7.1, 0.0])
#: casts per engine; the median and the fastest are reported
REPEAT = 5


def _status_gib(field):
    """``VmRSS`` / ``VmHWM`` of this process, GiB (None where /proc is not there)."""
    try:
        for line in open("/proc/self/status"):
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return None


def _reset_peak():
    """Reset the kernel's high-water mark to the current RSS; False where not allowed."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak():
    hwm = _status_gib("VmHWM")
    return hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def _timed(fn, times=None):
    times = [] if times is None else times
    for _ in range(REPEAT):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times)), min(times)


def inputs(n):
    pts = np.ascontiguousarray(realistic_cloud()[:n])
    rpath, npath = RESULTS / f"pcu_radii_{n}.npy", RESULTS / f"pcu_normals_{n}.npy"
    if not rpath.exists():
        from slr_ray import prepare

        s = prepare(pts, "embree")
        np.save(rpath, s.radii)
        np.save(npath, s.normals)
    return pts, np.load(rpath), np.load(npath)


def run(engine, n):
    import gc

    from slr_ray import ScanPattern
    from slr_ray.pattern import pulse_rays

    pts, radii, normals = inputs(n)
    dirs, _, _ = pulse_rays(ScanPattern(0.144))
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    gc.collect()
    reset = _reset_peak()
    base = _status_gib("VmRSS") if reset else _peak()
    extra = {}
    all_casts = []
    if engine == "pcu":
        import point_cloud_utils as pcu

        p = (pts - centre).astype(np.float32)
        t0 = time.perf_counter()
        isect = pcu.RaySurfelIntersector(p, normals.astype(np.float32), r=radii.astype(np.float32))
        build = time.perf_counter() - t0
        # one origin per ray: point-cloud-utils 0.31 misses every ray given a single (3,) origin
        o = np.repeat((ORIGIN - centre).astype(np.float32)[None], len(dirs), axis=0)
        d32 = dirs.astype(np.float32)
        # (ids, distances), whatever its docstring says
        isect.intersect_rays(o, d32)  # one untimed cast, as for slr_ray
        (pid, t), cast, best = _timed(lambda: isect.intersect_rays(o, d32), all_casts)
        pid = np.asarray(pid)
    else:
        from slr_ray.raycast import RayScene

        t0 = time.perf_counter()
        scene = RayScene.discs(pts, radii, normals, centre=centre)
        build = time.perf_counter() - t0
        ties = 1.0 if "ties" in engine else 0.0
        one_pass = "two queries" not in engine
        # one untimed cast of all the rays (compiled or loaded from numba's cache; the first casts of a
        # fresh scene are up to 2x slower, pages of its BVH being touched)
        scene.intersect(ORIGIN, dirs, ties=ties, one_pass=one_pass)
        hits, cast, best = _timed(lambda: scene.intersect(ORIGIN, dirs, ties=ties, one_pass=one_pass), all_casts)
        if ties and one_pass:  # the rule of earlier versions, same process, same rays
            scene.intersect(ORIGIN, dirs, ties=ties, one_pass=False)
            old, old_cast, old_best = _timed(lambda: scene.intersect(ORIGIN, dirs, ties=ties, one_pass=False))
            extra = {"two_queries_cast_seconds": old_cast, "two_queries_cast_best_seconds": old_best,
                     "same_as_two_queries": bool(np.array_equal(hits.owners, old.owners)
                                                 and np.array_equal(hits.primitives, old.primitives)
                                                 and np.array_equal(hits.distances, old.distances))}
        pid = hits.owners
    hit = pid >= 0
    peak = _peak()
    print(json.dumps({"engine": engine, "points": n, "rays": len(dirs), "build_seconds": build,
                      "cast_seconds": cast, "cast_best_seconds": best, "cast_seconds_all": all_casts, **extra,
                      "rays_hit": int(hit.sum()), "points_hit": int(len(np.unique(pid[hit]))),
                      "inputs_rss_gib": base, "peak_rss_gib": peak, "peak_above_inputs_gib": peak - base,
                      "memory_method": "VmHWM reset after the inputs" if reset else "peak RSS of the process"}))


def interleaved(n):
    """Both libraries in one process, their casts taken in turn (REPEAT rounds): on a
    shared machine whose speed drifts within a run, the ratios of these medians hold
    where those of separate processes do not."""
    import point_cloud_utils as pcu

    from slr_ray import ScanPattern
    from slr_ray.pattern import pulse_rays
    from slr_ray.raycast import RayScene

    pts, radii, normals = inputs(n)
    dirs, _, _ = pulse_rays(ScanPattern(0.144))
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    scene = RayScene.discs(pts, radii, normals, centre=centre)
    isect = pcu.RaySurfelIntersector((pts - centre).astype(np.float32), normals.astype(np.float32),
                                     r=radii.astype(np.float32))
    o = np.repeat((ORIGIN - centre).astype(np.float32)[None], len(dirs), axis=0)
    d32 = dirs.astype(np.float32)
    casts = {"slr_ray discs": lambda: scene.intersect(ORIGIN, dirs),
             "slr_ray discs, ties": lambda: scene.intersect(ORIGIN, dirs, ties=1.0),
             "slr_ray discs, ties, two queries": lambda: scene.intersect(ORIGIN, dirs, ties=1.0, one_pass=False),
             # one thread: its CPU time is the work a cast does, steady on a shared machine
             "slr_ray discs, ties, 1 thread": lambda: scene.intersect(ORIGIN, dirs, ties=1.0, n_threads=1),
             # Embree's packet width (default: the widest native, 16 here) on one thread: on the loaded
             # machine of 3 December 2026 which is cheapest changed from run to run (docs/speed.md)
             "slr_ray discs, ties, 1 thread, packets of 8":
                 lambda: scene.intersect(ORIGIN, dirs, ties=1.0, n_threads=1, packet=8),
             "slr_ray discs, ties, 1 thread, one ray at a time":
                 lambda: scene.intersect(ORIGIN, dirs, ties=1.0, n_threads=1, packet=1),
             "pcu": lambda: isect.intersect_rays(o, d32)}
    for f in casts.values():
        f()
    times = {k: [] for k in casts}
    cpu = {k: [] for k in casts}
    for _ in range(REPEAT):
        for k, f in casts.items():
            c0, t0 = time.process_time(), time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)  # all threads of the process
    print(json.dumps({"engine": "interleaved", "points": n, "rays": len(dirs),
                      "cast_seconds": {k: float(np.median(v)) for k, v in times.items()},
                      "cast_seconds_all": times,
                      "cast_cpu_seconds": {k: float(np.median(v)) for k, v in cpu.items()},
                      "cast_cpu_seconds_all": cpu}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=5_000_000)
    ap.add_argument("--engine", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.engine == "interleaved":
        return interleaved(args.points)
    if args.engine:
        return run(args.engine, args.points)
    inputs(args.points)  # radii and normals once, outside the timed processes
    rows = []
    for engine in ("slr_ray discs", "slr_ray discs, ties", "slr_ray discs, ties, two queries", "pcu"):
        r = run_isolated(__file__, ["--points", str(args.points), "--engine", engine], "engine", engine)
        rows.append(r)
        print(json.dumps(r), file=sys.stderr, flush=True)
    inter = run_isolated(__file__, ["--points", str(args.points), "--engine", "interleaved"], "engine", "interleaved")
    print(json.dumps(inter), file=sys.stderr, flush=True)
    ok = {r["engine"]: r for r in rows if "error" not in r}
    if "pcu" in ok and "slr_ray discs, ties" in ok:
        # slr_ray's default (ties, one query) against pcu; medians
        a, b = ok["slr_ray discs, ties"], ok["pcu"]
        ratios = {"build_x_faster": b["build_seconds"] / a["build_seconds"],
                  "cast_x_faster": b["cast_seconds"] / a["cast_seconds"],
                  "cast_x_faster_without_ties": b["cast_seconds"] / ok.get("slr_ray discs", a)["cast_seconds"],
                  "one_pass_x_faster_than_two_queries": a["two_queries_cast_seconds"] / a["cast_seconds"],
                  "memory_fraction": a["peak_above_inputs_gib"] / max(b["peak_above_inputs_gib"], 1e-9)}
        if "error" not in inter:  # the same ratios from casts taken in turn in one process
            c = inter["cast_seconds"]
            ratios["interleaved"] = {
                "cast_x_faster": c["pcu"] / c["slr_ray discs, ties"],
                "cast_x_faster_without_ties": c["pcu"] / c["slr_ray discs"],
                "one_pass_x_faster_than_two_queries": c["slr_ray discs, ties, two queries"] / c["slr_ray discs, ties"]}
            u = inter.get("cast_cpu_seconds")
            if u:  # process CPU (pcu casts on one thread: its CPU is its wall time on a quiet machine)
                ratios["interleaved"]["cpu"] = {
                    "cast_x_less_cpu": u["pcu"] / u["slr_ray discs, ties"],
                    "cast_x_less_cpu_without_ties": u["pcu"] / u["slr_ray discs"],
                    "one_thread_x_less_cpu": u["pcu"] / u["slr_ray discs, ties, 1 thread"]}
    else:
        ratios = None
    print(f"{'engine':<33} {'build s':>8} {'cast s':>7} {'peak+ GiB':>10} {'rays hit':>10} {'points hit':>11}")
    for r in rows:
        if "error" in r:
            print(f"{r['engine']:<33} {r['error']}")
        else:
            print(f"{r['engine']:<33} {r['build_seconds']:>8.2f} {r['cast_seconds']:>7.3f} "
                  f"{r['peak_above_inputs_gib']:>10.2f} {r['rays_hit']:>10,} {r['points_hit']:>11,}")
    if ratios:
        print(f"slr_ray (ties, the default) vs pcu: build {ratios['build_x_faster']:.1f}x faster, cast "
              f"{ratios['cast_x_faster']:.1f}x faster ({ratios['cast_x_faster_without_ties']:.1f}x without ties), "
              f"memory {ratios['memory_fraction']:.2f} of pcu's; one query "
              f"{ratios['one_pass_x_faster_than_two_queries']:.2f}x faster than two, same answers: "
              f"{ok['slr_ray discs, ties']['same_as_two_queries']}")
        if "interleaved" in ratios:
            q = ratios["interleaved"]
            print("casts taken in turn in one process (medians): "
                  + ", ".join(f"{k} {v:.3f} s" for k, v in inter["cast_seconds"].items())
                  + f"; ties {q['cast_x_faster']:.2f}x pcu, no ties {q['cast_x_faster_without_ties']:.2f}x, "
                    f"one query {q['one_pass_x_faster_than_two_queries']:.2f}x two")
            if "cpu" in q:
                print("their process CPU (medians): "
                      + ", ".join(f"{k} {v:.3f} s" for k, v in inter["cast_cpu_seconds"].items())
                      + f"; pcu / ties {q['cpu']['cast_x_less_cpu']:.2f}, pcu / no ties "
                        f"{q['cpu']['cast_x_less_cpu_without_ties']:.2f}, pcu / ties on one thread "
                        f"{q['cpu']['one_thread_x_less_cpu']:.2f}")
    save("bench_pcu", {"machine": machine(), "inputs": vars(args), "rows": rows, "interleaved": inter,
                       "ratios": ratios})


if __name__ == "__main__":
    main()
