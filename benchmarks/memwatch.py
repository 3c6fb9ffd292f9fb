"""Resident memory of this process by stage, split into anonymous and file-backed pages.

The kernel's peak (VmHWM) counts every resident page: anonymous memory (what
the process allocated) and the pages of files it has mapped (a memory-mapped
primary). The two are not the same cost: mapped pages of a file are clean
and the kernel drops them under pressure (reading them back when touched),
anonymous ones it cannot drop without swap. VmHWM has no split, so a thread
samples ``RssAnon`` and ``RssFile`` of /proc/self/status every few
milliseconds and keeps each one's maximum, and that of their sum, per stage.
A peak shorter than the interval can be missed: compare the sampled total
with VmHWM (reported too).

    from memwatch import MemWatch
    with MemWatch() as w:
        ...
        w.mark("primary scan")      # closes the stage that ran since the last mark
    w.stages   # [{"stage", "seconds", "anon_gib", "file_gib", "total_gib"}, ...]
"""

from __future__ import annotations

import threading
import time


def status_kib() -> dict:
    """``VmRSS``, ``VmHWM``, ``RssAnon``, ``RssFile`` of this process (KiB); {} where unreadable."""
    out = {}
    try:
        with open("/proc/self/status") as f:
            for line in f:
                key = line.split(":", 1)[0]
                if key in ("VmRSS", "VmHWM", "RssAnon", "RssFile", "RssShmem"):
                    out[key] = int(line.split()[1])
    except OSError:
        pass
    return out


class MemWatch:
    """Samples RssAnon / RssFile in a thread; :meth:`mark` closes a stage."""

    def __init__(self, interval: float = 0.005):
        self.interval = interval
        self.stages = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._reset()

    def _reset(self):
        s = status_kib()
        a, f = s.get("RssAnon", 0), s.get("RssFile", 0) + s.get("RssShmem", 0)
        self._max = [a, f, a + f]
        self._t0 = time.perf_counter()

    def _sample(self):
        s = status_kib()
        a, f = s.get("RssAnon", 0), s.get("RssFile", 0) + s.get("RssShmem", 0)
        with self._lock:
            self._max = [max(self._max[0], a), max(self._max[1], f), max(self._max[2], a + f)]

    def _run(self):
        while not self._stop.wait(self.interval):
            self._sample()

    def __enter__(self):
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    def mark(self, stage: str, **extra) -> dict:
        """Close the stage that ran since the last mark (or the start): its peaks in GiB."""
        self._sample()
        with self._lock:
            a, f, t = self._max
            row = {"stage": stage, "seconds": round(time.perf_counter() - self._t0, 3),
                   "anon_gib": a / 2**20, "file_gib": f / 2**20, "total_gib": t / 2**20,
                   "vmhwm_gib": status_kib().get("VmHWM", 0) / 2**20, **extra}
            self.stages.append(row)
        self._reset()
        return row

    def peak(self) -> dict:
        """The largest of each column over every stage marked so far (GiB)."""
        return {k: max((r[k] for r in self.stages), default=0.0) for k in ("anon_gib", "file_gib", "total_gib")}
