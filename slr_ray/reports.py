"""The tables and files of an evaluation: a pair's (:func:`slr_ray.evaluate.evaluate_pair`) and a
sequence's (:func:`slr_ray.sequence.evaluate_sequence`), written as JSON, markdown and CSV.

Moved out of :mod:`slr_ray.evaluate` (which still names every function here); they read a result's
rows and the metrics' registry, and compute nothing.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

from .arrays import json_safe
from .errors import OutputError
from .io import atomic_path
from .metrics import REGISTRY as METRICS, metric_columns

__all__ = ["EVALUATION_FILES", "evaluation_table", "markdown_table", "compact_json", "splits_table", "csv_text",
           "evaluation_directory", "write_evaluation", "reach_table", "SEQUENCE_COLUMNS", "write_sequence_evaluation",
           "sequence_summary"]


# --- tables and files ---------------------------------------------------------------------------------------

def evaluation_table(result: dict) -> list[dict]:
    """One flat row per method: the figures of the table (JSON-ready), each registered metric's columns
    in the registry's order (:data:`slr_ray.metrics.REGISTRY`)."""
    return [{"method": r["label"], "points": r["points_out"]} | metric_columns(r, result) for r in result["rows"]]


def reach_table(result: dict) -> list[dict]:
    """One row per method and part of the real target by what the source could have seen of it (the
    ``source`` split of :func:`slr_ray.evaluate.evaluate_pair`: seen by source, in source view but unseen,
    outside the source's range, outside its field of view, and the pulses with no real return): target
    points and real pulses of the part, the point figures at the first threshold and the depth and drop
    figures on its pulses. Every part is a row, empty or not: the parts sum to the whole."""
    reach = result.get("source_reach")
    if not reach:
        return []
    tau = f"{100 * result['thresholds'][0]:g}cm"
    out = []
    for r in result["rows"]:
        points = r.get("points", {}).get("groups", {}).get("source", {})
        image = r.get("image", {}).get("groups", {}).get("source", {})
        for label in (*reach["labels"], "no return"):
            p, im = points.get(label, {}), image.get(label, {})
            f = p.get("fscore", {}).get(tau, {})
            out.append({"method": r["label"], "part": label, "target points": reach["points"].get(label, 0),
                        "real pulses": reach["pulses"].get(label, 0),
                        "simulated points": p.get("simulated_points", 0), f"P@{tau}": f.get("precision", math.nan),
                        f"R@{tau}": f.get("recall", math.nan), f"F@{tau}": f.get("fscore", math.nan),
                        "depth_medae_m": im.get("medae", math.nan), "depth_rmse_m": im.get("rmse", math.nan),
                        "drop_accuracy": im.get("accuracy", math.nan)})
    return out


def _fmt(v):
    if isinstance(v, float):
        if math.isnan(v):
            return "–"
        return f"{v:.4f}" if abs(v) < 10 else f"{v:.2f}"
    return f"{v:,}" if isinstance(v, int) else str(v)


def markdown_table(table: list[dict], columns=None) -> str:
    """``table`` (from :func:`evaluation_table`) as a markdown table."""
    cols = columns or list(table[0])
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(_fmt(r.get(c, math.nan)) for c in cols) + " |" for r in table]
    return "\n".join(lines)




