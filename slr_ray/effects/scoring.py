"""A scan with effects scored against a real frame: its range image, and intensity errors.

:func:`range_image` turns an :class:`~slr_ray.effects.EffectScan` (one row
per return) into the images :func:`slr_ray.metrics.range_image_metrics`
scores: per pulse the nearest return's range, the scanned point behind it
and its intensity (one value per pulse, as a single-return image holds).

:func:`intensity_metrics` scores simulated intensity against a real frame's
over the pulses where both return and both have a value: mean, median and
RMS absolute error, the bias (mean of simulated - real) and Pearson's
correlation. A simulated image without intensity (intensity off, or a cloud
without) scores nothing: every figure NaN, ``pulses`` 0.

>>> import numpy as np
>>> m = intensity_metrics(np.array([[0.2, 0.4, np.nan]]), np.array([[0.3, 0.4, 0.5]]))
>>> m["pulses"], round(m["mae"], 3), round(m["bias"], 3)
(2, 0.05, 0.05)
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputValueError

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


def intensity_metrics(real, simulated) -> dict:
    """Errors of ``simulated`` intensity against ``real`` (module docstring).

    Parameters
    ----------
    real : (rows, cols) float
        NaN where the real frame has no return.
    simulated : (rows, cols) float or None
        NaN where the simulation has no return (or no value); None: no intensity.

    Returns
    -------
    dict
        ``pulses`` (compared), ``mae``, ``medae``, ``rmse``, ``bias``, ``pearson``
        (NaN with fewer than two pulses or no spread).
    """
    a = np.asarray(real, np.float64)
    empty = {"pulses": 0, "mae": math.nan, "medae": math.nan, "rmse": math.nan, "bias": math.nan,
             "pearson": math.nan}
    if simulated is None:
        return empty
    b = np.asarray(simulated, np.float64)
    if a.shape != b.shape:
        raise InputValueError(f"real and simulated must be images of one shape, got {a.shape} and {b.shape}")
    both = np.isfinite(a) & np.isfinite(b)
    x, y = a[both], b[both]
    if len(x) == 0:
        return empty
    e = y - x
    sx, sy = x.std(), y.std()
    r = float(np.mean((x - x.mean()) * (y - y.mean())) / (sx * sy)) if len(x) > 1 and sx > 0 and sy > 0 \
        else math.nan
    return {"pulses": int(len(x)), "mae": float(np.mean(np.abs(e))), "medae": float(np.median(np.abs(e))),
            "rmse": float(np.sqrt(np.mean(e * e))), "bias": float(np.mean(e)), "pearson": r}
