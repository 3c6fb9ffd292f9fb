"""The embree backend on the validation's dense primaries (the paper's scale).

    python benchmarks/bench_embree_primary.py [--resolutions 0.0144 0.00576] [--scene rect-1000]
                                              [--settings footprint spacing]

For each primary resolution: the dense primary of the scene (the paper's 5 mm
grid, nearest in pulse; 58 M points at 0.0144 deg, 209 M at 0.00576 deg for
rect-1000) is made once in its own process and cached under results/ (not
committed); then each disc setting is prepared in a fresh process that maps
the cached cloud, and one 0.144 deg scan is cast from a position 14 m away.
The paper's sort method runs on the same cloud in the same run as the
baseline. Reports prepare + build seconds, the ratio to the sort baseline,
peak RSS above the mapped cloud, bytes a point handed to Embree, and the
scan's time and size. Saves results/bench_embree_primary.json.

Settings: ``footprint`` = discs of each point's primary pulse footprint facing
the primary scanner (no neighbour search); ``grid`` = footprint radii with
normals from the primary's own pulse grid (no kd-tree); ``pulse-grid`` = the
default when the primary's origin and resolution are given (spacing radii and
PCA normals, both from the pulse grid); ``spacing`` = the default without
them (kNN radii, PCA normals). Rows of earlier runs for other resolutions or
settings are kept in the JSON (each row says when it was measured).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, run_isolated, save  # noqa: E402

ORIGIN = [12.3, -7.1, 0.0]


def settings(res):
    return {"footprint": {"radius": "footprint", "orientation": "primary", "primary_origin": [0.0, 0.0, 0.0],
                          "primary_resolution": res},
            "grid": {"radius": "footprint", "neighbours": "pulse-grid", "primary_origin": [0.0, 0.0, 0.0],
                     "primary_resolution": res},
            # the default when the primary is known: spacing radii and PCA normals from its pulse grid
            "pulse-grid": {"primary_origin": [0.0, 0.0, 0.0], "primary_resolution": res},
            "spacing": {}}


def _peak_gib():
    """The process's peak RSS (the kernel's VmHWM; since the last :func:`_reset_peak`)."""
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def _rss_gib():
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return _peak_gib()


def _reset_peak():
    """VmHWM back to the current RSS (/proc/self/clear_refs); False where not allowed."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def cache_path(scene, res):
    return RESULTS / f"primary_{scene}_{res:g}_dense.npy"


def make_primary(scene_name, res):
    import numpy as np

    from slr_ray import ScanPattern, scan_mesh
    from slr_ray.scenes import scene_from_spec

    t0 = time.perf_counter()
    ms = scan_mesh(scene_from_spec(scene_name), [0, 0, 0], ScanPattern(res), mode="dense", progress=True)
    path = cache_path(scene_name, res)
    tmp = path.with_suffix(".tmp.npy")
    np.save(tmp, ms.points)
    tmp.rename(path)
    print(json.dumps({"job": "primary", "points": len(ms), "seconds": time.perf_counter() - t0,
                      "peak_rss_gib": _peak_gib()}))


