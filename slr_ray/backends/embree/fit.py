"""The primary's pattern estimated from its cloud and origin (``primary_pattern='fit'``).

A KITTI-like frame (points stored beam by beam, 64 rings: :func:`slr_ray.sensors.scan_order_beams`)
gets the HDL-64E S2 table fitted to it as :mod:`slr_ray.evaluate` fits it (each beam's elevation the
median of its points', columns from the azimuth step along a beam). Any other cloud gets a uniform
grid: its zenith and azimuth steps are the typical angular offsets between a point and its nearest
neighbours straight above or below it and beside it (four azimuth sectors of at most 65,536 points
each, seen from the origin), the zenith rows placed so that the points lie mid-row. The azimuth
columns of a :class:`~slr_ray.ScanPattern` start at 0: a scanner whose columns do not is fitted with
its own steps but columns split between its points. The scanner's axes are taken to be the cloud's
(a levelled scan; a tilted one needs its points in the scanner's frame).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ...arrays import as_origin
from ...errors import InputValueError
from ...pattern import ScanPattern
from ...sensors import fitted_pattern, scan_order_beams, sensor

__all__ = ["fit_primary_pattern", "FIT", "FIT_SENSOR"]

#: the value of ``primary_pattern`` asking for the fit
FIT = "fit"
#: the beam table fitted to a frame stored beam by beam (its 64 rings)
FIT_SENSOR = "velodyne_hdl64e_s2"
_SECTOR_POINTS = 1 << 16


def fit_primary_pattern(points, origin):
    """``(pattern, how)``: the primary's pattern fitted to ``points`` seen from ``origin`` (module
    docstring), and a line saying which fit it is."""
    p = np.asarray(points, np.float64) - as_origin(origin, "primary_origin")
    base = sensor(FIT_SENSOR)
    beams = scan_order_beams(p, base.n_beams)
    if beams is not None:
        return fitted_pattern(p, beams, base), (f"beam table: {FIT_SENSOR} fitted to the cloud's {base.n_beams} "
                                                "rings (scan order)")
    pattern = _fit_uniform(p)
    return pattern, (f"uniform: steps {pattern.zenith_resolution:.5g} deg (zenith) x "
                     f"{pattern.azimuth_resolution:.5g} deg (azimuth) from the points' angular spacing")


def _fit_uniform(p) -> ScanPattern:
    rho = np.hypot(p[:, 0], p[:, 1])
    keep = (rho > 0) | (p[:, 2] != 0)
    theta = np.arctan2(rho[keep], p[keep, 2])
    phi = np.mod(np.arctan2(p[keep, 1], p[keep, 0]), 2 * math.pi)
    n = len(theta)
    if n < 16:
        raise InputValueError(f"primary_pattern='fit' needs a cloud to fit: {n} point(s) seen from primary_origin")
    width = 2 * math.pi / 4 * min(1.0, _SECTOR_POINTS / (n / 4))
    vert, horiz = [], []
    for s in range(4):
        a0 = s * math.pi / 2
        m = np.flatnonzero((phi >= a0) & (phi < a0 + width))
        if len(m) < 8:
            continue
        th, ph = theta[m], phi[m]
        st = np.sin(th)
        tree = cKDTree(np.column_stack([th, ph * st]))
        _, idx = tree.query(np.column_stack([th, ph * st]), k=min(7, len(m)))
        dth = th[idx[:, 1:]] - th[:, None]
        dph = ph[idx[:, 1:]] - ph[:, None]
        dah = dph * st[:, None]
        up = (np.abs(dah) < 0.25 * np.abs(dth)) & (dth != 0)
        side = (np.abs(dth) < 0.25 * np.abs(dah)) & (dph != 0)
        # each point's nearest neighbour above or below, and beside (the next but one is farther)
        v = np.where(up, np.abs(dth), np.inf).min(axis=1)
        h = np.where(side, np.abs(dph), np.inf).min(axis=1)
        vert.append(v[np.isfinite(v)])
        horiz.append(h[np.isfinite(h)])
    vert = np.concatenate(vert) if vert else np.empty(0)
    horiz = np.concatenate(horiz) if horiz else np.empty(0)
    if len(vert) < 8 or len(horiz) < 8:
        raise InputValueError("primary_pattern='fit': the points show no grid of rows and columns seen from "
                              "primary_origin (give primary_resolution or primary_pattern)")
    d_theta = _snap(_step(vert))
    d_phi = _step(horiz)
    columns = max(1, int(round(2 * math.pi / d_phi)))
    # rows mid-way between the points: the circular mean of their zenith phase is a row's centre
    ang = 2 * math.pi * theta / d_theta
    phase = math.atan2(float(np.mean(np.sin(ang))), float(np.mean(np.cos(ang)))) / (2 * math.pi) * d_theta
    lo = math.fmod(phase - 0.5 * d_theta, d_theta)
    lo = lo + d_theta if lo < 0 else lo
    if min(lo, d_theta - lo) < 1e-6 * d_theta:  # rows from the zenith
        lo = 0.0
    return ScanPattern(azimuth_resolution=360.0 / columns, zenith_resolution=_snap_degrees(math.degrees(d_theta)),
                       zenith_range=(math.degrees(lo), 180.0), name="fitted to the cloud")


def _snap(step: float) -> float:
    """``step`` (radians), or the nearest 2 pi / integer within a millionth of it."""
    k = round(2 * math.pi / step)
    return 2 * math.pi / k if k and abs(2 * math.pi / k - step) <= 1e-6 * step else step


def _snap_degrees(deg: float) -> float:
    """``deg`` rounded to 12 significant digits (0.19999999999999996 is 0.2, as a user would give it)."""
    return float(f"{deg:.12g}")


def _step(d) -> float:
    """The grid step in offsets ``d`` (radians) between a point and its neighbours along one axis: the
    median offset, then the mean of the offsets within a fifth of a step of it (neighbours two
    steps away, across a lost pulse, count at half their offset)."""
    s = float(np.median(d))
    k = np.maximum(np.round(d / s), 1.0)
    near = np.abs(d / k - s) < 0.2 * s
    return float(np.mean((d / k)[near])) if np.any(near) else s
