"""The files a validation run writes as it goes: ``results.csv`` rows, ``stages.csv``
and ``settings.json``.

Rows are appended and flushed as they are made, so an interrupted run
resumes where it stopped. A row is keyed by (scene, primary resolution,
position, backend, truth); rows written before precision was recorded read
back with ``precision`` and ``fscore`` empty. ``settings.json`` holds the
settings that change a row's value (:data:`ROW_SETTINGS`): a run resumed with
other values is refused rather than mixed with the old rows. What only adds
rows (more positions, scenes, backends, truths) may change between sittings.
"""

from __future__ import annotations

import csv
import hashlib
import json
import resource
from pathlib import Path

from ..backends.embree import EmbreeOptions
from ..errors import FormatError, InputValueError
from ..io import atomic_path
from ..scenes import load_toml_spec

__all__ = ["COLUMNS", "read_rows", "row_key", "ResultsWriter", "StageLog", "peak_rss_gib", "stage_summary",
           "PAPER_STAGES", "EXTRA_STAGES", "ROW_SETTINGS", "check_settings"]

COLUMNS = ["scene", "n_rectangles", "scene_seed", "primary_resolution", "position", "x", "y", "z",
           "distance_m", "backend", "truth", "similarity", "precision", "fscore", "true_points", "slr_points",
           "seconds"]


def row_key(scene, resolution, position, backend, truth) -> tuple:
    """The key of a row (strings, as read back from the CSV)."""
    return (str(scene), str(resolution), str(position), str(backend), str(truth))


#: Columns a row is keyed and reported by: a results.csv without them is another program's.
_KEY_COLUMNS = ("scene", "primary_resolution", "position", "backend", "truth", "similarity", "distance_m")


def read_rows(path) -> dict:
    """Rows of a ``results.csv`` by :func:`row_key` (empty when there is no file)."""
    path = Path(path)
    if not path.exists():
        return {}
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            head = reader.fieldnames or []
            missing = [c for c in _KEY_COLUMNS if c not in head]
            if missing and path.stat().st_size:
                raise FormatError(f"{path} is not a results.csv of slr_ray (no column(s) {missing}): "
                                  "write the validation elsewhere")
            rows = list(reader)
    except UnicodeDecodeError:
        raise FormatError(f"{path} is not a results.csv of slr_ray (not text): write the validation elsewhere") \
            from None
    for r in rows:
        if None in r or any(r.get(c) is None for c in _KEY_COLUMNS):  # a row longer or shorter than the header
            raise FormatError(f"{path}: a row does not match the header ({len(head)} columns): "
                              "cut short or edited; remove it to resume")
        for k in ("precision", "fscore"):
            r.setdefault(k, "")
    return {row_key(r["scene"], r["primary_resolution"], r["position"], r["backend"], r["truth"]): r
            for r in rows}


#: config fields that change the value of a row (or which positions the rows are at)
ROW_SETTINGS = ("primary_semantics", "dense_spacing", "seed", "secondary_resolution", "nearest_supersample",
                "positions_resolution", "min_ground_points", "threshold", "embree_options")


def check_settings(outdir, config) -> dict:
    """Refuse to resume ``outdir`` with settings that would change its rows.

    The first sitting writes ``outdir/settings.json`` with the config's
    :data:`ROW_SETTINGS` and the embree options they resolve to in this
    version of slr_ray (``embree_resolved``: a default changed by an upgrade
    changes the embree rows as surely as a setting); a later sitting must
    match them (options a newer version adds are not compared). A directory
    with rows but no settings file (made before it existed) takes the
    current settings. Returns the settings.

    Raises
    ------
    InputValueError
        Naming each setting that differs, with the run's and the config's value.
    """
    path = Path(outdir) / "settings.json"
    now = json.loads(json.dumps({**{k: getattr(config, k) for k in ROW_SETTINGS},
                                 "embree_resolved": _embree_resolved(config),
                                 "scene_specs": _spec_digests(config)}))  # tuples -> lists
    if path.exists():
        try:
            then = json.loads(path.read_text())
        except ValueError:
            then = None
        if not isinstance(then, dict):
            raise FormatError(f"{path} is not a settings.json of slr_ray: write the validation elsewhere")
        differ = {k: (then.get(k), now[k]) for k in ROW_SETTINGS if then.get(k, now[k]) != now[k]}
        old_opts, new_opts = then.get("embree_resolved", {}), now["embree_resolved"]
        differ.update({f"embree option {k}": (old_opts[k], new_opts[k]) for k in old_opts
                       if k in new_opts and old_opts[k] != new_opts[k]})
        old_specs = then.get("scene_specs", {})  # a spec edited in place (same name, even same size)
        differ.update({f"scene spec {k} (content digest)": (old_specs[k], d) for k, d in now["scene_specs"].items()
                       if k in old_specs and old_specs[k] != d})
        if differ:
            said = "; ".join(f"{k}: {a!r} in the run, {b!r} now" for k, (a, b) in differ.items())
            raise InputValueError(f"{outdir} holds rows made with other settings ({said}); resuming would mix "
                                  "them: write to another directory, or resume with the run's settings")
        if all(k in then for k in (*ROW_SETTINGS, "embree_resolved", "scene_specs")):
            return now
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(now, indent=1, sort_keys=True) + "\n")
    return now


