"""Pulse keys of a uniform (zenith, azimuth) grid: the exact angle kernels.

The definition (docs/backends.md, "What a scan returns"): of a point less the scanner
origin, in float64, ``v = floor((atan2(hypot(dx, dy), dz) - theta_min) /
d_theta)`` and ``h = floor(atan2(dy, dx) mod 2 pi / d_phi)``, the last bin of
each axis taking what rounding puts beyond it; the pulse key is ``v *
n_azimuth + h``. Every part of slr_ray that bins points into a uniform
pattern (the binning backend, streamed scans, mesh ground truths, the embree
backend's pulse grid, :func:`slr_ray.spherical.pulse_bins`) computes it here,
so a point on a bin edge falls on the same side everywhere.

How it runs: a compiled loop (numba) takes the points in blocks of
:data:`BLOCK`, subtracts the origin in float64 and computes both angles with a
branch-free polynomial ``atan2`` that the compiler vectorises (one division
per angle, a 7-term Chebyshev polynomial; error below 1e-11 rad); a second
vectorised pass turns them into keys wherever they decide the bin for
certain; a point within 1e-8 rad of a bin edge, a field-of-view limit or the
azimuth wrap (a few in 10^5), or within 1e-140 m of the origin (where the
squares the fast angles take are subnormal), is left to a third pass, run
only for a block that has such points, that takes its bin from the C
library's ``atan2``: every key is exactly the definition's *for the float64
offsets* ``dx = x - ox``... as computed. Those offsets are the exact
differences of the stored coordinates when point and origin lie within a
factor of two of each other on an axis (Sterbenz's lemma: a UTM cloud with
its scanner inside it), or when both are multiples of one power of two
``2**-k`` below ``2**(53 - k)`` (1/1024 m up to 8.8e12 m); then moving cloud
and origin by such an offset changes no key (tested:
``test_scans_do_not_depend_on_where_the_cloud_lies``). Adding an offset to
arbitrary float64 coordinates rounds them (by up to 4.7e-10 m at 4e6 m): that
is another cloud, and a point that close to a bin edge may change bin.

Keys: ``>= 0`` seen; -1 not seen (range 0, outside the view or the range
limits); -2 not finite.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from ..arrays import as_origin
from ..threads import default_threads

__all__ = ["grid_keys", "ranges_of", "kernel_params", "block_keys", "block_keys_range", "keys_exact",
           "count_nonfinite", "ranges_into", "scratch", "atan2_fast", "BLOCK", "FAST_TOL", "APPROX_MATH"]

#: points per block: the scratch arrays (5 x 4 KiB) stay in the L1 cache
BLOCK = 512

# atan(t) / t as a polynomial in t^2 for |t| <= tan(pi/8): the degree-6
# Chebyshev interpolant at the first-kind nodes (its error, measured against
# mpmath, is 8e-12 rad; tests/test_binning.py checks 1e-10 against libm). Seven
# terms instead of the thirteen of the Taylor series the first version used.
_ATAN_C = (0.9999999999783985, -0.333333320976113, 0.19999883856645354, -0.14281588774020137,
           0.1104048923222256, -0.08456192859922249, 0.04707347983517718)
_TAN_PI_8 = 0.41421356237309503
#: bound used on |fast angle - libm angle| (radians), far above the true ~1e-11
FAST_TOL = _FAST_TOL = 1e-8
#: below this range (metres) the squares in the fast angles may be subnormal:
#: ``sqrt(dx * dx + dy * dy)`` is then off by up to ~2.2e-162 m (a zenith error
#: of that over the range: 0.1 rad at 2e-161 m), so neither the fast bin nor the
#: fast view test is trusted there; above it the error is below 1e-21 rad
_R_SURE = 1e-140
#: the polynomial may be contracted into FMAs and divide by reciprocals: it is
#: only used where its error bound decides the bin for certain
APPROX_MATH = _APPROX_MATH = {"contract", "arcp"}


@njit(cache=True, inline="always", fastmath=_APPROX_MATH, error_model="numpy")
def _atan2_fast(y, x):
    """atan2(y, x) to ~1e-11 rad, branch-free so that loops vectorise.

    NaN when x = y = 0; callers check such points with the exact path. The
    bound holds where ``max(|x|, |y|)`` is at least ~1e-300: below, the branch
    test ``mn > tan(pi/8) * mx`` rounds among subnormals and the error reaches
    3e-8 rad (callers send such points to the exact path too: the grid kernel
    through its range and zenith tests, the beam kernel through ``AXIS``).
    """
    ax = abs(x)
    ay = abs(y)
    mn = min(ax, ay)
    mx = max(ax, ay)
    # one division: t = a or (a - 1) / (a + 1) for a = mn / mx, without forming a
    # (divisions, not the polynomial, are what this costs)
    big = mn > _TAN_PI_8 * mx
    num = mn - mx if big else mn
    den = mn + mx if big else mx
    t = num / den
    base = math.pi / 4 if big else 0.0
    t2 = t * t
    p = _ATAN_C[6]
    p = p * t2 + _ATAN_C[5]
    p = p * t2 + _ATAN_C[4]
    p = p * t2 + _ATAN_C[3]
    p = p * t2 + _ATAN_C[2]
    p = p * t2 + _ATAN_C[1]
    p = p * t2 + _ATAN_C[0]
    r = base + t * p
    r = (math.pi / 2 - r) if ay > ax else r
    r = (math.pi - r) if x < 0.0 else r
    return -r if y < 0.0 else r


#: the fast ``atan2`` under its public name (the beam-table kernels use it too)
atan2_fast = _atan2_fast


@njit(cache=True, nogil=True, fastmath=_APPROX_MATH, error_model="numpy")
def _approx_angles(x, y, z, theta, phi, n):
    for i in range(n):
        theta[i] = _atan2_fast(math.sqrt(x[i] * x[i] + y[i] * y[i]), z[i])
        phi[i] = _atan2_fast(y[i], x[i])


@njit(cache=True, inline="always", error_model="numpy")
def _bins_exact(dx, dy, dz, d_theta, d_phi, th0, th1, nv, nh):
    """(v, h) with libm's atan2 and hypot: the definition. v = -1 outside the view."""
    theta = math.atan2(math.hypot(dx, dy), dz)
    if theta < th0 or theta > th1:
        return np.int64(-1), np.int64(-1)
    v = np.int64(math.floor((theta - th0) / d_theta))
    if v >= nv:
        v = nv - 1
    phi = math.atan2(dy, dx)
    if phi < 0.0:
        phi += 2.0 * math.pi
    h = np.int64(math.floor(phi / d_phi))
    if h >= nh:
        h = nh - 1
    return v, h


