"""Reproducing the paper's validation (Experiment 1), and going past it.

A run is described by a :class:`ValidationConfig` (TOML; shipped ones:
``quick``, ``paper``, ``distance``, ``occlusion``, ``resolution``) and made by
:func:`run_validation`, which writes rows as it goes and resumes where it
stopped. The modules, in the order a run uses them:

``config``
    :class:`ValidationConfig`, :func:`load_config`.
``planning``
    which rows are missing; the secondary positions, saved per scene.
``truths``
    true scans of the positions, shared by a scene's primaries.
``runner``
    :func:`run_validation`: primaries, positions, SLR scans, agreement.
``results``
    the CSV files (``results.csv``, ``stages.csv``), :func:`peak_rss_gib`.
``report``
    the paper's statistics and Markdown tables from the rows.
``diagnostics``
    :func:`miss_breakdown`, :func:`hidden_from`: occlusion vs artefact.
``profile``
    :func:`build_synthetic_profile`: the shipped azimuth profile, remade
    from the synthetic scenes.

Figures are drawn by :mod:`slr_ray.plotting` (``validation_figure``,
``paper_figure``), from the rows :func:`load_rows` reads.
"""

from .config import ValidationConfig, load_config
from .diagnostics import hidden_from, miss_breakdown
from .profile import build_synthetic_profile
from .report import full_pairs, headline, load_rows, paper_report, paper_report_markdown, series, series_stats
from .results import COLUMNS, peak_rss_gib, read_rows, stage_summary
from .runner import run_validation

__all__ = ["ValidationConfig", "load_config", "run_validation", "read_rows", "load_rows", "COLUMNS",
           "peak_rss_gib", "headline", "series", "series_stats", "full_pairs", "paper_report",
           "paper_report_markdown", "miss_breakdown", "hidden_from", "stage_summary", "build_synthetic_profile"]