def compact_json(obj, indent: int = 1, width: int = 1000, _level: int = 0) -> str:
    """JSON with every block that fits in ``width`` characters (a split's figures, a list of numbers)
    on one line: a file people read and diff, not one number a line."""
    flat = json.dumps(obj, allow_nan=False)
    scalars = isinstance(obj, list) and not any(isinstance(v, (dict, list)) for v in obj)
    if not isinstance(obj, (dict, list)) or scalars or len(flat) <= width or not obj:
        return flat
    pad, inner = " " * (indent * _level), " " * (indent * (_level + 1))
    if isinstance(obj, dict):
        items = [f"{inner}{json.dumps(str(k))}: {compact_json(v, indent, width, _level + 1)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    items = [inner + compact_json(v, indent, width, _level + 1) for v in obj]
    return "[\n" + ",\n".join(items) + "\n" + pad + "]"


def splits_table(result: dict) -> list[dict]:
    """Every split of every method as one flat row (method, part, split, label, then the figures;
    F-scores as ``P@5cm``, ``R@5cm``, ``F@5cm``...): the JSON's ``groups`` as a long table."""
    out = []
    for r in result["rows"]:
        for part in (m for m in METRICS if m in r):
            for split, labels in r[part].get("groups", {}).items():
                for label, block in labels.items():
                    row = {"method": r["method"], "part": part, "split": split, "label": label}
                    for k, v in block.items():
                        if k == "fscore":
                            for tau, f in v.items():
                                row |= {f"P@{tau}": f["precision"], f"R@{tau}": f["recall"], f"F@{tau}": f["fscore"]}
                        else:
                            row[k] = v
                    out.append(row)
    return out


def csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    fields = list(dict.fromkeys(k for r in rows for k in r))
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


#: the files of an evaluation (the ``evaluate`` command's), by kind: :func:`write_evaluation` writes all
#: but ``figure``, which :func:`slr_ray.plotting.evaluation_figure` draws (figures are not computed here)
EVALUATION_FILES = {"json": "evaluation.json", "markdown": "table.md", "csv": "table.csv",
                    "splits": "splits.csv", "figure": "evaluation.png"}


def evaluation_directory(directory, force: bool) -> Path:
    """``directory``, made; refused when it is a file, or not empty without ``force``."""
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise OutputError(f"{d} exists and is not a directory")
    if d.is_dir() and any(d.iterdir()) and not force:
        raise OutputError(f"{d} exists and is not empty (use --force to replace its evaluation files)")
    d.mkdir(parents=True, exist_ok=True)
    return d


#: the heading of ``table.md``'s second table (:func:`reach_table`)
REACH_HEADING = "By what the source could have seen of the real target (part: the source split; parts sum to the whole)"


def write_evaluation(result: dict, directory, force: bool = False, inputs: dict | None = None) -> dict:
    """Write ``evaluation.json`` (everything, splits included; one line per figure block),
    ``table.md``, ``table.csv`` and ``splits.csv`` (every split, one row each) into a new ``directory``.

    Refuses an existing non-empty directory unless ``force`` (then only these
    files are replaced). Returns the paths written, by kind. The figure,
    ``evaluation.png``, is drawn by the figures' layer, as the ``evaluate``
    command does: ``save_figure(evaluation_figure(result), directory / "evaluation.png")``
    (:mod:`slr_ray.plotting`).
    """
    d = evaluation_directory(directory, force)
    table = evaluation_table(result)
    reach = reach_table(result)
    doc = {k: v for k, v in result.items() if k != "images"} | {"table": table, "inputs": inputs or {}}
    if reach:
        doc["reach_table"] = reach
    paths = {kind: d / name for kind, name in EVALUATION_FILES.items() if kind != "figure"}
    with atomic_path(paths["json"]) as tmp:
        tmp.write_text(compact_json(json_safe(doc)) + "\n")
    with atomic_path(paths["markdown"]) as tmp:
        tmp.write_text(markdown_table(table) + "\n" + (f"\n{REACH_HEADING}\n\n{markdown_table(reach)}\n" if reach else ""))
    with atomic_path(paths["csv"]) as tmp:
        tmp.write_text(csv_text(table))
    with atomic_path(paths["splits"]) as tmp:
        tmp.write_text(csv_text(splits_table(result)))
    return {k: str(v) for k, v in paths.items()}


#: the columns of a sequence evaluation's ``table.md`` by protocol (every column is in ``table.csv`` and
#: the JSON): the default, and LiDAR4D's (its clamped depth errors, Chamfer and 22.4 cm F-score)
SEQUENCE_COLUMNS = {
    "slr": ("frame", "method", "points", "F@5cm", "F@10cm", "depth_medae_m", "depth_rmse_m", "drop_accuracy",
            "drop_recall", "cd_sum_m2", "R@10cm seen", "F@5cm in reach", "depth_medae_m in reach",
            "target points out of reach", "points out of reach", "F@5cm out of reach"),
    "lidar4d": ("frame", "method", "points", "cd_sum_m2", "F@22.3607cm", "lidar4d_depth_rmse_m",
                "lidar4d_depth_medae_m", "drop_accuracy")}


def _sequence_rows(result: dict) -> list[dict]:
    return [r for f in result["frames"] for r in f["table"]] + result["mean"]


def _sequence_columns(result: dict, rows: list[dict]) -> list[str]:
    cols = SEQUENCE_COLUMNS.get(result.get("protocol", "slr"), SEQUENCE_COLUMNS["slr"])
    return [c for c in cols if c in rows[0]]


def write_sequence_evaluation(result: dict, directory, force: bool = False) -> dict:
    """Write a sequence evaluation (:func:`slr_ray.sequence.evaluate_sequence`'s result, with what the
    caller adds: ``protocol``, ``inputs``...) into ``directory``: ``evaluation.json`` (everything, its
    ``table`` every frame's rows and the means), ``table.md`` (the columns of its protocol,
    :data:`SEQUENCE_COLUMNS`) and ``table.csv`` (every column). Refuses an existing non-empty
    directory unless ``force`` (then only these files are replaced). Returns the paths, by kind."""
    d = evaluation_directory(directory, force)
    rows = _sequence_rows(result)
    paths = {kind: d / EVALUATION_FILES[kind] for kind in ("json", "markdown", "csv")}
    with atomic_path(paths["json"]) as tmp:
        tmp.write_text(compact_json(json_safe(result | {"table": rows})) + "\n")
    with atomic_path(paths["markdown"]) as tmp:
        tmp.write_text(markdown_table(rows, _sequence_columns(result, rows)) + "\n")
    with atomic_path(paths["csv"]) as tmp:
        tmp.write_text(csv_text(rows))
    return {k: str(v) for k, v in paths.items()}


def sequence_summary(result: dict) -> tuple[str, list[dict]]:
    """A sequence evaluation in short: the mean rows as a markdown table of its protocol's columns, and
    the same rows (those columns only, figures to 4 decimals) for a summary."""
    rows = result["mean"]
    cols = [c for c in _sequence_columns(result, rows) if c != "frame"]
    short = [{c: round(v, 4) if isinstance(v, float) else v for c, v in ((c, r.get(c)) for c in cols)} for r in rows]
    return markdown_table(rows, cols), short
