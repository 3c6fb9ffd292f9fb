"""What a metric is to slr_ray: :class:`Metric`, one entry of the registry
:data:`slr_ray.metrics.registry.REGISTRY`, and :class:`Pair`, what it scores.

A metric module (``field`` holds the field's two: ``POINTS`` and ``IMAGE``)
defines its score and its table columns and one ``Metric`` entry; the
registry lists it. :func:`slr_ray.evaluate.evaluate_pair` scores every
registered metric for every method (a block of the row under the metric's
name), and :func:`~slr_ray.evaluate.evaluation_table` asks each for its
columns.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["Metric", "Pair"]


@dataclass(frozen=True)
class Pair:
    """One simulation beside the real frame it is scored against.

    Attributes
    ----------
    target : (n, 3) float64
        The real frame's points (in its table's view).
    simulated : (m, 3) float64
        The simulation's points, in the same frame.
    real_image, image : (rows, cols) float64
        The real and simulated range images (NaN: no return).
    thresholds : tuple of float
        The distance thresholds (m) of the F-scores.
    point_groups : dict
        name -> ``(n,)`` labels of the target points (the splits).
    pulse_groups : dict
        name -> labels of the pulses (``(rows, cols)``, or ``(rows,)`` by beam).
    """

    target: np.ndarray
    simulated: np.ndarray
    real_image: np.ndarray
    image: np.ndarray
    thresholds: tuple = ()
    point_groups: dict = field(default_factory=dict)
    pulse_groups: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Metric:
    """One metric of a simulated frame against the real one.

    Attributes
    ----------
    name : str
        Its block's key in an evaluation's rows (``'points'``, ``'image'``).
    score : callable
        ``score(pair: Pair) -> dict``: the block, JSON-ready (a ``groups``
        entry, name -> label -> figures, makes rows of ``splits.csv``).
    columns : callable
        ``columns(block, result) -> dict``: its columns of the table
        (``result``: the evaluation, for its ``thresholds`` and
        ``seen_threshold``).
    """

    name: str
    score: Callable
    columns: Callable
