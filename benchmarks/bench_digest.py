"""What augment's input identity costs: :func:`slr_ray.outputs.content_digest`
(BLAKE2b of the whole file) against reading the same bytes and against
decompressing the LAZ (what a run does anyway), scaled to a 1.5 GB LAZ.

    PYTHONPATH=. nice python benchmarks/bench_digest.py [--input /work/shared/data/forest_tls_riegl.laz] [--copies 40]

The input is concatenated ``--copies`` times into a temporary file (a LAZ's
bytes; hashing does not care that it is not one valid file), hashed and read
several times (medians; the file is in the page cache, so this is the CPU
cost, the floor of a cold read's disk time). LAZ decompression is timed on
the input itself, in points a second, and scaled by bytes.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import laspy

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine, save  # noqa: E402

from slr_ray.outputs import content_digest  # noqa: E402

TARGET = 1.5e9  # bytes of the LAZ the issue asks about


def _median(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--input", default="/work/shared/data/forest_tls_riegl.laz")
    ap.add_argument("--copies", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    src = Path(args.input).read_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        big = Path(tmp) / "big.bin"
        with open(big, "wb") as f:
            for _ in range(args.copies):
                f.write(src)
        size = big.stat().st_size

        def read():
            with open(big, "rb") as f:
                while f.read(1 << 22):
                    pass

        content_digest(big)  # warm the page cache
        t_digest = _median(lambda: content_digest(big), args.repeats)
        t_read = _median(read, args.repeats)
    t_laz = _median(lambda: laspy.read(args.input), max(1, args.repeats // 2))
    scale = TARGET / size
    res = {"input": args.input, "input_bytes": len(src), "hashed_bytes": size, "repeats": args.repeats,
           "digest_seconds": t_digest, "read_seconds": t_read, "digest_gb_per_s": size / t_digest / 1e9,
           "read_gb_per_s": size / t_read / 1e9,
           "digest_seconds_at_1_5_gb": t_digest * scale, "read_seconds_at_1_5_gb": t_read * scale,
           "laz_decompress_seconds": t_laz,
           "laz_decompress_seconds_at_1_5_gb": t_laz * TARGET / len(src), "machine": machine()}
    print(f"{size / 1e6:.0f} MB hashed in {t_digest:.3f} s ({res['digest_gb_per_s']:.2f} GB/s); plain read "
          f"{t_read:.3f} s ({res['read_gb_per_s']:.2f} GB/s)")
    print(f"scaled to a 1.5 GB LAZ: digest {res['digest_seconds_at_1_5_gb']:.2f} s, read "
          f"{res['read_seconds_at_1_5_gb']:.2f} s, LAZ decompression {res['laz_decompress_seconds_at_1_5_gb']:.0f} s "
          f"(digest / decompression = {res['digest_seconds_at_1_5_gb'] / res['laz_decompress_seconds_at_1_5_gb']:.1%})")
    save("bench_digest", res)


if __name__ == "__main__":
    main()
