"""The primary's pattern estimated from its cloud and origin (``primary_pattern='fit'``).

A KITTI-like frame (points stored beam by beam, 64 rings: :func:`slr_ray.sensors.scan_order_beams`)
gets the HDL-64E S2 table fitted to it as :mod:`slr_ray.evaluate` fits it (each beam's elevation the
median of its points', columns from the azimuth step along a beam). Any other cloud gets a uniform
grid: its zenith and azimuth steps are the typical angular offsets between a point and the next point
above it in its column and right of it in its row (four azimuth sectors of at most 65,536 points
each, seen from the origin; one neighbour on one side, so jittered angles do not shorten the steps),
the zenith rows placed so that the points lie mid-row. A scan whose steps are within
:data:`FIT_STEP_TOLERANCE` of a uniform fit's is taken for the primary's own pattern
(:func:`fitted_grid_holds`). The azimuth
columns of a :class:`~slr_ray.ScanPattern` start at 0: a scanner whose columns do not is fitted with
its own steps but columns split between its points. The scanner's axes are taken to be the cloud's
(a levelled scan; a tilted one needs its points in the scanner's frame).

A fit is checked before it is used (:func:`fit_quality`): a scan from the origin returns one point a
pulse, so most occupied pulses of the fitted grid hold one point (the project's real scans: 0.88-0.99,
a KITTI frame's fitted table 0.90); points that are no scan from there (random points, a scan seen
from 1 m aside, two merged scans, a voxel-thinned or airborne cloud: 0.54-0.74) crowd two or more into
many pulses and leave their neighbours empty. Below :data:`FIT_MIN_SINGLE` the fit is refused:
pulse-grid discs sized from a grid that is not there are wrong, and a caller who asked for it should
know. A scan with second returns in more than about a fifth of its pulses falls below it too (give
its pattern, or fit its first returns).
"""

from __future__ import annotations

import math

import numpy as np

from ... import lazy
from ...arrays import as_origin
from ...errors import InputValueError
from ...pattern import ScanPattern
from ...sensors import fitted_pattern, scan_order_beams, sensor

#: scipy.spatial, loaded on first use (slr_ray.lazy: the command line starts without it)
scipy_spatial = lazy.module("scipy.spatial")

__all__ = ["fit_primary_pattern", "fitted_grid_holds", "fit_quality", "FIT", "FIT_SENSOR", "FIT_STEP_TOLERANCE",
           "FIT_MIN_SINGLE"]

#: the value of ``primary_pattern`` asking for the fit
FIT = "fit"
#: the beam table fitted to a frame stored beam by beam (its 64 rings)
FIT_SENSOR = "velodyne_hdl64e_s2"
_SECTOR_POINTS = 1 << 16
#: a uniform fit's steps are estimates: a scan pattern whose steps are within this share of them is
#: taken for the primary's own (the forest scan's fit is 0.25 % off its documented steps)
FIT_STEP_TOLERANCE = 0.02
#: a fit is a scan's grid where at least this share of its occupied pulses holds one point (the
#: project's real scans 0.88-0.99, KITTI frames' tables 0.90, clouds that are no scan from the origin 0.54-0.74)
FIT_MIN_SINGLE = 0.8


def fit_primary_pattern(points, origin, min_quality: float = FIT_MIN_SINGLE):
    """``(pattern, how, quality)``: the primary's pattern fitted to ``points`` seen from ``origin``
    (module docstring), a line saying which fit it is, and the fit's :func:`fit_quality`. Raises
    InputValueError where the points show no grid, or where the fitted one holds them as no scan
    would (quality below ``min_quality``; 0: any fit)."""
    p = np.asarray(points, np.float64) - as_origin(origin, "primary_origin")
    base = sensor(FIT_SENSOR)
    beams = scan_order_beams(p, base.n_beams)
    if beams is not None:
        beams = np.asarray(base.beam_of_row)[beams]  # rows to the table's beam ids (fitted_pattern's, pulse_ids')
        pattern = fitted_pattern(p, beams, base)
        quality = fit_quality(p, pattern, beams)
        how = f"beam table: {FIT_SENSOR} fitted to the cloud's {base.n_beams} rings (scan order)"
    else:
        pattern, quality = _fit_uniform(p)
        how = (f"uniform: steps {pattern.zenith_resolution:.5g} deg (zenith) x "
               f"{pattern.azimuth_resolution:.5g} deg (azimuth) from the points' angular spacing")
    if not quality >= min_quality:
        raise InputValueError(
            f"primary_pattern='fit': the cloud is no scan from primary_origin: the fitted grid ({how}) holds one "
            f"point in {quality:.0%} of its occupied pulses, a scan's in {min_quality:.0%} or more (give "
            "primary_resolution or primary_pattern, or no primary: kNN discs)")
    return pattern, f"{how}; one point in {quality:.1%} of its occupied pulses", quality


