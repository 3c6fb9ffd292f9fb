"""Question 3 without see-through: SLR scans of ray-cast (pulse-centre) primaries.

    python benchmarks/fair_q3.py [--scene rect-1000] [--positions 20] [--band 250]
                                 [--resolutions 0.0144 0.00576]

The paper's primaries keep the nearest sample of a 5 mm grid per pulse; at
0.00576 deg a fifth of rect-1000's primary lies behind another surface
(benchmarks/primary_see_through.py), so question 3 ("a finer primary removes
the effect of distance") is partly answered by points a real scanner would not
have. Here each primary is the exact ray cast of the scene mesh through every
pulse centre (mode 'center': nothing behind a surface, by construction):
1.95e9 rays at 0.00576 deg, about 1.2e9 points. It is never held in memory:
it is cast in zenith bands of ``--band`` rows, each band fed to one
:class:`slr_ray.ScanAccumulator` per secondary position (the exact binning
reduction, streamed) and written as float32 coordinates to a scratch file on
disk (12 bytes a point, deleted at the end) from which the kept points are
read back. The positions and true scans are those of the paper-size
validation (docs/validate_paper/positions/<scene>.csv, first N). Each pair
gets coverage (the paper's similarity) and precision against both truths,
next to the 5 mm dense primary's rows of docs/validate_paper/results.csv.
Saves results/fair_q3.json and results/fair_q3.png.
"""

from __future__ import annotations

import argparse
import csv
import math
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, machine, save  # noqa: E402

from slr_ray import ScanAccumulator, ScanPattern, agreement, scan_mesh  # noqa: E402
from slr_ray.scenes import scene_from_spec  # noqa: E402

DOCS = Path(__file__).resolve().parents[1] / "docs" / "validate_paper"