@njit(cache=True, nogil=True, error_model="numpy")
def _sure_keys(x, y, z, theta, phi, n, inv_dt, inv_dp, th0, th1, nh, rmin, rmax, tol_v, tol_h,
               keys, ranges):
    """Keys the approximate angles decide for certain; -3 where they do not.

    Branch-free (selects only), so the compiler vectorises it. Key -1: surely
    not seen (a finite range outside the limits, or an angle more than
    ``_FAST_TOL`` outside the field of view). Key -3: near a bin edge, the
    view's edge or the azimuth wrap, within ``_R_SURE`` of the origin, or not
    finite: decided by :func:`_fix_keys` with libm. ``r`` is computed without
    contraction, so it is bit for bit the range every other path computes.
    Multiplying by the inverse bin width instead of dividing moves ``q`` by a
    few ulp, far inside the ``1e-12 * q`` margin.

    Each two-sided test is one comparison of a distance to a centre: ``lo <=
    a <= hi`` as ``|a - (lo + hi) / 2| <= (hi - lo) / 2`` (a bin's fraction
    ``e`` against its margins, the zenith against the view, the azimuth
    against the wrap), and the range's four tests as two against limits that
    exclude infinity and ranges below ``_R_SURE`` (0 among them: there the
    fast angles are not within their bound, so only the range may decide);
    the roundings this adds (~1e-16 of a bin or a radian) are 10^8 times
    smaller than the margins. NaN fails every test.
    Returns the number of keys left at -3, so that a block with none skips
    the third pass (most blocks: a few points in 10^5 are near an edge).
    What the folded tests and the skip gained: docs/speed.md
    (``python benchmarks/compare_checkouts.py``).
    """
    two_pi = 2.0 * math.pi
    r_lo = max(rmin, _R_SURE)  # r > 0 and r >= rmin, and no subnormal squares
    r_hi = min(rmax, 1.7976931348623157e308)  # r <= rmax and r < inf
    t_mid = 0.5 * (th0 + th1)
    t_in = 0.5 * (th1 - th0) - _FAST_TOL  # surely inside the view
    t_out = 0.5 * (th1 - th0) + _FAST_TOL  # surely outside it
    p_in = math.pi - _FAST_TOL  # surely clear of the wrap
    unsure = 0
    for i in range(n):
        dx = x[i]
        dy = y[i]
        dz = z[i]
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        ranges[i] = r
        t = theta[i]
        p = phi[i]
        p = p + two_pi if p < 0.0 else p
        qv = (t - th0) * inv_dt
        qh = p * inv_dp
        fv = math.floor(qv)
        fh = math.floor(qh)
        ev = abs(qv - fv - 0.5)  # qv - fv is exact, in [0, 1)
        eh = abs(qh - fh - 0.5)
        mv = 0.5 - (tol_v + 1e-12 * qv)
        mh = 0.5 - (tol_h + 1e-12 * qh)
        dt = abs(t - t_mid)
        inside = ((r >= r_lo) & (r <= r_hi) & (dt <= t_in) & (abs(p - math.pi) <= p_in)
                  & (ev <= mv) & (eh <= mh))
        outside = (r < math.inf) & ((r < rmin) | (r > rmax) | ((dt > t_out) & (r >= _R_SURE)))
        # int64 arithmetic: keys reach 2**62, beyond a double's exact integers
        k = np.int64(fv) * nh + np.int64(fh)
        keys[i] = k if inside else (np.int64(-1) if outside else np.int64(-3))
        unsure += 0 if inside | outside else 1
    return unsure


