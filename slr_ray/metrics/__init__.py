"""Every metric slr_ray computes, in one home.

- :mod:`~slr_ray.metrics.coverage`: scan agreement, the paper's: coverage
  (:func:`similarity`), precision and F-score (:func:`agreement`), and the
  one kd-tree lookup :func:`nearest`;
- :mod:`~slr_ray.metrics.field`: the novel-view field's metrics of a
  simulated frame against a real one: Chamfer distance and F-scores
  (:func:`point_metrics`), depth errors and ray drop
  (:func:`range_image_metrics`), split by range band, beam and what the
  primary saw (:func:`seen_from`);
- :mod:`~slr_ray.metrics.intensity`: intensity scores (:func:`intensity_metrics`);
- :mod:`~slr_ray.metrics.runs`: a validation run's statistics from its rows
  (:func:`headline`, :func:`series`, :func:`series_stats`, :func:`full_pairs`);
- :mod:`~slr_ray.metrics.cellgrid`: :class:`CellGrid`, the fixed-radius
  neighbour test the agreement and F-scores run on;
- :mod:`~slr_ray.metrics.registry`: :data:`REGISTRY`, the metrics an
  evaluation scores (:class:`Metric` entries of a :class:`Pair`): a new one
  is a module here and its entry in the registry's line.

The old paths still import: ``slr_ray.similarity`` and ``slr_ray.cellgrid``
are :mod:`~slr_ray.metrics.coverage` and :mod:`~slr_ray.metrics.cellgrid`,
and what ``slr_ray/metrics.py`` held is named here.
"""

from .cellgrid import CellGrid, GridUnsuitable
from .coverage import Agreement, agreement, nearest, nearest_distances, similarity
from .field import (FIELD_THRESHOLD, LIDAR4D_CODE_THRESHOLD, PAPER_THRESHOLD, RANGE_BANDS, PointMetrics,
                    RangeImageMetrics, point_metrics, range_bands, range_image_metrics, seen_from)
from .intensity import intensity_metrics
from .metric import Metric, Pair
from .registry import REGISTRY, metric_columns, score_pair
from .runs import full_pairs, headline, series, series_stats

__all__ = ["point_metrics", "PointMetrics", "range_image_metrics", "RangeImageMetrics", "seen_from",
           "nearest", "nearest_distances", "range_bands", "RANGE_BANDS", "FIELD_THRESHOLD", "PAPER_THRESHOLD",
           "LIDAR4D_CODE_THRESHOLD", "similarity", "agreement", "Agreement", "intensity_metrics", "headline",
           "series", "series_stats", "full_pairs", "CellGrid", "GridUnsuitable", "Metric", "Pair", "REGISTRY",
           "score_pair", "metric_columns"]
