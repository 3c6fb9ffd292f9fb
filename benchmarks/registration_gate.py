"""Registration figures of real overlapping frames against unrelated pairs (issue #48, item 8).

:func:`slr_ray.registration.register` aligns any two clouds: a KITTI street frame registered onto an
indoor scan came out at fitness 0.47-0.59 and inlier RMSE 0.09 m, which the old bounds (fitness
>= 0.3, RMSE <= 0.12 m) accepted. This script registers, as ``slr-ray evaluate`` and ``sequence
--register`` do (B onto A), pairs that overlap (consecutive KITTI frames and 0 -> 3, the Hesai
Pandar64 sequence, the BALM OS0-64 sequence) and pairs that do not (a KITTI frame onto the indoor
pump scan, onto the forest scan, ...), and prints every figure the library's gate
(:func:`slr_ray.registration.registration_checks`) tests, and which checks refuse each pair, so
that its bounds (:data:`slr_ray.registration.REGISTRATION_BOUNDS`) keep their margins from measured
figures. Two pairs are "moved copies": a KITTI frame turned and moved far onto its neighbour; the
same scene, whose registration finds the turn and the move (it is right, and accepted: the gate
refuses what does not overlap, not large motions).

Run: ``PYTHONPATH=. nice python benchmarks/registration_gate.py`` from the repository root (a few
minutes on two cores). ``--data`` names the folder of the shared samples (default
``../shared/data``, else /work/shared/data); files that are absent or do not read are reported and
skipped. Saves benchmarks/results/registration_gate.json.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save  # noqa: E402

from slr_ray.registration import REGISTRATION_BOUNDS, register, registration_checks  # noqa: E402
from slr_ray.io import read_cloud  # noqa: E402


def _data_dir(given):
    for d in ([given] if given else []) + [Path(__file__).resolve().parents[1] / ".." / "shared" / "data",
                                            Path("/work/shared/data")]:
        if Path(d).is_dir():
            return Path(d)
    return None


def _turned(points, deg, shift):
    a = math.radians(deg)
    R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    return points @ R.T + np.asarray(shift, float)


def _subsample(points, n, seed=0):
    if len(points) <= n:
        return points
    return points[np.sort(np.random.default_rng(seed).choice(len(points), n, replace=False))]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", help="folder of the shared samples")
    args = ap.parse_args(argv)
    data = _data_dir(args.data)
    if data is None:
        sys.exit("no data folder: give --data")
    cache, skipped = {}, []

    def cloud(name):
        if name not in cache:
            path = data / name
            try:
                pts = read_cloud(path).points
            except Exception as e:  # noqa: BLE001 - a sample that does not read is reported and skipped
                skipped.append(f"{name}: {type(e).__name__}: {e}")
                pts = None
            cache[name] = pts
        return cache[name]

    kitti = [f"kitti_hdl64_00000{i}.bin" for i in range(4)]
    hesai = sorted(p.name for p in (data / "hesai_p64_seq").glob("*.pcd"))
    balm = [f"full{i}.pcd" for i in range(20, 30)]
    pairs = []  # (kind, label, A loader, B loader)
    for i, j in ((0, 1), (1, 2), (2, 3), (0, 3)):
        pairs.append(("overlap", f"KITTI {j} onto {i}", lambda i=i: cloud(kitti[i]), lambda j=j: cloud(kitti[j])))
    for i in range(len(hesai) - 1):
        pairs.append(("overlap", f"Hesai P64 {i + 1} onto {i}", lambda i=i: cloud(f"hesai_p64_seq/{hesai[i]}"),
                      lambda i=i: cloud(f"hesai_p64_seq/{hesai[i + 1]}")))
    for i in range(0, len(balm) - 1, 3):  # 20->21, 23->24, 26->27, 29 alone: three of nine pairs (time)
        pairs.append(("overlap", f"BALM OS0-64 {balm[i + 1]} onto {balm[i]}",
                      lambda i=i: cloud(f"balm_os0_64/{balm[i]}"), lambda i=i: cloud(f"balm_os0_64/{balm[i + 1]}")))
    forest = lambda: None if cloud("forest_tls_riegl.laz") is None else _subsample(cloud("forest_tls_riegl.laz"), 150_000)  # noqa: E731
    pairs += [
        ("unrelated", "KITTI 0 onto pump (indoor TLS)", lambda: cloud("pump_tls.e57"), lambda: cloud(kitti[0])),
        ("unrelated", "KITTI 1 onto pump (indoor TLS)", lambda: cloud("pump_tls.e57"), lambda: cloud(kitti[1])),
        ("unrelated", "pump onto KITTI 0", lambda: cloud(kitti[0]), lambda: cloud("pump_tls.e57")),
        ("unrelated", "KITTI 0 onto forest (150k of the TLS scan)", forest, lambda: cloud(kitti[0])),
        ("unrelated", "forest (150k) onto KITTI 0", lambda: cloud(kitti[0]), forest),
        ("moved copy", "KITTI 1 onto KITTI 0 turned 90 deg, moved 60 m", lambda: cloud(kitti[0]),
         lambda: _turned(cloud(kitti[1]), 90, (60, 0, 0))),
        ("moved copy", "KITTI 1 onto KITTI 0 turned 180 deg, moved 40 m", lambda: cloud(kitti[0]),
         lambda: _turned(cloud(kitti[1]), 180, (0, 40, 0))),
        ("unrelated", "Hesai P64 0 onto KITTI 0", lambda: cloud(kitti[0]), lambda: cloud(f"hesai_p64_seq/{hesai[0]}")),
        ("unrelated", "BALM full20 onto KITTI 0", lambda: cloud(kitti[0]), lambda: cloud("balm_os0_64/full20.pcd")),
        ("unrelated", "KITTI 0 onto BALM full25", lambda: cloud("balm_os0_64/full25.pcd"), lambda: cloud(kitti[0])),
        ("unrelated", "Hesai P64 0 onto BALM full20", lambda: cloud("balm_os0_64/full20.pcd"),
         lambda: cloud(f"hesai_p64_seq/{hesai[0]}")),
    ]
    rows = []
    for kind, label, la, lb in pairs:
        a, b = la(), lb()
        if a is None or b is None:
            print(f"skipped {label}: a file did not read", file=sys.stderr)
            continue
        t0 = time.perf_counter()
        reg = register(b, a)
        failed = registration_checks(reg)
        row = {"kind": kind, "pair": label, "points_a": len(a), "points_b": len(b)} | reg.to_dict()
        row.pop("transform")
        row["failed_checks"] = [name for name, _ in failed]
        row["wall_s"] = round(time.perf_counter() - t0, 2)
        rows.append(row)
        print(f"{kind:10s} {label:50s} fit {reg.fitness:.3f} rev {reg.reverse_fitness:.3f} rmse {reg.inlier_rmse:.3f} "
              f"rot {row['rotation_deg']:6.1f} tilt {reg.tilt_deg:5.1f} t {row['translation_norm_m']:7.2f} "
              f"{reg.init:11s} failed {row['failed_checks']}", flush=True)
    for s in skipped:
        print("skipped:", s, file=sys.stderr)
    print("\n| kind | pair | fitness | reverse fitness | inlier RMSE (m) | rotation (deg) | tilt (deg) | "
          "translation (m) | init | refused by |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['kind']} | {r['pair']} | {r['fitness']:.3f} | {r['reverse_fitness']:.3f} | "
              f"{r['inlier_rmse_m']:.3f} | {r['rotation_deg']:.1f} | {r['tilt_deg']:.1f} | "
              f"{r['translation_norm_m']:.2f} | {r['init']} | {', '.join(r['failed_checks']) or '-'} |")
    save("registration_gate", {"machine": machine(), "bounds": dict(REGISTRATION_BOUNDS), "rows": rows,
                               "skipped": skipped})


if __name__ == "__main__":
    main()
