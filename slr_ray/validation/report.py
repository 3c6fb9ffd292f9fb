"""The paper's figures from a run's rows: headline numbers, per-question series, Markdown.

Every statistic here is computed from ``results.csv`` rows (see
:mod:`slr_ray.validation.results`), so a report can be remade from a
finished or partial run at any time; the statistics themselves
(:func:`headline`, :func:`series`, :func:`series_stats`, :func:`full_pairs`)
live in :mod:`slr_ray.metrics.runs`, the home of every metric. Coverage is the paper's similarity;
precision (the share of SLR points near a true point) is reported next to it
where the rows have it.
"""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import InputValueError
from ..metrics import full_pairs, headline, series, series_stats
from ..paper import DISTANCE_BANDS, NEAR_DISTANCE, Q1_SCENES, Q2_SCENES
from .results import read_rows

__all__ = ["headline", "series", "series_stats", "full_pairs", "paper_report", "paper_report_markdown",
           "load_rows"]  # the statistics live in slr_ray.metrics.runs, named here too


def load_rows(csv_path) -> list:
    """The rows of a ``results.csv`` (an error when there are none)."""
    rows = list(read_rows(Path(csv_path)).values())
    if not rows:
        raise InputValueError(f"{csv_path}: no rows")
    return rows


def paper_report(csv_path) -> dict:
    """The figures behind docs/validation.md, "Reproducing the paper (Experiment 1)", from a
    ``results.csv`` of ``validate-paper`` (or of the single-question configs).

    ``q1[res]``: the five 1000-rectangle scenes (``all`` and ``by_scene``);
    ``occlusion[res]``: the 0/500/1000/2000-rectangle scenes (questions 2 and
    3: 0.0144 and 0.00576 deg); ``semantics[res]``: the positions where
    every backend and truth was run, each series on the same pairs, pooled
    over scenes; ``cross_check[res][backend][scene]``: each backend other than
    binning beside binning (``{"binning": ..., backend: ...}``) on the pairs
    where both were run against pulse-centre truth, per scene and ``all``.
    ``res`` is a primary resolution as text ('0.0144'). Every entry is
    :func:`series_stats` of binning vs pulse-centre truth unless named
    otherwise.
    """
    rows = load_rows(csv_path)
    out: dict = {"rows": len(rows), "q1": {}, "occlusion": {}, "semantics": {}, "cross_check": {}}
    resolutions = sorted({float(r["primary_resolution"]) for r in rows}, reverse=True)
    for res in resolutions:
        by = {sc: series_stats(*series(rows, [sc], res)) for sc in Q1_SCENES}
        by = {k: v for k, v in by.items() if v["pairs"]}
        if by:
            out["q1"][f"{res:g}"] = {"all": series_stats(*series(rows, Q1_SCENES, res)), "by_scene": by}
        occ = {sc: series_stats(*series(rows, [sc], res)) for sc in Q2_SCENES}
        occ = {k: v for k, v in occ.items() if v["pairs"]}
        if occ:
            out["occlusion"][f"{res:g}"] = occ
    names = sorted({(r["backend"], r["truth"]) for r in rows})
    for res in resolutions:
        full = full_pairs(rows, res, names)
        if full and len(names) > 1:
            out["semantics"][f"{res:g}"] = {f"{b}/{t}": series_stats(*series(rows, None, res, b, t, full))
                                           for b, t in names}
    for res in resolutions:
        for b in sorted({r["backend"] for r in rows} - {"binning"}):
            both = full_pairs(rows, res, [("binning", "center"), (b, "center")], exact=False)
            scenes = [sc for sc in (*Q1_SCENES, *Q2_SCENES) if any(k[0] == sc for k in both)]
            if not scenes:
                continue
            per = {sc: {x: series_stats(*series(rows, [sc], res, x, "center", both)) for x in ("binning", b)}
                   for sc in scenes}
            per["all"] = {x: series_stats(*series(rows, scenes, res, x, "center", both)) for x in ("binning", b)}
            out["cross_check"].setdefault(f"{res:g}", {})[b] = per
    return out


def _pct(x):
    return "–" if x is None else f"{100 * x:.1f} %"


def paper_report_markdown(report: dict) -> str:
    """:func:`paper_report` as Markdown tables (coverage per band; precision where recorded)."""
    lines = []
    bands = [f"{lo:g}–{hi:g} m" if math.isfinite(hi) else f"≥ {lo:g} m" for lo, hi in DISTANCE_BANDS]
    keys = [f"{lo:g}-{hi:g}" for lo, hi in DISTANCE_BANDS]
    head = (f"| series | pairs | mean < {NEAR_DISTANCE:g} m (min) | pairs < {NEAR_DISTANCE:g} m > 90 % | "
            "pairs > 80 % | " + " | ".join(bands) + " | slope /10 m | precision (< 17.5 m) |")
    sep = "|" + "---|" * (7 + len(bands))

    def row(name, st):
        b = st["below_17.5m"]
        cells = [_pct(st["bands"][k]["mean"]) if k in st["bands"] else "–" for k in keys]
        slope = "–" if st["slope_per_10m"] is None else f"{100 * st['slope_per_10m']:+.1f}"
        near = f"{_pct(b['mean'])} ({_pct(b['min'])})" if b["pairs"] else "–"
        prec = "–" if st.get("precision") is None else f"{_pct(st['precision'])} ({_pct(b.get('precision'))})"
        return (f"| {name} | {st['pairs']} | {near} | {_pct(b['share_above_0.9'])} of {b['pairs']} | "
                f"{_pct(st['share_above_0.8'])} | " + " | ".join(cells) + f" | {slope} | {prec} |")

    def table(title, items):
        if items:
            lines.extend([f"**{title}**", "", head, sep] + [row(n, st) for n, st in items] + [""])

    for res, q in report["q1"].items():
        table(f"Question 1 (distance): 1000-rectangle scenes, {res}° primaries, binning vs pulse-centre truth",
              list(q["by_scene"].items()) + [(f"all {len(q['by_scene'])}", q["all"])])
    for res, q in report["occlusion"].items():
        table(f"Questions 2 and 3 (occlusion, resolution): {res}° primaries, binning vs pulse-centre truth",
              list(q.items()))
    for res, ser in report["semantics"].items():
        table(f"Backends and truth semantics on the same pairs ({res}° primaries, all scenes)", list(ser.items()))
    for res, by_backend in report.get("cross_check", {}).items():
        for b, per in by_backend.items():
            table(f"{b} beside binning on the same pairs ({res}° primaries, vs pulse-centre truth)",
                  [(f"{sc}, {x}", st) for sc, pair in per.items() for x, st in pair.items()])
    run = report.get("run")
    if run and run.get("sittings"):
        lines.extend([
            "**The run** (from `stages.csv`)", "",
            "| sittings | wall time | paper's part | extras | peak memory |", "|---|---|---|---|---|",
            f"| {run['sittings']}" + (f" ({run['interrupted']} cut off: stage times)" if run.get("interrupted") else "")
            + f" | {run['wall_seconds'] / 60:.1f} min | {run['paper_seconds'] / 60:.1f} min | "
            f"{run['extras_seconds'] / 60:.1f} min | {run['peak_rss_gib']} GiB |", ""])
    return "\n".join(lines)