def fit_quality(points, pattern, beams=None) -> float:
    """The share of the occupied pulses of ``pattern`` that hold exactly one of ``points`` (relative to
    the scanner's origin; ``beams``: each point's beam, for a beam table): near 1 for a scan from there
    (one return a pulse), about 0.55 for random points (module docstring)."""
    keys, _ = pattern.pulse_ids(np.asarray(points, np.float64), np.zeros(3), beams)
    return _single_share(keys)


def _single_share(keys) -> float:
    keys = np.sort(keys[keys >= 0])
    if len(keys) == 0:
        return 0.0
    first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    counts = np.diff(np.r_[first, len(keys)])
    return float(np.mean(counts == 1))


def fitted_grid_holds(pattern, fitted) -> bool:
    """Whether ``pattern`` is, within what a fit can tell, the uniform grid ``fitted`` was fitted to:
    both uniform, each step within :data:`FIT_STEP_TOLERANCE` of the fitted one (the zenith range's
    start aside: the fitted rows' phase is as uncertain as their step)."""
    if getattr(pattern, "has_beams", False) or getattr(fitted, "has_beams", False):
        return False
    return all(abs(a / b - 1.0) <= FIT_STEP_TOLERANCE
               for a, b in ((pattern.azimuth_resolution, fitted.azimuth_resolution),
                            (pattern.zenith_resolution, fitted.zenith_resolution)))


def _fit_uniform(p):
    """``(pattern, quality)``: the uniform grid of ``p``'s angular spacing (module docstring) and its
    :func:`fit_quality` on the points it was fitted to."""
    rho = np.hypot(p[:, 0], p[:, 1])
    keep = (rho > 0) | (p[:, 2] != 0)
    theta = np.arctan2(rho[keep], p[keep, 2])
    phi = np.mod(np.arctan2(p[keep, 1], p[keep, 0]), 2 * math.pi)
    n = len(theta)
    if n < 16:
        raise InputValueError(f"primary_pattern='fit' needs a cloud to fit: {n} point(s) seen from primary_origin")
    width = 2 * math.pi / 4 * min(1.0, _SECTOR_POINTS / (n / 4))
    sectors = [np.flatnonzero((phi >= a0) & (phi < a0 + width)) for a0 in np.arange(4) * (math.pi / 2)]
    sectors = [m for m in sectors if len(m) >= 8]
    v0, h0 = _rough_steps(theta, phi, sectors)
    if v0 is None or h0 is None:
        raise InputValueError("primary_pattern='fit': the points show no grid of rows and columns seen from "
                              "primary_origin (give primary_resolution or primary_pattern)")
    vert, horiz = _row_offsets(theta, phi, sectors, v0, h0)
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
    pattern = ScanPattern(azimuth_resolution=360.0 / columns, zenith_resolution=_snap_degrees(math.degrees(d_theta)),
                          zenith_range=(math.degrees(lo), 180.0), name="fitted to the cloud")
    # the quality on the sectors' points, in the columns that lie whole within a sector
    d_t, d_p = math.radians(pattern.zenith_resolution), 2 * math.pi / columns
    m = np.concatenate(sectors)
    v = np.floor((theta[m] - math.radians(lo)) / d_t).astype(np.int64)
    h = np.minimum(np.floor(phi[m] / d_p).astype(np.int64), columns - 1)
    whole = np.zeros(len(m), bool)
    for a0 in np.arange(4) * (math.pi / 2):
        whole |= (h * d_p >= a0) & ((h + 1) * d_p <= a0 + width)
    whole &= v >= 0
    return pattern, _single_share(np.where(whole, v * columns + h, -1))


