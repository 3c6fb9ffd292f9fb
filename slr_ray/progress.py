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

Both (and the command line, unless ``--quiet``) call ``say_compiling``: the
first time numba compiles a kernel in the process (not when it loads one from
its cache) one line says so on stderr, and a phase that spent time compiling
says how much of it, so that 30-40 s of a first run is not blamed on the
phase's work.

``step``
    what a phase is doing now (``step("neighbours", 0.4)``), from inside
    it: once the phase is named, a new step is a line "PHASE: STEP ..." on
    stderr (a share done, on a terminal only, is redrawn in place on its
    line), so that a phase of half a minute shows where it is; nothing
    outside a phase or before it is named.

stdout is never written: it holds the command's one line of JSON.
"""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

from numba.core import event as numba_event
from tqdm import tqdm

__all__ = ["bar", "phase", "step", "say_compiling", "PHASE_AFTER", "COMPILING"]

#: Seconds a phase runs before it is named on stderr.
PHASE_AFTER = 2.0

#: What stderr says, once a process, when numba first compiles (a cache miss).
COMPILING = "compiling numba kernels (first run only, cached) ..."

_compiles = {"listening": False, "said": False, "depth": 0, "start": 0.0, "seconds": 0.0}
_compiles_lock = threading.Lock()


def say_compiling() -> None:
    """From now on, say :data:`COMPILING` on stderr the first time numba compiles in this process
    (numba's ``numba:compile`` event fires on a cache miss only: a kernel loaded from the cache says
    nothing), and count the seconds spent compiling (what :func:`phase` reports)."""
    with _compiles_lock:
        if _compiles["listening"]:
            return
        _compiles["listening"] = True
    class _Compiles(numba_event.Listener):
        def on_start(self, ev):
            with _compiles_lock:
                _compiles["depth"] += 1
                if _compiles["depth"] > 1:  # a kernel compiled for another: counted with it
                    return
                _compiles["start"] = time.perf_counter()
                say = not _compiles["said"]
                _compiles["said"] = True
            if say:
                tqdm.write(COMPILING, file=sys.stderr)

        def on_end(self, ev):
            with _compiles_lock:
                _compiles["depth"] -= 1
                if _compiles["depth"] == 0:
                    _compiles["seconds"] += time.perf_counter() - _compiles["start"]

    numba_event.register("numba:compile", _Compiles())


def bar(iterable=None, desc: str = "", unit: str = "it", *, total=None, progress: bool = True,
        leave: bool = False, unit_scale: bool = False) -> tqdm:
    """A tqdm bar on stderr over ``iterable`` (or of ``total`` steps, advanced by
    ``update``); disabled, and silent, when ``progress`` is false.

    ``leave=False`` clears the bar on a terminal only: elsewhere (a log, a
    pipe) clearing writes a line of blanks, so the bar's last state is kept
    there, ended by a newline."""
    leave = leave or not _is_terminal(sys.stderr)
    if progress:
        say_compiling()
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
    say_compiling()
    t0, compiled = time.perf_counter(), _compiles["seconds"]
    lock = threading.Lock()
    shown = []
    state = {"desc": desc, "lock": lock, "shown": shown, "step": None, "bar": None}
    _phases.append(state)

    def show():
        with lock:
            if shown is not None:
                shown.append(True)
                tqdm.write(f"{desc} ...", file=sys.stderr)
                if state["step"] is not None:
                    _say_step(state)

    timer = threading.Timer(PHASE_AFTER if after is None else after, show)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        if state in _phases:
            _phases.remove(state)
        with lock:
            if state["bar"] is not None:
                state["bar"].close()
            if shown:
                compiling = _compiles["seconds"] - compiled
                tqdm.write(f"{desc}: {time.perf_counter() - t0:.1f} s"
                           + (f" ({compiling:.1f} s of it compiling numba kernels)" if compiling >= 0.5 else ""),
                           file=sys.stderr)
            shown = None


#: the phases running now, innermost last: where :func:`step` says what it says
_phases: list = []


def step(text: str, done: float | None = None) -> None:
    """Say what the innermost running :func:`phase` does now (``text``), and on a terminal the share of
    it ``done`` (0-1), redrawn in place; a new ``text`` is a new line. Nothing outside a phase, nor
    before the phase is named (a phase that ends within :data:`PHASE_AFTER` says nothing at all)."""
    if not _phases:
        return
    state = _phases[-1]
    with state["lock"]:
        new = state["step"] is None or state["step"][0] != text
        state["step"] = (text, done)
        if state["shown"]:
            if new:
                _say_step(state)
            elif state["bar"] is not None and done is not None:
                state["bar"].n = round(1000 * min(max(done, 0.0), 1.0))
                state["bar"].refresh()


def _say_step(state) -> None:
    """A phase's step: a line, and on a terminal a bar of its share done (when it has one)."""
    text, done = state["step"]
    if state["bar"] is not None:
        state["bar"].close()
        state["bar"] = None
    if done is not None and _is_terminal(sys.stderr):
        state["bar"] = tqdm(total=1000, desc=f"{state['desc']}: {text}", file=sys.stderr, leave=False,
                            bar_format="{desc} {percentage:3.0f}% |{bar}| {elapsed}")
        state["bar"].n = round(1000 * min(max(done, 0.0), 1.0))
        state["bar"].refresh()
    else:
        tqdm.write(f"{state['desc']}: {text} ...", file=sys.stderr)
