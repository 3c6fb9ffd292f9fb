"""Set the rows of two validation runs side by side, pair by pair.

Used to re-run a backend's rows of a shipped validation with today's defaults
and show old and new together (#38: the embree rows of ``validate-paper-hour``)::

    slr-ray validate benchmarks/validate_embree_hour.toml -o runs/embree-hour
    python benchmarks/compare_validation_rows.py \\
        docs/validate_paper_hour/results.csv runs/embree-hour/results.csv \\
        --backend embree --truth center

Only pairs present in both runs are compared (same scene, primary resolution,
position and truth; the positions must agree to 1 mm or the script refuses).
Prints a table per scene (mean similarity, precision, F-score and SLR points,
old and new) and saves JSON beside the other benchmark results.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from common import machine, save


def _rows(path: Path, backend: str, truth: str) -> dict:
    out = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["backend"] != backend or r["truth"] != truth:
                continue
            key = (r["scene"], float(r["primary_resolution"]), int(r["position"]))
            out[key] = r
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old", type=Path, help="results.csv of the earlier run")
    ap.add_argument("new", type=Path, help="results.csv of the re-run")
    ap.add_argument("--backend", default="embree")
    ap.add_argument("--truth", default="center")
    ap.add_argument("--name", default="validation_rows", help="JSON file name stem")
    args = ap.parse_args(argv)

    old = _rows(args.old, args.backend, args.truth)
    new = _rows(args.new, args.backend, args.truth)
    keys = sorted(set(old) & set(new))
    if not keys:
        print("no pair is in both runs", file=sys.stderr)
        return 2
    for k in keys:
        a = np.array([float(old[k][c]) for c in "xyz"])
        b = np.array([float(new[k][c]) for c in "xyz"])
        if np.abs(a - b).max() > 1e-3:
            print(f"position {k} differs between the runs: {a} vs {b}", file=sys.stderr)
            return 2

    metrics = ("similarity", "precision", "fscore", "slr_points")
    scenes = sorted({k[:2] for k in keys})
    table = []
    for scene in scenes + [("all", None)]:
        ks = [k for k in keys if scene[0] == "all" or k[:2] == scene]
        row = {"scene": scene[0], "primary_resolution": scene[1], "pairs": len(ks)}
        for m in metrics:
            o = np.array([float(old[k][m]) for k in ks])
            n = np.array([float(new[k][m]) for k in ks])
            row[f"{m}_old"] = float(o.mean())
            row[f"{m}_new"] = float(n.mean())
        row["pairs_same_points"] = int(sum(old[k]["slr_points"] == new[k]["slr_points"] for k in ks))
        table.append(row)

    print(f"{args.backend} rows, {args.truth} truth: old {args.old} / new {args.new}")
    print("| scene | pairs | similarity old → new | precision old → new | F old → new | SLR points old → new |")
    print("|---|---|---|---|---|---|")
    for r in table:
        print(
            f"| {r['scene']} | {r['pairs']} "
            f"| {100 * r['similarity_old']:.1f} → {100 * r['similarity_new']:.1f} % "
            f"| {100 * r['precision_old']:.1f} → {100 * r['precision_new']:.1f} % "
            f"| {100 * r['fscore_old']:.1f} → {100 * r['fscore_new']:.1f} % "
            f"| {r['slr_points_old']:,.0f} → {r['slr_points_new']:,.0f} |"
        )
    save(
        args.name,
        {
            "inputs": {"old": str(args.old), "new": str(args.new), "backend": args.backend, "truth": args.truth},
            "machine": machine(),
            "rows": table,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
