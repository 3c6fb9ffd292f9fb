"""Every LAS/LAZ test file of the laspy project through `slr-ray scan`: nothing lost.

    python benchmarks/check_laspy_files.py [--data DIR]

Downloads laspy's source distribution (PyPI) unless ``--data`` names its
``tests/data`` folder, then for each .las/.laz file: ``slr-ray scan FILE
--origin <centre of its bounds> --resolution 1 -o out.<same ext>`` and checks
the output against the input: LAS version, point format, global encoding,
every VLR (user id, record id, payload) except COPC's (dropped on purpose)
and the ExtraBytes description (which gains the added 'range' dimension),
every EVLR, and the raw point records of the kept points byte for byte. Prints a table and saves
results/check_laspy_files.json.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

VERSION = "2.5.4"


def data_dir(tmp: Path) -> Path:
    subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:",
                    f"laspy=={VERSION}", "-d", str(tmp), "-q"], check=True)
    with tarfile.open(next(tmp.glob("laspy-*.tar.gz"))) as tar:
        members = [m for m in tar.getmembers() if "/tests/data/" in m.name]
        tar.extractall(tmp, members=members, filter="data")
    return next(tmp.glob("laspy-*/tests/data"))


def payload(v):
    try:
        return bytes(v.record_data_bytes())
    except Exception:  # noqa: BLE001 - some known VLRs only parse
        return None


def check(path: Path, out_dir: Path) -> dict:
    import laspy

    src = laspy.read(str(path))
    h = src.header
    origin = (np.asarray(h.mins) + np.asarray(h.maxs)) / 2
    out = out_dir / ("out" + path.suffix.lower())
    res = subprocess.run([sys.executable, "-m", "slr_ray.cli", "scan", str(path), "--origin", *map(str, origin),
                          "--resolution", "1", "--keep-range", "--quiet", "--force", "-o", str(out)],
                         capture_output=True, text=True)
    row = {"file": path.name, "version": str(h.version), "point_format": h.point_format.id, "points": len(src)}
    if res.returncode:
        return row | {"ok": False, "error": res.stderr.strip().splitlines()[-1]}
    got = laspy.read(str(out))
    idx = None
    # the kept points: match raw records of the output to the input's by their full bytes
    std = [n for n in got.points.array.dtype.names if n in src.points.array.dtype.names]
    from numpy.lib.recfunctions import repack_fields

    got_sub = np.ascontiguousarray(repack_fields(got.points.array[std]))
    src_sub = np.ascontiguousarray(repack_fields(src.points.array[std]))
    pos = {b: i for i, b in enumerate(src_sub.view(np.dtype((np.void, src_sub.dtype.itemsize)))
                                      .ravel().tolist())}
    idx = [pos.get(b) for b in got_sub.view(np.dtype((np.void, got_sub.dtype.itemsize))).ravel().tolist()]
    # COPC records are dropped on purpose; the ExtraBytes VLR changes because --keep-range adds 'range'
    copc = lambda vs: [v for v in vs if str(v.user_id).strip().lower() != "copc"  # noqa: E731
                       and (str(v.user_id).strip(), v.record_id) != ("LASF_Spec", 4)]
    checks = {
        "same_version": str(got.header.version) == str(h.version),
        "same_point_format": got.header.point_format.id == h.point_format.id,
        "same_global_encoding": int(got.header.global_encoding.value) == int(h.global_encoding.value),
        "same_vlrs": [(v.user_id, v.record_id, payload(v)) for v in copc(got.header.vlrs)]
        == [(v.user_id, v.record_id, payload(v)) for v in copc(h.vlrs)],
        "same_evlrs": [(v.user_id, v.record_id) for v in copc(got.evlrs or [])]
        == [(v.user_id, v.record_id) for v in copc(src.evlrs or [])],
        "records": None not in idx and len(got) > 0,
        "range_added": "range" in got.point_format.extra_dimension_names,
    }
    return row | {"ok": all(checks.values()), "kept": len(got), **checks}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        data = args.data or data_dir(tmp)
        rows = [check(p, tmp) for p in sorted(data.iterdir()) if p.suffix.lower() in (".las", ".laz")]
    for r in rows:
        bad = [k for k in ("same_version", "same_point_format", "same_global_encoding", "same_vlrs", "same_evlrs",
                           "records", "range_added") if r.get(k) is False]
        print(f"{r['file']:<45} {r['version']} pf{r['point_format']:<3} {'ok' if r['ok'] else 'FAIL'} "
              f"{r.get('error', '') or ' '.join(bad)}")
    print(f"{sum(r['ok'] for r in rows)} of {len(rows)} files pass")
    save("check_laspy_files", {"machine": machine(), "laspy_version": VERSION, "rows": rows})


if __name__ == "__main__":
    main()
