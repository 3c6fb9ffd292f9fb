"""Embree discs from each source frame's own pulse grid (`embree-sources`, slr_ray.sequence.sources)
and variants of it that were not shipped, scored as `slr-ray sequence evaluate` scores every method:

- shipped: each frame's discs from its fitted pulse grid at its origin, radii half the backend's
  (``SOURCE_RADIUS_SCALE``), one scene a frame; a target pulse's return is where its centre ray
  meets the first disc over the window's frames (the backend's tie rule within a frame, ``ties``
  3, a beam-table primary's);
- radii 0.3, 0.7 and 1 times the backend's;
- ``ties 0`` (Embree's first hit) and ``ties 6``;
- the disc's own point returned (its centre, as the ``embree-knn`` estimator returns) instead of
  where the ray meets the disc.

And where the large depth errors lie on KITTI (returns over 1 m short or long of the real frame's,
against fpa's); and on the synthetic drive (HDL-64E frames, VLP-16 targets, as convert) the seconds
to prepare one frame's scene and to cast one target's pulses into one frame's scene.

On the four KITTI frames of the project's data (frames 1 and 2 held out, +-2, at the poses
`--register` found: docs/sequence_kitti/poses.txt) and the synthetic drive (frames 4, 8, 12, 16, 20
held out, +-2, moving box left out by its labels). docs/sequences.md quotes it; writes
benchmarks/results/sequence_sources.json.

    python benchmarks/sequence_sources.py
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from common import machine, save  # puts this checkout first on the path

from slr_ray.evaluate import markdown_table, zbuffer
from slr_ray.sensors import fitted_pattern, scan_order_beams, sensor
from slr_ray.sequence import (FrameCache, accumulate, discs_of_frames, estimate, evaluate_sequence, read_sequence,
                              sources, to_frame, union, window)
from slr_ray.sequence.frames import read_file_list
from slr_ray.sequence.synthetic import synthetic_drive

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
KITTI = [f"kitti_hdl64_00000{i}.bin" for i in range(4)]
COLUMNS = ["variant", "points", "F@5cm", "F@10cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy", "cd_sum_m2",
           "seconds"]
SHIPPED = sources.cast_sources


def _centres(scanners, pose, pattern):
    pts = np.concatenate([sc.points for sc, _ in scanners if sc is not None])
    return SHIPPED(scanners, pose, pattern, centres=pts)


#: name: (tie window, radius scale, cast)
VARIANTS = {"shipped (ties 3, radii 0.5, where the ray meets the disc)": (3.0, 0.5, SHIPPED),
            "radii 0.3": (3.0, 0.3, SHIPPED), "radii 0.7": (3.0, 0.7, SHIPPED),
            "radii 1 (the backend's)": (3.0, 1.0, SHIPPED), "ties 0": (0.0, 0.5, SHIPPED),
            "ties 6": (6.0, 0.5, SHIPPED), "the disc's own point": (3.0, 0.5, _centres)}


def run(seq, holdout) -> list[dict]:
    rows = []
    for name, (ties, scale, cast) in VARIANTS.items():
        # read at call time
        sources.SOURCE_TIES, sources.SOURCE_RADIUS_SCALE, union.cast_sources = ties, scale, cast
        try:
            res = evaluate_sequence(seq, holdout, "velodyne_hdl64e_s2", ["embree-sources"], half=2)
        finally:
            sources.SOURCE_TIES, sources.SOURCE_RADIUS_SCALE, union.cast_sources = 3.0, 0.5, SHIPPED
        rows.append({"variant": name, **res["mean"][0], "seconds": res["seconds"]})
    print(markdown_table(rows, COLUMNS))
    return rows


def error_sides(seq, holdout) -> list[dict]:
    """Where the large depth errors are: per held-out frame, the pulses both images fill whose
    simulated range is over 1 m short of the real one, or over 1 m long, shipped against fpa."""
    cache, base = FrameCache(seq), sources.base_pattern("velodyne_hdl64e_s2")
    rows = []
    for t in holdout:
        fb, _ = cache.get(t)
        pat = fitted_pattern(fb.points, scan_order_beams(fb.points, base.n_beams), base)
        real = zbuffer(fb.points, pat, backend="real").range_image()["range"]
        others = window(seq, t, 2)
        u = to_frame(accumulate(seq, others, cache=cache).points, fb.pose)
        for name, ret in (("embree-sources", discs_of_frames(cache, others, fb.pose, pat, base, True, None, (t,))[0]),
                          ("fpa", estimate(u, pat, "fpa"))):
            sim = ret.image(pat)
            both = np.isfinite(real) & np.isfinite(sim)
            e = sim[both] - real[both]
            rows.append({"frame": t, "estimator": name, "pulses": int(both.sum()), "short_over_1m": int((e < -1).sum()),
                         "long_over_1m": int((e > 1).sum()), "rmse_m": float(np.sqrt(np.mean(e * e))),
                         "share_of_squared_error_short": float((e[e < -1] ** 2).sum() / (e * e).sum())})
    print(markdown_table(rows))
    return rows


def timing(seq) -> dict:
    """Seconds (wall, median over frames) to prepare one frame's scene (its fitted view and range
    image, its pulse-grid discs, its Embree scene: once while the frame is held) and to cast one
    target's VLP-16 pulses into one frame's scene (each target does it once a frame of its window)."""
    cache, base, pat = FrameCache(seq, len(seq), local=False), sources.base_pattern("velodyne_hdl64e_s2"), \
        sensor("velodyne_vlp16")
    prep, cast = [], []
    for i in range(len(seq)):
        cache.get(i)
        t0 = time.perf_counter()
        cache.discs(i, base, True)
        prep.append(time.perf_counter() - t0)
    frames = list(range(len(seq)))
    for t in range(4, len(seq) - 4, 4):
        t0 = time.perf_counter()
        discs_of_frames(cache, frames, seq.poses[t], pat, base, True)
        cast.append((time.perf_counter() - t0) / len(frames))
    out = {"frames": len(seq), "prepare_seconds_a_frame": statistics.median(prep),
           "cast_seconds_a_target_a_frame": statistics.median(cast), "load_average": os.getloadavg()[0]}
    print(out)
    return out


def main() -> None:
    out = {"machine": machine()}
    if all((DATA / k).exists() for k in KITTI):
        seq = read_file_list([DATA / k for k in KITTI], ROOT / "docs" / "sequence_kitti" / "poses.txt")
        out["kitti_errors"] = error_sides(seq, [1, 2])
        out["kitti"] = run(seq, [1, 2])
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_drive(Path(tmp) / "drive", n_frames=24, sensor="velodyne_hdl64e_s2")
        seq = read_sequence(Path(tmp) / "drive")
        out["timing"] = timing(seq)
        out["synthetic"] = run(seq, range(4, 21, 4))
    save("sequence_sources", out)


if __name__ == "__main__":
    main()
