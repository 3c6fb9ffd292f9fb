"""A scan with effects as the images a real frame is scored by.

:func:`range_image` turns an :class:`~slr_ray.effects.EffectScan` (one row
per return) into the images :func:`slr_ray.metrics.range_image_metrics` and
:func:`slr_ray.metrics.intensity_metrics` score: per pulse the nearest
return's range, the scanned point behind it and its intensity (one value per
pulse, as a single-return image holds). The scores themselves live in
:mod:`slr_ray.metrics` (``intensity_metrics`` is still importable from here).
"""

from __future__ import annotations

import numpy as np

from ..metrics import intensity_metrics

__all__ = ["range_image", "intensity_metrics"]


def range_image(es) -> dict:
    """The nearest return of each pulse of ``es`` (an :class:`~slr_ray.effects.EffectScan`) as images.

    Returns
    -------
    dict
        ``range`` (rows, cols) float64, NaN where the pulse has no return;
        ``index`` (rows, cols) int64 into the scanned cloud, -1 there;
        ``row`` (rows, cols) int64 into ``es``'s returns, -1 there;
        ``intensity`` (rows, cols) float64 (NaN there) or None when ``es`` has none.
    """
    nv, nh = es.pattern.shape
    key = es.pulses[:, 0] * nh + es.pulses[:, 1]
    order = np.lexsort((np.arange(len(key)), es.ranges, key))  # by pulse, then range, then row
    k = key[order]
    first = order[np.r_[True, k[1:] != k[:-1]]] if len(k) else np.zeros(0, np.int64)
    out = {"range": np.full(nv * nh, np.nan), "index": np.full(nv * nh, -1, np.int64),
           "row": np.full(nv * nh, -1, np.int64)}
    out["range"][key[first]] = es.ranges[first]
    out["index"][key[first]] = es.indices[first]
    out["row"][key[first]] = first
    if es.intensity is not None:
        out["intensity"] = np.full(nv * nh, np.nan)
        out["intensity"][key[first]] = es.intensity[first]
    else:
        out["intensity"] = None
    return {k: (v.reshape(nv, nh) if v is not None else None) for k, v in out.items()}
