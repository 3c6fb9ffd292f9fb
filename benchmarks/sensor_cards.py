"""Sensor cards fitted from the real frames of ../shared/data, against each unit's own table (#45).

For every unit with frames there: the card fitted with its ring field (where the frames have one)
and from the points alone; its fit quality (median angle of the points off their beam, share of points
assigned); and, where the unit has a table of its own (Ouster metadata; the shipped Velodyne tables,
KITTI's HDL-64E against the shipped S2 and S3 calibrations of two other units), the median and largest
difference of the fitted elevations from the table's (each fitted beam against the table's nearest).
Frames that are not a spinning unit's (the AT128, the forest TLS, the airborne tile) are refused, and
the refusal is printed.

    python benchmarks/sensor_cards.py            # prints the table, saves benchmarks/results/sensor_cards.json
    python benchmarks/sensor_cards.py --ship     # also writes the fitted cards of the Apache-2.0 frames to
                                                 # slr_ray/data/sensors/ (never over a file)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from common import machine, save

from slr_ray.errors import SlrNote
from slr_ray.sensorfit import fit_card
from slr_ray.sensors import SENSORS_DIR, card_dict, sensor

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
if not DATA.is_dir():
    DATA = Path("/work/shared/data")
NEBULA = "tier4/nebula @606ac41, decoder ground-truth PCD {} (Apache-2.0)"
PJLAB = "PJLab-ADG/SensorsCalibration @7fe8d46, {} (Apache-2.0)"

#: (key, frames, ring, table to compare with, shipped card name or None, source text)
UNITS = [
    ("ouster_os1_128 (rings)", ["ouster_os1_128/os1_128_frame0*.npz"], "auto",
     "ouster_os1_128/OS-1-128_v2.3.0_1024x10.json", None, None),
    ("ouster_os1_128 (points)", ["ouster_os1_128/os1_128_frame0*.npz"], False,
     "ouster_os1_128/OS-1-128_v2.3.0_1024x10.json", None, None),
    ("velodyne_vlp16 (rings)", ["single_frames/velodyne_vlp16_*.pcd"], "auto", "velodyne_vlp16", None, None),
    ("velodyne_vlp16 (points)", ["single_frames/velodyne_vlp16_*.pcd"], False, "velodyne_vlp16", None, None),
    ("velodyne_vlp32c (points)", ["single_frames/velodyne_vlp32_*.pcd"], "auto", "velodyne_vlp32c", None, None),
    ("kitti hdl64e vs s2 (scan order)", ["kitti_hdl64_00000*.bin"], "auto", "velodyne_hdl64e_s2", None, None),
    ("kitti hdl64e vs s3 (scan order)", ["kitti_hdl64_00000*.bin"], "auto", "velodyne_hdl64e_s3", None, None),
    ("kitti hdl64e vs s3 (points)", ["kitti_hdl64_00000*.bin"], False, "velodyne_hdl64e_s3", None, None),
    ("hesai_pandar40p (points)", ["single_frames/hesai_40p_*.pcd"], "auto", None, "hesai_pandar40p", NEBULA),
    ("hesai_pandar64 (points)", ["single_frames/hesai_64_*.pcd"], "auto", None, "hesai_pandar64", NEBULA),
    ("hesai_at128 (points)", ["single_frames/hesai_at128_*.pcd"], "auto", None, None, NEBULA),
    ("hesai_ot128 (points)", ["single_frames/hesai_ot128_*.pcd"], "auto", None, "hesai_ot128", NEBULA),
    ("hesai_qt128 (points)", ["single_frames/hesai_qt128_*.pcd"], "auto", None, "hesai_pandarqt128", NEBULA),
    ("hesai_qt64 (points)", ["single_frames/hesai_qt64_*.pcd"], "auto", None, "hesai_pandarqt64", NEBULA),
    ("hesai_xt16 (points)", ["single_frames/hesai_xt16_*.pcd"], "auto", None, "hesai_xt16", NEBULA),
    ("hesai_xt32m (points)", ["single_frames/hesai_xt32m_*.pcd"], "auto", None, None, NEBULA),
    ("hesai_pandar64 seq (rings)", ["hesai_p64_seq/*.pcd"], "auto", "hesai_pandar64 (points)",
     "hesai_pandar64_pjlab", PJLAB),
    ("hesai_pandar64 rig (rings)", ["hesai_p64_qt64/p64.pcd"], "auto", "hesai_pandar64 (points)", None, PJLAB),
    ("hesai_qt64 rig (points)", ["hesai_p64_qt64/qt.pcd"], "auto", "hesai_qt64 (points)", "hesai_pandarqt64_pjlab",
     PJLAB),
    ("balm os0-64-like (points; GPL-2 data, not shipped)", ["balm_os0_64/full2*.pcd"], "auto", None, None, None),
    ("forest TLS (not spinning)", ["forest_tls_riegl.laz"], "auto", None, None, None),
    ("airborne LAS (not spinning)", ["autzen_als_classified.las"], "auto", None, None, None),
]


def compare(card, table) -> dict:
    t = np.asarray(table.elevation_deg)
    d = np.array([np.min(np.abs(t - e)) for e in card.elevation_deg])
    return {"median_deg": round(float(np.median(d)), 4), "max_deg": round(float(d.max()), 4),
            "table_beams": table.n_beams}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ship", action="store_true", help="write the Apache-2.0 units' cards to slr_ray/data/sensors")
    args = ap.parse_args()
    rows, cards = [], {}
    for key, globs, ring, against, ship, source in UNITS:
        files = sorted(p for g in globs for p in DATA.glob(g))
        if not files:
            print(f"{key}: absent", file=sys.stderr)
            continue
        t0 = time.perf_counter()
        row = {"unit": key, "frames": [f.relative_to(DATA).as_posix() for f in files]}
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SlrNote)
                src = None if source is None else source.format(", ".join(row["frames"]))
                card = fit_card(files, ring=ring, name=ship or key.split(" ")[0], source=src)
        except ValueError as exc:
            row["refused"] = str(exc).split("(", 1)[-1].rsplit(")", 1)[0]
            rows.append(row)
            continue
        cards[key] = card
        q = card.meta["fit"]
        row.update(beams=card.n_beams, columns=card.columns, how=q["how"], off_beam_deg=q["median_off_beam_deg"],
                   assigned=q["share_assigned"], elevation_range_deg=[min(card.elevation_deg),
                                                                       max(card.elevation_deg)],
                   seconds=round(time.perf_counter() - t0, 2))
        if against:
            table = cards.get(against) or sensor(against if not against.endswith(".json") else str(DATA / against))
            row["against"] = against
            row.update(compare(card, table))
        rows.append(row)
        if args.ship and ship:
            path = SENSORS_DIR / f"{ship}.json"
            if path.exists():
                print(f"{path} exists: not written", file=sys.stderr)
            else:
                d = card_dict(card)
                # the ranges a bench frame saw (a room, a box) are not the unit's: the card says them, sets none
                d["ranges_seen_m"] = [d.pop("min_range_m"), d.pop("max_range_m")]
                d["notes"] = ("fitted by `slr-ray sensor fit` (benchmarks/sensor_cards.py) from the frames named in "
                              "source: the beams that returned points, at distinct elevations (a beam that returned "
                              "nothing, or shares another's elevation, is not in the card); no range limits (the "
                              "frame's, ranges_seen_m, are a test bench's: --min-range/--max-range set the unit's)")
                path.write_text(json.dumps(d, indent=1) + "\n")
                print(f"wrote {path}", file=sys.stderr)
    print(f"| unit | beams | columns | median off beam | assigned | against | median diff | max diff |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "refused" in r:
            print(f"| {r['unit']} | refused: {r['refused']} | | | | | | |")
        else:
            print(f"| {r['unit']} | {r['beams']} | {r['columns']} | {r['off_beam_deg']:.4f}° | {r['assigned']:.1%} "
                  f"| {r['against'] + ' (%d beams)' % r['table_beams'] if 'against' in r else ''} | "
                  f"{'%.4f°' % r['median_deg'] if 'median_deg' in r else ''} | "
                  f"{'%.4f°' % r['max_deg'] if 'max_deg' in r else ''} |")
    save("sensor_cards", {"machine": machine(), "rows": rows})


if __name__ == "__main__":
    main()