def _peak():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def stream_primary(scene, res, positions, secondary, band_rows, scratch: Path):
    """Cast the pulse-centre primary band by band; returns (accumulators, memmap, stats)."""
    full = ScanPattern(res)
    nv = full.n_zenith
    accs = [ScanAccumulator(p, secondary) for p in positions]
    cap = int(full.n_pulses * 0.75) + 1  # upper bound of points (a scene never fills the sky); grown if needed
    store = np.lib.format.open_memmap(scratch, mode="w+", dtype=np.float32, shape=(cap, 3))
    n = 0
    t0 = time.perf_counter()
    cast = 0.0
    for b0 in range(0, nv, band_rows):
        b1 = min(nv, b0 + band_rows)
        pat = ScanPattern(res, zenith_range=(b0 * res, min(180.0, b1 * res)))
        t1 = time.perf_counter()
        band = scan_mesh(scene, [0.0, 0.0, 0.0], pat)
        cast += time.perf_counter() - t1
        pts = band.points
        if n + len(pts) > cap:
            raise RuntimeError("scratch file too small: raise the bound")
        for a in accs:
            a.add(pts)
        store[n:n + len(pts)] = pts.astype(np.float32)
        n += len(pts)
        done = b1 / nv
        el = time.perf_counter() - t0
        print(f"\r  {res:g} deg: rows {b1:,}/{nv:,}, {n:,} points, {el:.0f} s "
              f"(eta {el / done - el:.0f} s), peak {_peak():.1f} GiB", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return accs, store, {"points": n, "seconds": time.perf_counter() - t0, "cast_seconds": cast,
                         "scratch_gib": n * 12 / 2**30}


def dense_rows(scene_name, res, n):
    rows = {}
    with open(DOCS / "results.csv", newline="") as f:
        for r in csv.DictReader(f):
            if r["scene"] == scene_name and float(r["primary_resolution"]) == res and r["backend"] == "binning" \
                    and int(r["position"]) < n:
                rows[(int(r["position"]), r["truth"])] = float(r["similarity"])
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="rect-1000")
    ap.add_argument("--positions", type=int, default=20)
    ap.add_argument("--band", type=int, default=250, help="zenith rows cast at a time")
    ap.add_argument("--resolutions", nargs="+", type=float, default=[0.0144, 0.00576])
    args = ap.parse_args(argv)
    scene = scene_from_spec(args.scene)
    positions = np.loadtxt(DOCS / "positions" / f"{Path(args.scene).stem}.csv", delimiter=",",
                           ndmin=2)[: args.positions]
    secondary = ScanPattern(0.144)
    t0 = time.perf_counter()
    truths = [{"center": scan_mesh(scene, p, secondary).points,
               "nearest": scan_mesh(scene, p, secondary, mode="nearest", supersample=3).points} for p in positions]
    print(f"true scans of {len(positions)} positions: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    rows, stats = [], {}
    for res in args.resolutions:
        with tempfile.TemporaryDirectory(prefix="slr_ray_fair_q3_") as tmp:  # outside the repository
            accs, store, st = stream_primary(scene, res, positions, secondary, args.band, Path(tmp) / "p.npy")
            stats[f"{res:g}"] = st | {"peak_rss_gib": _peak()}
            dense = dense_rows(args.scene, res, args.positions)
            for i, (p, a) in enumerate(zip(positions, accs)):
                scan = a.result()
                slr = np.asarray(store[scan.indices], np.float64)
                for sem in ("center", "nearest"):
                    ag = agreement(truths[i][sem], slr)
                    rows.append({"resolution": res, "position": i, "distance_m": float(math.hypot(*p[:2])),
                                 "truth": sem, "coverage": ag.coverage, "precision": ag.precision,
                                 "slr_points": len(scan), "dense_5mm_coverage": dense.get((i, sem))})
            del store
    for res in args.resolutions:
        for sem in ("center", "nearest"):
            rr = [r for r in rows if r["resolution"] == res and r["truth"] == sem]
            d = np.array([r["distance_m"] for r in rr])
            cov = np.array([r["coverage"] for r in rr])
            prec = np.array([r["precision"] for r in rr])
            dn = np.array([np.nan if r["dense_5mm_coverage"] is None else r["dense_5mm_coverage"] for r in rr])
            near, far = d < 17.5, d >= 17.5
            print(f"{res:g} deg, {sem:>7} truth: coverage < 17.5 m {100 * cov[near].mean():.1f} %, >= 17.5 m "
                  f"{100 * cov[far].mean():.1f} % (slope {100 * np.polyfit(d, cov, 1)[0] * 10:+.1f} /10 m); "
                  f"precision {100 * prec[near].mean():.1f} / {100 * prec[far].mean():.1f} %; 5 mm dense primary "
                  f"coverage {100 * np.nanmean(dn[near]):.1f} / {100 * np.nanmean(dn[far]):.1f} %")
    save("fair_q3", {"machine": machine(), "inputs": vars(args), "stats": stats, "rows": rows})
    plot(rows, args.resolutions, RESULTS / "fair_q3.png")


def plot(rows, resolutions, path):
    from slr_ray.plotting import save_figure
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 4.4))
    ax = fig.subplots(1, 2)
    for k, res in enumerate(resolutions):
        rr = sorted((r for r in rows if r["resolution"] == res and r["truth"] == "center"),
                    key=lambda r: r["distance_m"])
        d = [r["distance_m"] for r in rr]
        ax[0].plot(d, [100 * r["coverage"] for r in rr], "o-", c=f"C{k}", label=f"{res:g}° ray-cast primary")
        ax[0].plot(d, [100 * r["dense_5mm_coverage"] if r["dense_5mm_coverage"] is not None else np.nan
                       for r in rr], "x:", c=f"C{k}", label=f"{res:g}° 5 mm dense primary (paper)")
        ax[1].plot(d, [100 * r["precision"] for r in rr], "o-", c=f"C{k}", label=f"{res:g}° ray-cast primary")
    ax[0].set(xlabel="distance from primary scanner (m)", ylabel="coverage (similarity, %)",
              title="question 3: coverage, pulse-centre truth")
    ax[1].set(xlabel="distance from primary scanner (m)", ylabel="precision (%)",
              title="precision of the same SLR scans")
    for a in ax:
        a.axvline(17.5, ls=":", c="gray")
        a.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


if __name__ == "__main__":
    main()
