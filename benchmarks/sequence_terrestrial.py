"""A terrestrial campaign through ``slr-ray sequence`` (#45 item 2): each held-out setup scored on its own
fitted uniform grid, not on a spinning unit's table.

The synthetic corridor of :func:`slr_ray.sequence.campaign.corridor_campaign` (24 m x 3 m, pillars,
cabinets, a door recess, a box; three setups 6 m apart, each turned by its own heading, 1.5 m above the
floor), scanned on a uniform grid of ``--resolution`` degrees (zenith 30-180 deg), 2 mm range noise.
Written in the three forms a campaign comes in (an E57 of three scans with their poses; one LAS split by
``point_source_id`` with an origins file; a LAS file a setup with an origins file), each evaluated by the
command line exactly as docs/sequences.md shows it, every setup held out in turn (from the other two):

- the E57 with every method that runs on a terrestrial scan (the table of docs/sequences.md);
- the same with ``--source-sensor velodyne_hdl64e_s2`` (the spinning path, what the command did before
  without the flag): the share of the held-out scan in that grid's view;
- the two LAS forms with ``fpa``: the same figures within the LAS files' 1 mm coordinates;
- ``sequence convert`` of the E57 to a VLP-16 at each setup.

    PYTHONPATH=. python benchmarks/sequence_terrestrial.py [--resolution 0.5]

Writes benchmarks/results/sequence_terrestrial.json (docs/sequences.md quotes it)."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import tempfile
import time
from pathlib import Path

from common import RESULTS, machine  # noqa: F401  (puts this checkout first on the path)

from slr_ray.cli import main as cli
from slr_ray.sequence.campaign import CAMPAIGN_FORMS, corridor_campaign

METHODS = ["zbuffer", "adjacent", "nearest", "fpa", "rays", "embree-knn"]
KEYS = ("F@5cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2")


def run(*args) -> tuple[dict, float]:
    """``slr-ray ARGS`` in this process: its summary (stdout's JSON line) and wall seconds."""
    out = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out):
        rc = cli([str(a) for a in args])
    if rc:
        raise SystemExit(f"slr-ray {' '.join(map(str, args))}: status {rc}")
    return json.loads(out.getvalue().strip().splitlines()[-1]), round(time.perf_counter() - t0, 1)


def evaluate(c, out, *extra) -> dict:
    summary, seconds = run("sequence", "evaluate", *c["paths"], *c["flags"], "--holdout", 0, 1, 2, "-o", out,
                           "--quiet", *extra)
    frames = json.loads((Path(out) / "evaluation.json").read_text())["frames"]
    return {"command_args": [*c["flags"], "--holdout", "0", "1", "2", *map(str, extra)], "wall_s": seconds,
            "sensor_kind": summary["sensor_kind"], "scoring_grid": summary["scoring_grid"],
            "in_view_share": summary["in_view_share"],
            "target_points": [f["target_points_in_view"] for f in frames],
            "unseen_share": [round(f["unseen_share"], 4) for f in frames],
            "method_seconds": {f["frame"]: {r["method"]: r["seconds"] for r in f["rows"]} for f in frames},
            "frames": {f["frame"]: [{"method": r["method"]} | {k: r[k] for k in ("points", *KEYS)} for r in f["table"]]
                       for f in frames},
            "mean": [{"method": r["method"]} | {k: round(r[k], 4) for k in ("points", *KEYS)} for r in summary["mean"]]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=float, default=0.5)
    a = ap.parse_args()
    load = os.getloadavg()
    res = {"machine": machine(), "load_average_before": load, "resolution_deg": a.resolution}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        c = {f: corridor_campaign(Path(tmp) / f, resolution=a.resolution, form=f) for f in CAMPAIGN_FORMS}
        res["campaign"] = {"points": c["e57"]["points"], "seconds": round(time.perf_counter() - t0, 1),
                           "poses": c["e57"]["poses"].tolist()}
        res["terrestrial"] = evaluate(c["e57"], Path(tmp) / "ev", "--methods", *METHODS)
        res["spinning_table"] = evaluate(c["e57"], Path(tmp) / "ev_hdl", "--methods", "nearest", "fpa",
                                         "--source-sensor", "velodyne_hdl64e_s2")
        for f in ("scans", "files"):
            res[f"las_{f}"] = evaluate(c[f], Path(tmp) / f"ev_{f}", "--methods", "fpa")
        conv, seconds = run("sequence", "convert", *c["e57"]["paths"], "--target-sensor", "velodyne_vlp16", "-o",
                            Path(tmp) / "cv", "--quiet")
        res["convert_vlp16"] = {"written": conv["written"], "points": conv["points"], "wall_s": seconds}
    res["load_average_after"] = os.getloadavg()
    for name in ("terrestrial", "spinning_table", "las_scans", "las_files"):
        r = res[name]
        print(f"{name}: {r['sensor_kind']} in view {r['in_view_share']} ({r['wall_s']} s)")
        for m in r["mean"]:
            print("   ", " ".join(f"{m[k]}" for k in ("method", "points", *KEYS)))
    print("convert:", res["convert_vlp16"])
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / "sequence_terrestrial.json"
    path.write_text(json.dumps(res, indent=1) + "\n")
    print("wrote", path)


if __name__ == "__main__":
    main()
