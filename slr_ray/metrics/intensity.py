"""Intensity scores: simulated intensity against a real frame's, per pulse.

:func:`intensity_metrics` scores simulated intensity against a real frame's
over the pulses where both return and both have a value: mean, median and
RMS absolute error, the bias (mean of simulated - real) and Pearson's
correlation. A simulated image without intensity (intensity off, or a cloud
without) scores nothing: every figure NaN, ``pulses`` 0. The images come from
:func:`slr_ray.effects.range_image` (a scan with effects) and a real frame's
range image.

>>> import numpy as np
>>> m = intensity_metrics(np.array([[0.2, 0.4, np.nan]]), np.array([[0.3, 0.4, 0.5]]))
>>> m["pulses"], round(m["mae"], 3), round(m["bias"], 3)
(2, 0.05, 0.05)
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputValueError

__all__ = ["intensity_metrics"]


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
