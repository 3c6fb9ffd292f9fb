"""Where `sequence convert`'s time goes, stage by stage (imported by bench_sequence.py --stages).

One conversion run in this process, one worker (the stages of a frame are the same in a pool's
worker), with each stage's function wrapped: its wall and CPU seconds (``time.process_time``: all of
the process's threads, Embree's and numba's included) *exclusive* of the stages it calls (reading a
frame inside a mesh's build counts as reading), over the frames converted. ``other`` is the
conversion's total less the stages: the loop, the estimator's own glue.

Stages: ``start`` (before the first frame: the settings, the inputs' digests, the resume check, the
manifest), ``read`` (a frame from its file, moved into the world frame), ``select`` (the points a
union keeps), ``beams`` (a frame's rings, its own axes), ``mesh`` (its ring mesh and Embree scene),
``union`` (the window's points and attributes gathered), ``to_frame`` (the union moved into the
target's frame), ``cast`` (the target's rays cast into the window's meshes), ``fill``, ``write``
(the frame's files), ``publish`` (its final names, after the journal), ``reach`` (the beams the
source saw, once at the end).
"""

from __future__ import annotations

import os
import resource
import time
from contextlib import contextmanager

STAGES = ("start", "read", "select", "beams", "mesh", "union", "to_frame", "cast", "fill", "write", "publish",
          "reach", "other")


class Stages:
    """Exclusive wall and CPU seconds by stage (a stack of the stages running)."""

    def __init__(self):
        self.wall = dict.fromkeys(STAGES, 0.0)
        self.cpu = dict.fromkeys(STAGES, 0.0)
        self.calls = dict.fromkeys(STAGES, 0)
        self._stack = []  # [wall, cpu] spent in the callees of each running stage

    def wrap(self, owner, name, stage):
        f = getattr(owner, name)

        def timed(*a, **k):
            self._stack.append([0.0, 0.0])
            w0, c0 = time.perf_counter(), time.process_time()
            try:
                return f(*a, **k)
            finally:
                w, c = time.perf_counter() - w0, time.process_time() - c0
                inner = self._stack.pop()
                self.wall[stage] += w - inner[0]
                self.cpu[stage] += c - inner[1]
                self.calls[stage] += 1
                if self._stack:
                    self._stack[-1][0] += w
                    self._stack[-1][1] += c

        setattr(owner, name, timed)
        return f

    def mark(self, stage, wall, cpu):
        self.wall[stage] += wall
        self.cpu[stage] += cpu


@contextmanager
def staged(seq):
    """The conversion's stage functions wrapped (restored after)."""
    from slr_ray.sequence import convert as C
    from slr_ray.sequence import embree_rays as E
    from slr_ray.sequence import union as U
    from slr_ray.sequence.layouts import base as L
    from slr_ray.sequence.methods import base as B
    from slr_ray.sequence.methods import embree_rays as M

    st = Stages()
    first = {}
    job = C._job

    def _job(*a, **k):
        first.setdefault("t", (time.perf_counter(), time.process_time()))
        return job(*a, **k)

    targets = [(type(seq), "read", "read"), (L.Frame, "world", "read"), (U.FrameCache, "selection", "select"),
               (E, "frame_points_beams", "beams"), (E, "_mesh", "mesh"), (B, "accumulate", "union"),
               (M, "to_frame", "to_frame"), (M, "cast_embree_rays", "cast"), (M, "fill_missing", "fill"),
               (C, "_write_frame", "write"), (C, "_publish", "publish"), (C, "conversion_reach", "reach")]
    saved = [(owner, name, st.wrap(owner, name, stage)) for owner, name, stage in targets]
    C._job = _job
    try:
        yield st, first
    finally:
        C._job = job
        for owner, name, f in reversed(saved):
            setattr(owner, name, f)


def profile(drive, out, target, estimator, half, extra: dict) -> dict:
    """One conversion of ``drive`` into the new directory ``out``, by stage: ``{stage: {wall_s, cpu_s,
    wall_per_frame, cpu_per_frame, calls}}`` and the totals."""
    from slr_ray.sequence.convert import convert_sequence
    from slr_ray.sequence.frames import read_sequence

    os.makedirs(out)
    seq = read_sequence(drive)
    with staged(seq) as (st, first):
        w0, c0 = time.perf_counter(), time.process_time()
        res = convert_sequence(seq, out, target, estimator=estimator, half=half, workers=1, **extra)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    n = res["written"]
    fw, fc = first["t"]
    st.mark("start", fw - w0, fc - c0)
    for d, total in ((st.wall, wall), (st.cpu, cpu)):
        d["other"] = total - sum(v for k, v in d.items() if k != "other")
    stages = {k: {"wall_s": round(st.wall[k], 3), "cpu_s": round(st.cpu[k], 3),
                  "wall_per_frame": round(st.wall[k] / n, 4), "cpu_per_frame": round(st.cpu[k] / n, 4),
                  "calls": st.calls[k]} for k in STAGES}
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return {"frames": n, "process_peak_gib": round(peak, 3), "peak_of": "this process, the drive's making included",
            "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "wall_per_frame": round(wall / n, 4),
            "cpu_per_frame": round(cpu / n, 4), "load_average": [round(x, 2) for x in os.getloadavg()],
            "stages": stages}
