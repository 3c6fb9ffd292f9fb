"""Memory of the validation's whole flow for one primary, stage by stage, anonymous and file-backed.

    python benchmarks/bench_validation_memory.py [--scene rect-1000] [--resolution 0.0288]
                                                 [--positions 3] [--variants in-memory mapped]
                                                 [--memory-cap GIB]

Runs :func:`slr_ray.validation.run_validation` on one scene and one primary
resolution with the binning and embree backends (the embree options of
``validate-paper``: pulse-grid neighbours), a few positions, each variant in
a fresh process, while :mod:`memwatch` samples the process's anonymous and
file-backed resident pages (RssAnon, RssFile). Stages: the primary scan
(mesh scan, dense), the positions, the spill of the primary to a mapped file
(variant ``mapped``), each backend's preparation (the embree discs: pulse-grid
spacing and normals, radii, Embree's build) and the position loop (true
scans, SLR scans, comparisons). ``in-memory``: the primary stays a numpy
array (what the runner does while it fits in 85 % of the available memory);
``mapped``: it is always moved to a memory-mapped file first, and its pages
are released (``slr_ray.arrays.release_pages``) before Embree's build and
after each chunk a binning scan has read; ``mapped, pages kept``: mapped,
nothing released (the kernel drops such pages only under pressure).

Reports per stage the peak of each kind in GiB and in bytes a point of the
primary (above the process's memory before the run: the interpreter and the
compiled kernels), and projects the peak to the 209,188,935 points of
rect-1000's 0.00576 deg primary: ``start + bytes a point x 209.2 M``.
``--memory-cap GIB`` runs the variants in a cgroup of that limit (root; v1
or v2): a run that fits its own memory but not the mapped file's pages
beside it finishes, the kernel dropping the clean pages, and must give the
same rows (variant names get ``, capped at GIB GiB``).
Saves results/bench_validation_memory.json.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, run_isolated, save  # noqa: E402
from memwatch import MemWatch, status_kib  # noqa: E402

#: points of rect-1000's 0.00576 deg dense primary (the paper's finest)
PAPER_POINTS = 209_188_935
VARIANTS = ["in-memory", "mapped", "mapped, pages kept"]


def run_one(scene, res, positions, variant, min_ground):
    import numpy as np

    from slr_ray import ScanPattern, prepare
    from slr_ray.validation import ValidationConfig, run_validation
    from slr_ray.validation import results as vresults
    from slr_ray.validation import runner

    # compile the kernels outside the measurement (numba caches them on disk anyway)
    pts = np.random.default_rng(0).normal(size=(5000, 3)) * 10
    prepare(pts, "embree", primary_origin=[0, 0, 0], primary_resolution=1.0,
            neighbours="pulse-grid").scan([1, 0, 0], ScanPattern(5.0))
    prepare(pts, "binning").scan([1, 0, 0], ScanPattern(5.0))
    del pts
    if variant == "mapped, pages kept":  # the mapped primary without releasing its pages after reading them
        import slr_ray.backends.binning as binning_mod
        import slr_ray.raycast.scene as scene_mod

        def keep(a):
            return 0

        scene_mod.release_pages = binning_mod.release_pages = keep
    start = status_kib()
    cfg = ValidationConfig(name="memory", scenes=[scene], primary_resolutions=[res], positions=positions,
                           backends=["binning", "embree"], min_ground_points=min_ground,
                           embree_options={"neighbours": "pulse-grid"})
    out = Path(tempfile.mkdtemp(prefix="tmp_valmem_", dir=RESULTS))
    n_points = {}
    with MemWatch() as w:
        add = vresults.StageLog.add

        def logged(self, scene_, resolution, stage, seconds, count):
            add(self, scene_, resolution, stage, seconds, count)
            if stage in ("primary scan", "embree discs"):
                n_points["n"] = count
            if stage not in ("embree discs", "run"):  # the discs are marked around prepare below
                w.mark(stage)

        spill = runner.spill_primary

        def spilled(primary, folder, extra, available=None):
            w.mark("(before the spill)")
            return primary if variant == "in-memory" else spill(primary, folder, extra, 0.0)

        def prepared(points, backend, options=None, **kw):
            w.mark(f"(before {backend} prepare: true scans, earlier scans)")
            s = prepare(points, backend, options, **kw)
            extra = {}
            if hasattr(s, "build_seconds"):
                extra = {"neighbour_seconds": round(s.neighbour_seconds, 2), "build_seconds": round(s.build_seconds, 2)}
            w.mark(f"{backend} prepare", **extra)
            return s

        vresults.StageLog.add, runner.spill_primary, runner.prepare = logged, spilled, prepared
        try:
            t0 = time.perf_counter()
            summary = run_validation(cfg, out, progress=False)
            seconds = time.perf_counter() - t0
        finally:
            vresults.StageLog.add, runner.spill_primary, runner.prepare = add, spill, prepare
    stages_csv = (out / "stages.csv").read_text()
    with open(out / "results.csv", newline="") as f:  # what the variants must agree on
        rows = sorted((r["position"], r["backend"], r["truth"], r["similarity"], r["precision"], r["slr_points"])
                      for r in csv.DictReader(f))
    shutil.rmtree(out, ignore_errors=True)
    print(json.dumps({"variant": variant, "points": n_points.get("n"), "seconds": round(seconds, 1),
                      "start_gib": {k: v / 2**20 for k, v in start.items()}, "stages": w.stages,
                      "vmhwm_gib": status_kib().get("VmHWM", 0) / 2**20, "new_rows": summary["new_rows"],
                      "rows": rows, "stages_csv": stages_csv}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="rect-1000")
    ap.add_argument("--resolution", type=float, default=0.0288)
    ap.add_argument("--positions", type=int, default=3)
    ap.add_argument("--min-ground-points", type=int, default=5000,
                    help="positions' ground threshold (the paper's 50,000 leaves none on coarse primaries)")
    ap.add_argument("--variants", nargs="+", default=["in-memory", "mapped"], choices=VARIANTS)
    ap.add_argument("--memory-cap", type=float, metavar="GIB",
                    help="run each variant under a memory limit (a cgroup, v1 or v2; root): does the run fit it, "
                         "and does it give the same rows? (the kernel drops clean file pages to stay under)")
    ap.add_argument("--job", nargs=1, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.job:
        return run_one(args.scene, args.resolution, args.positions, args.job[0], args.min_ground_points)
    cap = _MemoryCap(args.memory_cap) if args.memory_cap else None
    try:
        out = _run_variants(args, cap)
    finally:
        if cap is not None:
            cap.close()
    if cap is not None:
        for r in out:
            r["memory_cap_gib"] = args.memory_cap
            r["variant"] = f"{r['variant']}, capped at {args.memory_cap:g} GiB"
    _save(args, out)


class _MemoryCap:
    """This process and its children in a cgroup limited to ``gib`` (v1 ``memory`` or v2 ``memory.max``)."""

    def __init__(self, gib: float):
        import os

        limit = str(int(gib * 2**30))
        v1 = Path("/sys/fs/cgroup/memory")
        if v1.is_dir():
            self.root = v1
            self.dir = v1 / f"slr_ray_cap_{os.getpid()}"
            self.dir.mkdir()
            (self.dir / "memory.limit_in_bytes").write_text(limit)
        else:
            self.root = Path("/sys/fs/cgroup")
            self.dir = self.root / f"slr_ray_cap_{os.getpid()}"
            self.dir.mkdir()
            (self.dir / "memory.max").write_text(limit)
            (self.dir / "memory.swap.max").write_text("0")
        (self.dir / "cgroup.procs").write_text(str(os.getpid()))
        print(f"memory capped at {gib:g} GiB ({self.dir})")

    def close(self) -> None:
        import os

        (self.root / "cgroup.procs").write_text(str(os.getpid()))
        self.dir.rmdir()


def _run_variants(args, cap):
    out = []
    for v in args.variants:
        r = run_isolated(__file__, ["--scene", args.scene, "--resolution", str(args.resolution), "--positions",
                                    str(args.positions), "--min-ground-points", str(args.min_ground_points),
                                    "--job", v], "variant", v)
        out.append(r)
        if "error" in r:
            print(f"{v}: {r['error']}")
            continue
        n, s0 = r["points"], r["start_gib"]
        base = {"anon_gib": s0.get("RssAnon", 0), "file_gib": s0.get("RssFile", 0), "total_gib": s0.get("VmRSS", 0)}
        print(f"\n{v}: {n:,} points, {r['seconds']} s, VmHWM {r['vmhwm_gib']:.2f} GiB "
              f"(start: anon {base['anon_gib']:.2f}, file {base['file_gib']:.2f} GiB)")
        print(f"  {'stage':<58} {'s':>7} {'anon GiB':>9} {'file GiB':>9} {'total':>7} "
              f"{'anon B/pt':>9} {'total B/pt':>10}")
        for st in r["stages"]:
            st["anon_bytes_per_point"] = (st["anon_gib"] - base["anon_gib"]) * 2**30 / n
            st["total_bytes_per_point"] = (st["total_gib"] - base["total_gib"]) * 2**30 / n
            print(f"  {st['stage'][:58]:<58} {st['seconds']:>7.1f} {st['anon_gib']:>9.2f} {st['file_gib']:>9.2f} "
                  f"{st['total_gib']:>7.2f} {st['anon_bytes_per_point']:>9.1f} {st['total_bytes_per_point']:>10.1f}")
        peak_anon = max(st["anon_bytes_per_point"] for st in r["stages"])
        peak_total = max(st["total_bytes_per_point"] for st in r["stages"])
        r["projection_gib"] = {"anon": base["anon_gib"] + peak_anon * PAPER_POINTS / 2**30,
                               "total": base["total_gib"] + peak_total * PAPER_POINTS / 2**30}
        r["peak_bytes_per_point"] = {"anon": peak_anon, "total": peak_total}
        print(f"  peak: anon {peak_anon:.1f} B/pt, total {peak_total:.1f} B/pt; projected to {PAPER_POINTS:,} "
              f"points: anon {r['projection_gib']['anon']:.2f} GiB, total {r['projection_gib']['total']:.2f} GiB")
    if len(out) > 1 and all("rows" in r for r in out):
        same = all(r["rows"] == out[0]["rows"] for r in out)
        print(f"\nsame rows in every variant: {same}")
    return out


def _save(args, out):
    # keep the runs of earlier calls at other resolutions or variants (each says when it was measured)
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    for r in out:
        r.update(resolution=args.resolution, measured=stamp)
    old = RESULTS / "bench_validation_memory.json"
    done = {(args.resolution, r.get("variant")) for r in out}
    kept = [r for r in json.loads(old.read_text()).get("runs", []) if (r.get("resolution"), r.get("variant")) not in done
            ] if old.exists() else []
    save("bench_validation_memory", {"inputs": vars(args), "machine": machine(), "runs": kept + out})


if __name__ == "__main__":
    main()
