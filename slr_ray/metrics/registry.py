"""The registry of metrics: name -> :class:`~slr_ray.metrics.metric.Metric`.

A new metric is one module of ``slr_ray/metrics/`` (its ``score(pair)``, its
``columns(block, result)`` and a ``Metric`` entry) and its entry in the line
below; :func:`slr_ray.evaluate.evaluate_pair` (a block per method),
:func:`~slr_ray.evaluate.evaluation_table` (its columns, in this order),
``splits.csv`` (its ``groups``) and the ``evaluate`` command's files read
the registry.
"""

from __future__ import annotations

from . import field
from .metric import Pair

__all__ = ["REGISTRY", "score_pair", "metric_columns"]

#: name -> Metric, in the order of an evaluation's rows and table
REGISTRY = {m.name: m for m in (field.POINTS, field.IMAGE)}


def score_pair(pair: Pair) -> dict:
    """Every registered metric's block for ``pair``, by name."""
    return {name: metric.score(pair) for name, metric in REGISTRY.items()}


def metric_columns(row: dict, result: dict) -> dict:
    """The table's columns of one evaluation row (``row[name]`` the blocks), metric by metric; a metric
    the row was not scored by (rows made before it was registered, or by another scorer) has none."""
    out = {}
    for name, metric in REGISTRY.items():
        if name in row:
            out |= metric.columns(row[name], result)
    return out