@njit(cache=True, nogil=True, error_model="numpy")
def _fix_keys(x, y, z, n, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax, keys, ranges):
    """Decide the keys left at -3 by :func:`_sure_keys` with libm: the definition.

    Key -1: not seen (range 0, outside the view or the range limits);
    -2: not finite. Returns the number of non-finite rows.
    """
    bad = 0
    for i in range(n):
        if keys[i] != -3:
            continue
        dx = x[i]
        dy = y[i]
        dz = z[i]
        if not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)):
            keys[i] = -2
            ranges[i] = math.inf
            bad += 1
            continue
        r = ranges[i]
        if r == 0.0 or r < rmin or r > rmax:
            keys[i] = -1
            continue
        v, h = _bins_exact(dx, dy, dz, d_theta, d_phi, th0, th1, nv, nh)
        keys[i] = -1 if v < 0 else v * nh + h
    return bad


@njit(cache=True, nogil=True, error_model="numpy")
def block_keys(points, s, e, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                x, y, z, theta, phi, keys, ranges):
    """Keys and ranges of points[s:e] (at most BLOCK) into keys[:e-s], ranges[:e-s].

    Key -1: not seen (range 0, outside the view or the range limits);
    -2: not finite. Returns the number of non-finite rows.

    Three passes over the block, the first two vectorised: approximate angles,
    the keys they decide for certain, and libm for the few they do not (a few
    points in 10^5 at 0.144 deg).
    """
    n = e - s
    for i in range(n):
        x[i] = np.float64(points[s + i, 0]) - ox
        y[i] = np.float64(points[s + i, 1]) - oy
        z[i] = np.float64(points[s + i, 2]) - oz
    _approx_angles(x, y, z, theta, phi, n)
    unsure = _sure_keys(x, y, z, theta, phi, n, 1.0 / d_theta, 1.0 / d_phi, th0, th1, nh, rmin,
                        rmax, _FAST_TOL / d_theta, _FAST_TOL / d_phi, keys, ranges)
    if unsure == 0:  # most blocks: the third pass would only look
        return 0
    return _fix_keys(x, y, z, n, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax, keys, ranges)


@njit(cache=True)
def scratch():
    return (np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK),
            np.empty(BLOCK), np.empty(BLOCK, np.int64), np.empty(BLOCK))



