"""The intensity of a re-simulated return: the primary point's, carried or corrected.

``carry``: the return takes the intensity the primary scanner recorded for
its point (times the footprint share with beam divergence: a return lit by
part of the beam sends back that part of the energy).

``correct``: a simple model of raw intensity, that of a Lambertian target
filling the beam: received power ~ reflectivity * cos(incidence) / R^2. The
primary recorded ``I0`` at range ``R0`` and incidence ``a0``; seen at ``R``
and ``a`` the same surface gives::

    I = I0 * (R0 / R)^2 * cos(a) / cos(a0)

clipped to ``[0, max(I0)]`` of the cloud (a sensor's scale saturates), with
``cos`` floored at ``cos(85 deg)`` (normals of grazing surfaces are noisy).
Many units normalise intensity for range themselves (KITTI's are nearly
range-free): use ``carry`` for those. A cloud without intensity gets none:
nothing is invented.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["corrected_intensity", "COS_FLOOR"]

#: cosines of incidence are floored here (85 deg)
COS_FLOOR = math.cos(math.radians(85.0))


def corrected_intensity(intensity, range_new, range_old, cos_new, cos_old, ceiling=None) -> np.ndarray:
    """``(m,)`` intensity seen at ``range_new`` and incidence cosine ``cos_new`` of a
    return the primary saw with ``intensity`` at ``range_old``, ``cos_old`` (module docstring)."""
    i0 = np.asarray(intensity, np.float64)
    r = np.maximum(np.asarray(range_new, np.float64), 1e-6)
    r0 = np.asarray(range_old, np.float64)
    c = np.maximum(np.abs(np.asarray(cos_new, np.float64)), COS_FLOOR)
    c0 = np.maximum(np.abs(np.asarray(cos_old, np.float64)), COS_FLOOR)
    out = i0 * (r0 / r) ** 2 * (c / c0)
    top = float(i0.max(initial=0.0)) if ceiling is None else float(ceiling)
    return np.clip(out, 0.0, top)
