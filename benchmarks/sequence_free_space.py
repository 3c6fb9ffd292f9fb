"""Moving objects found without labels by free space (an experiment, not shipped): a point of frame
s is flagged when, seen from another frame f of its window, its pulse and the four pulses beside it
all return from more than ``margin`` metres beyond it in f's own range image (f saw through where
the point was), in at least ``need`` other frames. Scored against the synthetic drive's labels
(one box driving 1.5 m a frame ahead of the sensor; `slr_ray.sequence.synthetic`): recall and
precision of the moving points, frames 2 to 21 of 24, each against the frames within +-2.
docs/sequences.md quotes it; writes benchmarks/results/sequence_free_space.json.

    python benchmarks/sequence_free_space.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from common import machine, save  # puts this checkout first on the path

from slr_ray.evaluate import markdown_table
from slr_ray.sensors import sensor
from slr_ray.sequence import MOVING_CLASSES, FrameCache, read_sequence, to_frame, window
from slr_ray.sequence.synthetic import synthetic_drive


def seen_through_votes(w, others, images, poses, pat, margin):
    """Per point of ``w`` (world), the frames of ``others`` that saw through it."""
    rows, cols = pat.shape
    votes = np.zeros(len(w), np.int64)
    for f in others:
        keys, r = pat.pulse_ids(to_frame(w, poses[f]), np.zeros(3))
        free = keys >= 0
        v, h = keys // cols, keys % cols
        for dv, dh in ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)):
            val = images[f][np.clip(v + dv, 0, rows - 1), (h + dh) % cols]
            free &= np.isfinite(val) & (val > r + margin)
        votes += free
    return votes


def main() -> None:
    pat = sensor("velodyne_hdl64e_s2")
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_drive(Path(tmp) / "drive", n_frames=24, sensor="velodyne_hdl64e_s2")
        seq = read_sequence(Path(tmp) / "drive")
        cache = FrameCache(seq, 24)
        images = {}
        for f in range(len(seq)):
            fr, w = cache.get(f)
            keys, r, _ = pat.reduce(fr.points, np.zeros(3))
            img = np.full(pat.n_pulses, np.nan)
            img[keys] = r
            images[f] = img.reshape(pat.shape)
        settings = [(m, n) for m in (0.3, 1.0) for n in (1, 2)]
        counts = {s: [0, 0, 0] for s in settings}  # flagged moving, flagged static, moving missed
        for s in range(2, 22):
            fr, w = cache.get(s)
            moving = np.isin(fr.attributes["semantic"], MOVING_CLASSES)
            for margin in (0.3, 1.0):
                votes = seen_through_votes(w, window(seq, s, 2), images, seq.poses, pat, margin)
                for need in (1, 2):
                    flag = votes >= need
                    c = counts[(margin, need)]
                    c[0] += int((flag & moving).sum())
                    c[1] += int((flag & ~moving).sum())
                    c[2] += int((~flag & moving).sum())
    rows = [{"margin_m": m, "frames_needed": n, "recall": tp / (tp + fn), "precision": tp / max(tp + fp, 1),
             "flagged": tp + fp, "moving": tp + fn} for (m, n), (tp, fp, fn) in counts.items()]
    print(markdown_table(rows))
    save("sequence_free_space", {"machine": machine(), "rows": rows})


if __name__ == "__main__":
    main()
