"""Progress on stderr, one look for every long phase.

Two helpers, used wherever slr_ray runs long enough to look stuck (~2 s):

``bar``
    a counted loop (scans, positions, rows): a tqdm bar on stderr, as
    ``augment`` has always drawn it, off with ``progress=False``
    (``--quiet``).
``phase``
    one step of unknown length (preparing embree's discs, a scan with beam
    divergence): its name on stderr once it has run 2 s, then its time;
    nothing for a step that ends sooner, nothing at all with
    ``progress=False``.

stdout is never written: it holds the command's one line of JSON.
"""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

from tqdm import tqdm

__all__ = ["bar", "phase", "PHASE_AFTER"]

#: Seconds a phase runs before it is named on stderr.
PHASE_AFTER = 2.0


def bar(iterable=None, desc: str = "", unit: str = "it", *, total=None, progress: bool = True,
        leave: bool = False, unit_scale: bool = False) -> tqdm:
    """A tqdm bar on stderr over ``iterable`` (or of ``total`` steps, advanced by
    ``update``); disabled, and silent, when ``progress`` is false.

    ``leave=False`` clears the bar on a terminal only: elsewhere (a log, a
    pipe) clearing writes a line of blanks, so the bar's last state is kept
    there, ended by a newline."""
    leave = leave or not _is_terminal(sys.stderr)
    return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, disable=not progress, file=sys.stderr,
                unit_scale=unit_scale)


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # no isatty, or closed
        return False


@contextmanager
def phase(desc: str, *, progress: bool = True, after: float | None = None):
    """Name the enclosed step on stderr when it runs longer than ``after`` seconds
    (default :data:`PHASE_AFTER`), then say how long it took::

        with phase("embree: preparing 4,000,000 points", progress=not quiet):
            scanner = prepare(points, "embree")
    """
    if not progress:
        yield
        return
    t0 = time.perf_counter()
    lock = threading.Lock()
    shown = []

    def show():
        with lock:
            if shown is not None:
                shown.append(True)
                tqdm.write(f"{desc} ...", file=sys.stderr)

    timer = threading.Timer(PHASE_AFTER if after is None else after, show)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        with lock:
            if shown:
                tqdm.write(f"{desc}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
            shown = None