@njit(cache=True, nogil=True, error_model="numpy")
def keys_exact(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, keys):
    """Keys with libm only (no fast path): for tests of the fast path."""
    for i in range(points.shape[0]):
        dx = np.float64(points[i, 0]) - ox
        dy = np.float64(points[i, 1]) - oy
        dz = np.float64(points[i, 2]) - oz
        v, h = _bins_exact(dx, dy, dz, d_theta, d_phi, th0, th1, nv, nh)
        keys[i] = -1 if v < 0 else v * nh + h


def kernel_params(origin, pattern):
    """The kernels' arguments after the points: origin, angles (radians), shape, range limits."""
    d_theta, d_phi, th0, th1 = pattern.radians
    rmin, rmax = pattern.range_limits
    nv, nh = pattern.shape
    return (float(origin[0]), float(origin[1]), float(origin[2]),
            d_theta, d_phi, th0, th1, np.int64(nv), np.int64(nh), rmin, rmax)


@njit(cache=True, nogil=True, error_model="numpy")
def count_nonfinite(points, start, stop):
    bad = 0
    for i in range(start, stop):
        if not (math.isfinite(points[i, 0]) and math.isfinite(points[i, 1])
                and math.isfinite(points[i, 2])):
            bad += 1
    return bad



@njit(cache=True, nogil=True, error_model="numpy")
def block_keys_range(points, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                      keys, ranges, start, stop):
    """Keys and ranges of points[start:stop] into keys[start:stop], ranges[start:stop]."""
    x, y, z, th, ph, kb, rb = scratch()
    for s in range(start, stop, BLOCK):
        e = min(stop, s + BLOCK)
        block_keys(points, s, e, ox, oy, oz, d_theta, d_phi, th0, th1, nv, nh, rmin, rmax,
                    x, y, z, th, ph, kb, rb)
        keys[s:e] = kb[: e - s]
        ranges[s:e] = rb[: e - s]



@njit(cache=True, nogil=True, error_model="numpy")
def ranges_into(points, idx, ox, oy, oz, out):
    """Ranges of points[idx], by the same arithmetic as the reduction."""
    for j in range(idx.shape[0]):
        i = idx[j]
        dx = np.float64(points[i, 0]) - ox
        dy = np.float64(points[i, 1]) - oy
        dz = np.float64(points[i, 2]) - oz
        out[j] = math.sqrt(dx * dx + dy * dy + dz * dz)



def grid_keys(points, origin, pattern):
    """Flat pulse key ``v * n_azimuth + h`` and range of every point, for a
    uniform grid (anything with ``radians``, ``range_limits`` and ``shape``:
    :class:`~slr_ray.pattern.ScanPattern`).

    The same compiled arithmetic as the reduction (:class:`~slr_ray.core.BinTables`),
    so a point on a bin edge falls on the same side here as in a scan. Key -1:
    not seen; -2: not finite.
    """
    keys = np.empty(len(points), dtype=np.int64)
    ranges = np.empty(len(points), dtype=np.float64)
    n = len(points)
    params = kernel_params(origin, pattern)
    # the kernel releases the GIL: large inputs are split over the cores (2.7 s -> 1.4 s on 58 M points)
    parts = max(1, min(default_threads(), n // (1 << 20)))
    if parts == 1:
        if n:
            block_keys_range(points, *params, keys, ranges, 0, n)
    else:
        cuts = [n * i // parts for i in range(parts + 1)]
        with ThreadPoolExecutor(parts) as pool:
            list(pool.map(lambda i: block_keys_range(points, *params, keys, ranges, cuts[i], cuts[i + 1]),
                          range(parts)))
    return keys, ranges


def ranges_of(points: np.ndarray, indices: np.ndarray, origin) -> np.ndarray:
    """``(m,) float64`` distances from ``origin`` of ``points[indices]``, in float64
    (float32 points are widened first), without copying the selected rows."""
    o = as_origin(origin)
    out = np.empty(len(indices), np.float64)
    ranges_into(points, np.asarray(indices, np.int64), float(o[0]), float(o[1]), float(o[2]), out)
    return out
