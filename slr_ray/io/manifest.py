"""An augment run's record in its output directory (:mod:`slr_ray.augment`): the names of its
manifest and journal, the settings a rerun must match, the scans it may keep, and the files
a run refuses to write among."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import InputValueError, OutputError
from .outputs import LOCK_NAME, output_sidecars

__all__ = ["MANIFEST", "JOURNAL", "same_settings", "resumable", "refuse_strangers", "refuse_theirs", "append_journal"]

#: The run's record in its output directory.
MANIFEST = "manifest.json"
#: Scans finished since the manifest was last written, one JSON line each (removed when a run completes).
JOURNAL = "manifest.scans.jsonl"


def _short(value, limit: int = 200) -> str:
    """``repr(value)``, cut to ``limit`` characters (a drop model's table is long)."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _differences(before: dict, now: dict, prefix: str = "") -> list:
    """``'key: old -> new'`` for every key of either mapping whose values differ
    (a setting only one run has differs too); within two mappings
    (``effects``), the keys that differ, as ``effects.range_noise``."""
    out = []
    for k in [*now, *(k for k in before if k not in now)]:
        old, new = before.get(k), now.get(k)
        if old == new:
            continue
        if isinstance(old, dict) and isinstance(new, dict):
            out += _differences(old, new, f"{prefix}{k}.")
        else:
            out.append(f"{prefix}{k}: {_short(old)} -> {_short(new)}")
    return out


def same_settings(manifest_path: Path, settings: dict, out: Path) -> dict:
    """The manifest of an earlier run into ``out``, refused unless its settings
    are this run's (input, seed, pattern, backend and options, ground
    threshold, format, effects): a rerun with other settings never mixes its
    scans with the old ones. Checked before the long steps; the positions,
    once drawn, by :func:`resumable`."""
    try:
        old = json.loads(manifest_path.read_text())
    except ValueError:
        old = None
    if not isinstance(old, dict) or not isinstance(old.get("settings", {}), dict):  # valid JSON of another shape
        raise InputValueError(f"{manifest_path} is not a manifest slr_ray can read: write elsewhere") from None
    before = old.get("settings")
    if before is None:
        raise InputValueError(f"{manifest_path} was written by an older slr_ray without its settings: "
                              "write elsewhere (or remove the directory)")
    diff = _differences(before, settings)
    if diff:
        raise InputValueError(f"{out} holds a run with other settings ({'; '.join(diff)}): "
                              "write elsewhere, or remove it to start again")
    return old


def resumable(old: dict, positions, out: Path) -> dict:
    """The scans of an earlier run into ``out`` (its manifest ``old``, of the
    same settings: :func:`same_settings`) that this run may keep.

    A run resumes one whose positions agree with this run's as far as both go
    (a run for more positions extends one for fewer; a run for fewer is
    refused, as its manifest could not describe the scans already there).
    """
    held = len(old.get("positions", []))
    if len(positions) < held:
        # its manifest would list the old run's scans past this run's positions, without them
        raise InputValueError(f"{out} holds a run of {held} positions and this run asks {len(positions)}: "
                              f"ask n={held} (or more) to resume or extend it, or write elsewhere",
                              flags={f"ask n={held}": f"ask --n {held}"})
    k = min(len(positions), held)
    if not np.array_equal(np.asarray(old.get("positions", []))[:k].reshape(-1, 3), positions[:k]):
        raise InputValueError(f"{out} holds a run with other settings (positions differ): "
                              "write elsewhere, or remove it to start again")
    scans = {s["file"]: s for s in old.get("scans", [])}
    journal = out / JOURNAL
    if journal.exists():  # scans recorded since the manifest was last written (an interrupted run)
        for line in journal.read_text().splitlines():
            try:
                entry = json.loads(line)
            except ValueError:
                continue  # a line cut short by the interruption
            if entry.get("withdrawn"):  # recorded, then found another's file at its name (augment's _publish)
                scans.pop(entry["file"], None)
            else:
                scans[entry["file"]] = entry
    return {k: v for k, v in scans.items() if (out / k).exists()}


def refuse_strangers(out, names, ext, force) -> None:
    """A fresh run refuses a directory holding its scans' names, or other files unless ``force``."""
    # a scan's sidecars too (a .bin's .label): written over, or removed as stale, by a fresh run
    strays = sorted(str(p if p.parent != out else p.name) for n in names
                    for p in [out / n, *output_sidecars(out / n, ext)] if os.path.lexists(p))
    if strays:
        raise OutputError(f"{out} holds {strays[0]}{f' and {len(strays) - 1} more' if len(strays) > 1 else ''} "
                          f"but no {MANIFEST}: not a run this one can resume; write elsewhere")
    others = sorted(p.name for p in out.iterdir() if p.name != LOCK_NAME
                    and not (p.name.startswith(".") and p.name.endswith(".part")))  # a killed run's
    if others and not force:
        raise OutputError(f"{out} holds {len(others):,} file(s) of no augment run ({', '.join(others[:3])}"
                          f"{', ...' if len(others) > 3 else ''}): a fresh run writes into an empty directory "
                          "or a new one; write elsewhere, or pass force=True to write among them "
                          "(never over one)", flags={"pass force=True": "give --force"})


def refuse_theirs(jobs, out, ext) -> None:
    """An extension or a resume refuses to write where a file its manifest does not list lies."""
    theirs = sorted(str(p if p.parent != out else p.name) for j in jobs
                    for p in [Path(j["path"]), *output_sidecars(j["path"], ext)] if os.path.lexists(p))
    if theirs:
        raise OutputError(f"{out} holds {theirs[0]}{f' and {len(theirs) - 1} more' if len(theirs) > 1 else ''}"
                          f", which its {MANIFEST} does not list: this run would write there; move "
                          f"{'it' if len(theirs) == 1 else 'them'} away, or write elsewhere")


def append_journal(journal, entry) -> None:
    """One scan's line appended to the journal (an error names the file)."""
    try:
        with open(journal, "a") as f:
            f.write(json.dumps(entry) + "\n")
    except OSError as exc:  # 'File too large', 'No space left on device': say which file
        if exc.filename is not None:
            raise
        raise OSError(exc.errno, f"cannot write {journal}: {exc.strerror or exc}") from exc
