"""The direction map of a ray cast (slr_ray.raycast.cull): its cost, what it leaves to Embree, what it saves.

    python benchmarks/bench_cull.py [--rounds 7]

On the discs of ``bench_pcu.py`` (5 M points of the benchmark cloud, their
radii and normals, 3.1 M pulse rays of 0.144 deg): the voxel boxes (count,
seconds to make), the map from bench_pcu's origin 14 m outside and from
inside the cloud (milliseconds, fraction of cells marked, rays left for
Embree), and casts with the map and without (``cull=False``, the reference:
the same answers) taken in turn, with and without the tie rule, on one thread
(CPU time of the casting thread) and on the default threads (wall-clock);
medians of ``--rounds``. Then the boxes and maps of the whole 29 M-point
cloud. Saves results/bench_cull.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_pcu import ORIGIN, inputs  # noqa: E402
from common import machine, realistic_cloud, save  # noqa: E402

from slr_ray import ScanPattern  # noqa: E402
from slr_ray.pattern import pulse_rays  # noqa: E402
from slr_ray.raycast import RayScene  # noqa: E402
from slr_ray.raycast.cull import FACE, could_hit, direction_map, voxel_boxes  # noqa: E402

INSIDE = np.array([0.0, 0.0, 1.5])


def _median_ms(fn, rounds=7):
    fn()
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _maps(boxes, centre, dirs=None):
    out = {}
    for name, o in (("outside, 14 m", ORIGIN), ("inside", INSIDE)):
        local = (o - centre).astype(np.float32).astype(np.float64)
        dmap = direction_map(boxes, local, FACE)
        row = {"map_ms": _median_ms(lambda: direction_map(boxes, local, FACE)), "marked": float(dmap.mean())}
        if dirs is not None:
            row["rays_left"] = int(sum(could_hit(dmap, FACE, *d) for d in dirs[::16]) * 16)
        out[name] = row
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args(argv)
    pts, radii, normals = inputs(5_000_000)
    dirs, _, _ = pulse_rays(ScanPattern(0.144))
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    scene = RayScene.discs(pts, radii, normals, centre=centre)
    vbuf = scene._buffers[0][4]
    res = {"discs": len(pts), "rays": len(dirs), "boxes": len(scene._cull_boxes),
           "boxes_ms": _median_ms(lambda: voxel_boxes(vbuf, None, len(pts)), 3),
           "maps": _maps(scene._cull_boxes, centre, dirs)}
    print(f"{len(pts):,} discs: {res['boxes']:,} voxel boxes in {res['boxes_ms']:.0f} ms", flush=True)
    for name, row in res["maps"].items():
        print(f"  from {name}: map {row['map_ms']:.2f} ms, {100 * row['marked']:.0f} % of cells marked, "
              f"~{row['rays_left']:,} of {len(dirs):,} rays left for Embree", flush=True)
    casts = {}
    for origin_name, o in (("outside", ORIGIN), ("inside", INSIDE)):
        for threads, clock in ((1, time.thread_time), (None, time.perf_counter)):
            for ties in (1.0, 0.0):
                kw = dict(ties=ties, n_threads=threads)
                if origin_name == "inside":
                    kw.update(skip_containing=True, pulse_aspect=1.0)  # as the embree backend casts
                a, b = scene.intersect(o, dirs, **kw), scene.intersect(o, dirs, cull=False, **kw)
                same = all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("owners", "distances"))
                t = {True: [], False: []}
                for _ in range(args.rounds):
                    for cull in (True, False):
                        t0 = clock()
                        scene.intersect(o, dirs, cull=cull, **kw)
                        t[cull].append(clock() - t0)
                key = f"{origin_name}, {'1 thread CPU' if threads == 1 else 'default threads wall'}, " \
                      f"{'ties' if ties else 'no ties'}"
                casts[key] = {"map_s": float(np.median(t[True])), "no_map_s": float(np.median(t[False])),
                              "same_answers": bool(same)}
                print(f"  {key}: {casts[key]['map_s']:.3f} s with the map, {casts[key]['no_map_s']:.3f} s "
                      f"without, same answers: {same}", flush=True)
    res["casts"] = casts
    cloud = np.asarray(realistic_cloud())
    c29 = 0.5 * (cloud.min(axis=0) + cloud.max(axis=0))
    v29 = np.empty((len(cloud), 4), np.float32)
    v29[:, :3] = cloud - c29
    v29[:, 3] = 0.01
    boxes29 = voxel_boxes(v29, None, len(cloud))
    res["cloud_29m"] = {"points": len(cloud), "boxes": len(boxes29),
                        "boxes_ms": _median_ms(lambda: voxel_boxes(v29, None, len(cloud)), 3),
                        "maps": _maps(boxes29, c29)}
    r = res["cloud_29m"]
    print(f"{len(cloud):,} points (radius 1 cm): {r['boxes']:,} voxel boxes in {r['boxes_ms']:.0f} ms; "
          + "; ".join(f"from {k}: map {v['map_ms']:.2f} ms, {100 * v['marked']:.0f} % marked"
                      for k, v in r["maps"].items()))
    save("bench_cull", {"machine": machine(), "inputs": vars(args), **res})


if __name__ == "__main__":
    main()