def _rough_steps(theta, phi, sectors):
    """Rough steps ``(v0, h0)`` (radians, or None): ``v0`` from each point's nearest neighbour straight
    above or below it among its six nearest on the sphere; ``h0`` from the nearest right of it in its
    row, the zenith axis stretched 1, 4, 16, 64 times (in units of ``v0``) until most points have one
    among their eight nearest (a scan's columns are often ten times as far apart as its rows). To a
    few per cent: short where the angles are jittered, the nearer of two jittered offsets."""
    vert = []
    for m in sectors:
        th, ph = theta[m], phi[m]
        st = np.sin(th)
        xy = np.column_stack([th, ph * st])
        _, idx = scipy_spatial.cKDTree(xy).query(xy, k=min(7, len(m)))
        dth = th[idx[:, 1:]] - th[:, None]
        dah = (ph[idx[:, 1:]] - ph[:, None]) * st[:, None]
        up = (np.abs(dah) < 0.25 * np.abs(dth)) & (dth != 0)
        vert.append(np.where(up, np.abs(dth), np.inf).min(axis=1))
    vert = _finite(vert)
    if len(vert) < 8:
        return None, None
    v0 = _step(vert)
    for stretch in (1.0, 4.0, 16.0, 64.0):
        horiz = _finite([_right_offsets(theta[m], phi[m], v0, stretch / v0, 1.0) for m in sectors])
        if len(horiz) >= 0.5 * sum(len(m) for m in sectors):
            break
    return v0, (_step(horiz) if len(horiz) >= 8 else None)


def _right_offsets(th, ph, v0, sth, sph):
    """Each point's azimuth offset to the next point right of it in its row, among its eight nearest in
    angles scaled by ``sth`` (zenith) and ``sph`` (azimuth, along the sphere); in its row: within half
    a row ``v0`` and a quarter of the offset along the sphere (a pulse's other returns left out)."""
    st = np.sin(th)
    xy = np.column_stack([th * sth, ph * st * sph])
    _, idx = scipy_spatial.cKDTree(xy).query(xy, k=min(9, len(th)))
    dth = np.abs(th[idx[:, 1:]] - th[:, None])
    dph = ph[idx[:, 1:]] - ph[:, None]
    ok = (dph > 0) & (dth < 0.5 * v0) & (dth < 0.25 * dph * st[:, None])
    return np.where(ok, dph, np.inf).min(axis=1)


def _row_offsets(theta, phi, sectors, v0: float, h0: float):
    """Each point's offset to the next point above it in its column and to the next one right of it in
    its row, given rough steps ``v0``, ``h0`` (radians): in angles scaled to a unit grid and stretched
    across the axis measured, so that a point's own column (row) holds its nearest neighbours. One
    neighbour on one side, not the nearer of two, and no sampling bias: unbiased under jitter (the
    forest scan's 1 mm coordinates, 0.01-0.04 deg at 1.5-7 m)."""
    vert, horiz = [], []
    for m in sectors:
        th, ph = theta[m], phi[m]
        xy = np.column_stack([th / v0, ph * (2.0 / h0)])
        _, idx = scipy_spatial.cKDTree(xy).query(xy, k=min(9, len(m)))
        dth = th[idx[:, 1:]] - th[:, None]
        dah = np.abs(ph[idx[:, 1:]] - ph[:, None]) * np.sin(th)[:, None]
        # within its column (half a column either side), a pulse's other returns left out by the cone
        ok = (dth > 0) & (dah < 0.5 * h0 * np.sin(th)[:, None]) & (dah < 0.25 * dth)
        vert.append(np.where(ok, dth, np.inf).min(axis=1))
        horiz.append(_right_offsets(th, ph, v0, 2.0 / v0, 1.0 / h0))
    return _finite(vert), _finite(horiz)


def _finite(parts) -> np.ndarray:
    a = np.concatenate(parts) if parts else np.empty(0)
    return a[np.isfinite(a)]


def _snap(step: float) -> float:
    """``step`` (radians), or the nearest 2 pi / integer within a millionth of it."""
    k = round(2 * math.pi / step)
    return 2 * math.pi / k if k and abs(2 * math.pi / k - step) <= 1e-6 * step else step


def _snap_degrees(deg: float) -> float:
    """``deg`` rounded to 12 significant digits (0.19999999999999996 is 0.2, as a user would give it)."""
    return float(f"{deg:.12g}")


def _step(d) -> float:
    """The grid step in offsets ``d`` (radians) between a point and its neighbours along one axis: the
    median offset, then three times the mean of the offsets within a fifth of a step of the last
    (neighbours two steps away, across a lost pulse, count at half their offset; offsets much shorter
    than a step, a pulse's other returns, drop out as the mean moves to the step's)."""
    s = float(np.median(d))
    for _ in range(3):
        k = np.maximum(np.round(d / s), 1.0)
        near = np.abs(d / k - s) < 0.2 * s
        if not np.any(near):
            break
        s = float(np.mean((d / k)[near]))
    return s