def run_one(scene_name, res, name):
    import numpy as np

    from slr_ray import ScanPattern, prepare

    pts = np.load(cache_path(scene_name, res), mmap_mode="r")
    n = len(pts)
    pattern = ScanPattern(0.144)
    if name == "sort baseline":
        from sort_baseline import sort_based_scan

        t0 = time.perf_counter()
        idx = sort_based_scan(np.asarray(pts), ORIGIN, pattern)
        print(json.dumps({"setting": name, "points": n, "seconds": time.perf_counter() - t0,
                          "points_out": len(idx), "peak_rss_gib": _peak_gib()}))
        return
    opts = settings(res)[name]
    prepare(np.asarray(pts[:2000]), "embree", **opts).scan(ORIGIN, 5.0)  # compile outside the timing
    import gc

    gc.collect()
    # the peak above this point: the mapped cloud is not read yet, so its pages count in the peak
    base = _rss_gib() if _reset_peak() else _peak_gib()
    t0 = time.perf_counter()
    scanner = prepare(pts, "embree", **opts)
    prep = time.perf_counter() - t0
    scan = scanner.scan(ORIGIN, pattern)
    print(json.dumps({"setting": name, "points": n, "prepare_and_build_seconds": prep,
                      "neighbour_seconds": scanner.neighbour_seconds, "build_seconds": scanner.build_seconds,
                      "scan_seconds": scan.seconds, "points_out": len(scan),
                      "embree_input_bytes_per_point": scanner.nbytes / n, "peak_rss_gib": _peak_gib(),
                      "peak_above_start_gib": _peak_gib() - base, "cloud_gib": pts.nbytes / 2**30,
                      # per point: the cloud (mapped, float64), the arrays handed to Embree (float4
                      # centres and radii, float3 normals), and the rest of the peak (Embree's BVH,
                      # transients of the preparation and the scan)
                      "peak_above_start_bytes_per_point": (_peak_gib() - base) * 2**30 / n,
                      "bytes_per_point": {"cloud": pts.nbytes / n, "embree_arrays": scanner.nbytes / n,
                                          "bvh_and_transients": ((_peak_gib() - base) * 2**30 - pts.nbytes
                                                                 - scanner.nbytes) / n},
                      "retained_after_scan_gib": _rss_gib() - base}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="rect-1000")
    ap.add_argument("--resolutions", nargs="+", type=float, default=[0.0144, 0.00576])
    ap.add_argument("--settings", nargs="+", default=["footprint"], choices=["footprint", "grid", "pulse-grid", "spacing"])
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--job", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.job:
        kind, res, name = args.job
        return make_primary(args.scene, float(res)) if kind == "primary" else run_one(args.scene, float(res), name)
    rows = []
    for res in args.resolutions:
        if not cache_path(args.scene, res).exists():
            print(f"making the {res:g} deg dense primary of {args.scene} ...", file=sys.stderr)
            r = run_isolated(__file__, ["--scene", args.scene, "--job", "primary", str(res), "-"], "job", "primary")
            rows.append({"resolution": res, **r})
            print(json.dumps(rows[-1]), file=sys.stderr)
        for name in ([] if args.no_baseline else ["sort baseline"]) + args.settings:
            r = run_isolated(__file__, ["--scene", args.scene, "--job", "run", str(res), name], "setting", name)
            rows.append({"resolution": res, **r})
            print(json.dumps(rows[-1]), file=sys.stderr)
    base = {r["resolution"]: r["seconds"] for r in rows if r.get("setting") == "sort baseline" and "seconds" in r}
    for r in rows:
        if "prepare_and_build_seconds" in r and r["resolution"] in base:
            r["x_sort_baseline"] = r["prepare_and_build_seconds"] / base[r["resolution"]]
    print(f"{'res':>8} {'setting':<16} {'points':>12} {'prepare s':>10} {'x sort':>7} {'B/pt':>6} "
          f"{'peak GiB':>9} {'scan s':>7} {'out':>10}")
    for r in rows:
        if "setting" in r and "error" not in r:
            print(f"{r['resolution']:>8g} {r['setting']:<16} {r['points']:>12,} "
                  f"{r.get('prepare_and_build_seconds', r.get('seconds', 0)):>10.1f} "
                  f"{r.get('x_sort_baseline', float('nan')):>7.2f} {r.get('embree_input_bytes_per_point', 0):>6.0f} "
                  f"{r['peak_rss_gib']:>9.2f} {r.get('scan_seconds', 0):>7.2f} {r['points_out']:>10,}")
        elif "error" in r:
            print(f"{r['resolution']:>8g} {r.get('setting', r.get('job'))}: {r['error']}")
    # keep the rows of earlier runs this one did not repeat (a 0.00576 deg run takes ~20 GiB and a while)
    old = RESULTS / "bench_embree_primary.json"
    done = {(r.get("resolution"), r.get("setting", r.get("job"))) for r in rows}
    kept = []
    if old.exists():
        prev = json.loads(old.read_text())
        kept = [{**r, "measured": r.get("measured", prev.get("machine", {}).get("date"))} for r in prev["rows"]
                if (r.get("resolution"), r.get("setting", r.get("job"))) not in done]
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    rows = kept + [{**r, "measured": stamp} for r in rows]
    save("bench_embree_primary", {"inputs": vars(args), "machine": machine(), "rows": rows})


if __name__ == "__main__":
    main()