def _spec_digests(config) -> dict:
    """Each scene spec's identity by content: a digest of its parsed TOML (a spec
    given by path can be edited in place, a shipped one changed by an upgrade)."""
    out = {}
    for entry in config.scenes:
        spec = config.scene_entry(entry)[0]
        try:
            data = load_toml_spec(spec, "scene", "scene spec")[0]
        except InputValueError:  # not found or not TOML: the run says so where it reads the spec
            continue
        out[spec] = hashlib.blake2b(json.dumps(data, sort_keys=True, default=str).encode(), digest_size=8).hexdigest()
    return out


def _embree_resolved(config) -> dict:
    """The embree options of the config's first primary as this version resolves them
    (defaults filled in), without the primary's origin and resolution."""
    res = config.scene_entry(config.scenes[0])[1][0] if config.scenes else config.primary_resolutions[0]
    opts = EmbreeOptions(**{"primary_origin": [0.0, 0.0, 0.0], "primary_resolution": res,
                            **config.embree_options}).to_dict()
    for k in ("primary_origin", "primary_resolution", "n_threads", "chunk"):  # not the rows' business
        opts.pop(k, None)
    return opts


def peak_rss_gib() -> float:
    """Peak resident memory of this process so far (GiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


class _AppendCSV:
    """A CSV opened for appending, with its header written when new; a context manager."""

    columns: list = []

    def __init__(self, path):
        self.path = Path(path)
        new = not self.path.exists() or self.path.stat().st_size == 0
        if not new:
            with open(self.path, newline="") as f:
                head = next(csv.reader(f), [])
            missing = [c for c in head if c not in self.columns]
            if missing:
                raise FormatError(f"{self.path} has columns {missing} this version does not write; "
                                 "resume it with the version that made it or write elsewhere")
            self.header = head
        else:
            self.header = list(self.columns)
        self.f = open(self.path, "a", newline="")
        self.w = csv.DictWriter(self.f, self.header, extrasaction="ignore")
        if new:
            self.w.writeheader()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.f.close()


class ResultsWriter(_AppendCSV):
    """``results.csv``: one row per (position, backend, truth), flushed as written.

    A file from before a column was added keeps its own header (the new
    column is left out of it), so an old run resumes without a mixed file."""

    columns = COLUMNS

    def add(self, row: dict) -> None:
        self.w.writerow(row)
        self.f.flush()


class StageLog(_AppendCSV):
    """``stages.csv``: wall time, size and peak memory of each stage of a run."""

    columns = ["scene", "primary_resolution", "stage", "seconds", "count", "peak_rss_gib"]

    def add(self, scene, resolution, stage, seconds, count) -> None:
        self.w.writerow({"scene": scene, "primary_resolution": resolution, "stage": stage,
                         "seconds": round(seconds, 2), "count": count, "peak_rss_gib": round(peak_rss_gib(), 2)})
        self.f.flush()


#: stages of the paper's own experiment, and of what this project adds to it
PAPER_STAGES = ("primary scan", "positions", "pairs")
#: "primary to a mapped file": the points of a primary that, with its discs, would not fit in memory
EXTRA_STAGES = ("embree discs", "extras", "primary to a mapped file")


def stage_summary(path) -> dict:
    """Totals of a ``stages.csv``: seconds of the paper's part (primary scans,
    positions, its binning/pulse-centre pairs) and of the extras (embree discs,
    nearest-in-pulse truths, embree pairs), the peak memory, and the sittings:
    one ``run`` row per call of :func:`~slr_ray.validation.run_validation`
    with its wall time (a run resumed over several sittings has several).

    A sitting that was cut off (killed, out of time) writes no ``run`` row: it
    is recognised where a stage of a primary repeats, and its wall time is
    the sum of its stages (``interrupted`` counts them). A call that found
    nothing to do is not a sitting."""
    rows = []
    if Path(path).exists():
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    total = {name: 0.0 for name in ("paper", "extras")}
    for r in rows:
        if r["stage"] in PAPER_STAGES:
            total["paper"] += float(r["seconds"])
        elif r["stage"] in EXTRA_STAGES:
            total["extras"] += float(r["seconds"])
    walls, interrupted = [], 0
    seen, open_seconds = set(), 0.0
    for r in rows:
        if r["stage"] == "run":
            if seen or int(r.get("count") or 0):
                walls.append(float(r["seconds"]))
            seen, open_seconds = set(), 0.0
            continue
        key = (r["scene"], r["primary_resolution"], r["stage"])
        if key in seen:  # the previous sitting stopped without its run row
            walls.append(open_seconds)
            interrupted += 1
            seen, open_seconds = set(), 0.0
        seen.add(key)
        open_seconds += float(r["seconds"])
    if seen:  # the last sitting stopped (or is still running)
        walls.append(open_seconds)
        interrupted += 1
    peaks = [float(r["peak_rss_gib"]) for r in rows if r["peak_rss_gib"]]
    return {"paper_seconds": round(total["paper"], 1), "extras_seconds": round(total["extras"], 1),
            "sittings": len(walls), "interrupted": interrupted, "wall_seconds": round(sum(walls), 1),
            "peak_rss_gib": max(peaks, default=None)}
