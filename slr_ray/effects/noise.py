"""Range noise, the blind zone and the maximum range a target's reflectivity allows.

Range noise moves a return along its ray by a normal draw of
``sigma(R) = sigma_0 + slope * R`` (datasheets quote one sigma, "accuracy";
``slope`` lets it grow with range). A return nearer than ``min_range`` (the
blind zone) is dropped. Where intensity is known, a return is kept only up
to the range at which a target of its reflectivity still returns: a
datasheet's "50 m at 10 % reflectivity" with received power proportional
to ``rho / R^2`` (a Lambertian target filling the beam) gives
``R_max(rho) = 50 m * sqrt(rho / 0.10)``.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputValueError

__all__ = ["range_sigma", "add_range_noise", "reflectivity_max_range"]


def range_sigma(ranges, sigma: float, slope: float = 0.0) -> np.ndarray:
    """``(m,)`` noise sigma, metres, at ``ranges``."""
    return sigma + slope * np.asarray(ranges, np.float64)


def add_range_noise(ranges, sigma: float, slope: float = 0.0, rng=None) -> np.ndarray:
    """``ranges`` plus a normal draw of :func:`range_sigma` each (``rng``: a seed
    or a generator), never below 0. A sigma so large that a range overflows is
    an :class:`~slr_ray.errors.InputValueError` (not a file of infinite points)."""
    r = np.asarray(ranges, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        noisy = r + np.random.default_rng(rng).standard_normal(len(r)) * range_sigma(r, sigma, slope)
    if not np.isfinite(noisy).all():
        raise InputValueError(f"range noise sigma={sigma!r}, slope={slope!r} makes ranges overflow to infinity")
    return np.maximum(noisy, 0.0)


def reflectivity_max_range(reflectivity, range_at: float, reflectivity_at: float) -> np.ndarray:
    """``(m,)`` the farthest range a target of ``reflectivity`` (0-1) returns from,
    for a unit that reaches ``range_at`` metres at ``reflectivity_at``."""
    rho = np.clip(np.asarray(reflectivity, np.float64), 0.0, None)
    return range_at * np.sqrt(rho / reflectivity_at)
