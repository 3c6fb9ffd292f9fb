"""The compiled cast loop of :class:`~slr_ray.raycast.RayScene` and its Embree filter.

:func:`cast_packets` hands Embree packets of ``width`` rays (``rtcIntersect4/8/16``,
or ``rtcIntersect1`` for a width of 1) through function pointers; :data:`FILTER`
is the filter callback (``RTCFilterFunctionN``) that skips discs holding the
scanner and implements the tie rule (package docstring). One struct layout
serves every width: Embree's ``RTCRayHitN`` (structure of arrays), which for
one ray is ``RTCRayHit``. Each ray of a packet carries its lane in the ray's
``id``: the filter keeps that lane's state in the query context, whatever
packet size Embree calls it with.
"""

from __future__ import annotations

import math

import numpy as np
from numba import carray, njit, types

from .. import lazy
from .cull import could_hit
from .intrinsics import as_pointer as _as_pointer, call3 as _call3, call4 as _call4, prefetch as _prefetch
from .library import FEATURE_FLAGS_ALL, INVALID_ID, RAY_QUERY_FLAG_INVOKE_ARGUMENT_FILTER

__all__ = ["cast_packets", "cast_each", "FILTER", "MODE_SKIP", "PACKET_WIDTHS", "silhouette_bit", "NO_CLIP",
           "CELLS_OFF", "CELLS_AND_SILHOUETTES", "CELLS_ONLY",
           "SILHOUETTE_PARALLAX"]

#: the packet widths Embree has (rtcIntersect1, 4, 8, 16)
PACKET_WIDTHS = (1, 4, 8, 16)
_MAX_WIDTH = 16
# RTCRayHitN, in 4-byte words of rows of N: the ray (org xyz, tnear, dir xyz, time, tfar, mask, id,
# flags), then the hit (Ng xyz, u, v, primID, geomID, instID[1], instPrimID[1]); for N = 1 that is
# RTCRayHit (the hit 16-byte aligned at word 12)
_ORG, _TNEAR, _DIR, _TIME, _TFAR, _MASK, _ID, _FLAGS = 0, 3, 4, 7, 8, 9, 10, 11
_PRIM, _GEOM, _INST, _INST_PRIM = 17, 18, 19, 20
_RAYHIT_ROWS = 22

# query context: RTCRayQueryContext (slots 0-3, 32 bytes reserved), what all rays share, then a
# block of state per lane
_C_CENTRES, _C_RADII, _C_DIV, _C_RSTRIDE, _C_ORG, _C_REACH, _C_ASPECT = 4, 5, 6, 7, 8, 11, 12
# one-pass ties: the normals (address, 4 or 8 bytes a value, 0: none), the tie factor; discs: the
# float32 vertex buffer (0: none) and the ray origin in its frame (float64)
_C_NORMALS, _C_NBYTES, _C_TIES, _C_VERTICES, _C_LOCAL = 13, 14, 15, 16, 17
# the silhouette rule: each owner's silhouette bits (uint8, 0: none), the primary's grid (float64:
# origin xyz, zenith min, zenith step (a beam table: its largest row gap), azimuth step, rows, columns) and its band edges (-cos, ascending)
_C_CLIP, _C_CLIP_GEO, _C_CLIP_EDGES, _C_CLIP_NEDGES = 20, 21, 22, 23
# and the primary's origin in the scene frame (float64 xyz: against the float32 vertices)
_C_CLIP_PO = 24
# where the rule holds: a hit at t from the ray origin, when t**2 >= this (the squared distance of the
# ray origin from the primary's, over SILHOUETTE_PARALLAX squared)
_C_CLIP_T2 = 27
_C_LANES = 28
# a lane: its mode and direction (float64); tie mode's best so far (owner, score, t, primitive);
# one pass: the nearest hit so far (t, owner, primitive), where the ray is cut, the candidates
_L_MODE, _L_DIR, _L_BEST, _L_SCORE, _L_BEST_T, _L_BEST_PRIM = 0, 1, 4, 5, 6, 7
_L_FIRST_T, _L_FIRST_OWNER, _L_FIRST_PRIM, _L_CULL, _L_NCAND, _L_INCOMPLETE, _L_CAND = 8, 9, 10, 11, 12, 13, 16
#: candidates a ray can hold in one pass (t, owner, primitive and a spare word each); beyond, a second query
_MAX_CANDIDATES = 64
_LANE_WORDS = _L_CAND + 4 * _MAX_CANDIDATES
_CTX_WORDS = _C_LANES + _MAX_WIDTH * _LANE_WORDS
#: sin(zenith) below which a ray counts as polar in the pulse-unit tie score
_MIN_RHO = 1e-9
#: the tie window stops growing beyond 20 radii (incidence above ~87 deg)
_MIN_COS = 0.05
MODE_SKIP, _MODE_TIES, _MODE_ONE_PASS, _MODE_CLIP = 1, 2, 4, 8
#: one pass: the ray is cut at the nearest hit's window times this, so that a nearer hit found
#: later whose window reaches a little further (an equal distance is common: duplicate points
#: with other normals) leaves the candidates complete; the window itself is unchanged
_CULL_PAD = 2.0


@njit(cache=True, nogil=True, inline="always")
def _tie_score(cx, cy, cz, dx, dy, dz, aspect):
    """The tie rule's rank of a candidate whose centre is at ``c`` from the ray origin
    (lower wins): its squared distance from the ray, or, with a pulse ``aspect``, its
    angular offset in pulse units: zenith and azimuth angles, the latter divided by
    sin(zenith) (pulses narrow towards the poles) and scaled by d_theta / d_phi, so
    that the point of the ray's own pulse wins over a nearer one of the next column."""
    t = cx * dx + cy * dy + cz * dz
    ex, ey, ez = cx - t * dx, cy - t * dy, cz - t * dz
    s = ex * ex + ey * ey + ez * ez
    if aspect > 0.0 and t > 0.0:
        rho = max(math.sqrt(dx * dx + dy * dy), _MIN_RHO)
        e_az = (ey * dx - ex * dy) / rho
        e_ze2 = max(s - e_az * e_az, 0.0)
        a = e_az * aspect / rho
        s = (e_ze2 + a * a) / (t * t)
    return s


@njit(cache=True, nogil=True, inline="always")
def _tie_window(ties, radius, has_normal, nx, ny, nz, dx, dy, dz):
    """The depth along the ray that a disc-sized step over the first disc's surface
    spans, times ``ties``: r / |cos(incidence)| (r for discs facing the ray)."""
    window = ties * radius
    if has_normal:
        cos = abs(nx * dx + ny * dy + nz * dz)
        window /= max(cos, _MIN_COS)
    return window


@njit(cache=True, nogil=True, inline="always")
def silhouette_bit(slot):
    """The bit of adjacent pulse ``slot`` (``(dv + 1) * 3 + dh + 1``; 4 is the pulse itself) in a
    point's silhouette bits."""
    return slot if slot < 4 else slot - 1


#: the silhouette rule holds for a hit at least 1 / SILHOUETTE_PARALLAX times as far from the ray's
#: origin as that origin lies from the primary's: seen from further aside, the primary's pulse cells
#: say little of what a ray meets, and cutting discs there lets rays through to points behind
#: (Experiment 1's embree rows lost 0.6 points of precision with the rule everywhere, rect-1000's
#: grazing ground 0.7; docs/backends.md, "The primary's own view and silhouettes")
SILHOUETTE_PARALLAX = 0.25

#: no silhouette rule (cast_packets' clip arguments)
NO_CLIP = (np.zeros(0, np.uint8), np.zeros(9), np.zeros(0))
#: the pulse-cell cut (``clip_geo[8]``): none; each disc within its owner's pulse of the primary, widened
#: by the parallax angle, and the silhouette rule; that cut alone (no silhouette bits known)
CELLS_OFF, CELLS_AND_SILHOUETTES, CELLS_ONLY = 0.0, 1.0, 2.0


@njit(cache=True, nogil=True, inline="always")
def _primary_cell(geo, edges, n_edges, x, y, z):
    """Row and column of the primary's pulse grid that holds direction ``(x, y, z) - origin``."""
    dx, dy, dz = x - geo[0], y - geo[1], z - geo[2]
    rho = math.sqrt(dx * dx + dy * dy)
    r = math.sqrt(rho * rho + dz * dz)
    if r == 0.0:
        return np.int64(-(1 << 40)), np.int64(0)
    phi = math.atan2(dy, dx)
    if phi < 0.0:
        phi += 2.0 * math.pi
    nh = np.int64(geo[7])
    h = min(np.int64(phi / geo[5]), nh - 1)
    if n_edges == 0:
        v = np.int64(math.floor((math.atan2(rho, dz) - geo[3]) / geo[4]))
    else:
        c = -dz / r
        lo, hi = 0, n_edges
        while lo < hi:  # the first edge above c
            mid = (lo + hi) // 2
            if edges[mid] <= c:
                lo = mid + 1
            else:
                hi = mid
        v = np.int64(lo - 1)
    return v, h


@njit(cache=True, nogil=True, inline="always")
def _outside_cell(ctx, ctxf, geo, owner, x, y, z, t):
    """The pulse-cell cut: whether the hit ``(x, y, z)`` at ``t`` on disc ``owner`` lies, as seen from
    the primary's origin, outside the owner's own pulse by more than the parallax angle (the ray
    origin's distance from the primary's over ``t``; 0 at the primary's origin, where each disc is
    cut to its pulse exactly)."""
    b = math.sqrt(ctxf[_C_CLIP_T2]) * SILHOUETTE_PARALLAX  # the ray origin's distance from the primary's
    if b > 0.0:
        # seen from the primary the hit lies within about r / (t - b - r) of the owner's direction, and the
        # owner in its pulse: no cut where that is within the parallax angle b / t (most hits away from the
        # primary's origin; the radius is read from Embree's vertex buffer, in cache)
        r = np.float64(carray(_as_pointer(ctx[_C_RADII] + owner * ctx[_C_RSTRIDE]), 1, dtype=np.float32)[0])
        if 1.5 * r * t <= b * (t - b - r):
            return False
    n_edges = ctx[_C_CLIP_NEDGES]
    edges = carray(_as_pointer(ctx[_C_CLIP_EDGES]), max(n_edges, 1), dtype=np.float64)
    cen = carray(_as_pointer(ctx[_C_CENTRES] + owner * 24), 3, dtype=np.float64)
    vc, hc = _primary_cell(geo, edges, n_edges, cen[0], cen[1], cen[2])
    vx, hx = _primary_cell(geo, edges, n_edges, x, y, z)
    if vc == vx and hc == hx:
        return False
    margin = b / t
    if margin == 0.0:
        return True
    # the hit's angles from the primary against the owner's cell, radians
    ax, ay, az = x - geo[0], y - geo[1], z - geo[2]
    rho = math.sqrt(ax * ax + ay * ay)
    theta = math.atan2(rho, az)
    if n_edges == 0:
        lo = geo[3] + vc * geo[4]
        hi = lo + geo[4]
    else:
        if vc < 0 or vc + 1 >= n_edges:
            return False  # the owner outside the table's bands: no cell to keep it in
        lo, hi = math.acos(-edges[vc]), math.acos(-edges[vc + 1])
    ex = max(0.0, lo - theta, theta - hi)
    phi = math.atan2(ay, ax)
    if phi < 0.0:
        phi += 2.0 * math.pi
    mid = (hc + 0.5) * geo[5]
    off = (phi - mid + math.pi) % (2.0 * math.pi) - math.pi
    ex = max(ex, (abs(off) - 0.5 * geo[5]) * math.sin(theta))
    return ex > margin


@njit(cache=True, nogil=True, inline="always")
def _clipped(ctx, ctxf, owner, t, dx, dy, dz):
    """The silhouette rule: whether the hit at ``t`` on disc ``owner`` lies, as seen from the primary's
    origin, beyond the pulses next to the owner's own (in azimuth, where columns are narrower than a
    row, as far as a row's height), or in a pulse next to it where the owner stands at a silhouette
    (its bit set: that pulse's own return lies behind). Pulses are counted exactly for the owners at
    a silhouette; for the others (nearly all) by the hit's angular offset, 1.5 pulses."""
    if t * t < ctxf[_C_CLIP_T2]:
        return False  # seen from too far aside of the primary's origin: its pulses are no guide here
    bits = np.int64(carray(_as_pointer(ctx[_C_CLIP] + owner), 1, dtype=np.uint8)[0])
    geo = carray(_as_pointer(ctx[_C_CLIP_GEO]), 9, dtype=np.float64)
    hx_, hy_, hz_ = ctxf[_C_ORG] + t * dx, ctxf[_C_ORG + 1] + t * dy, ctxf[_C_ORG + 2] + t * dz
    if geo[8] != CELLS_OFF:
        if _outside_cell(ctx, ctxf, geo, owner, hx_, hy_, hz_, t):
            return True
        if geo[8] == CELLS_ONLY:
            return False
    if bits == 0:
        # an inner point: no angles, its pulse offset in the tangent frame of its direction: a hit
        # 1.5 rows off, or 1.5 columns (or where columns are narrower than a row, half a column
        # more than a row's height) is beyond the pulses next to its own. For discs, its direction
        # from the float32 centre Embree has just read (in cache; 1e-7 of its distance from the
        # scene's centre: a thousandth of a pulse of 0.01 deg at a tenth of that distance), not from
        # the float64 one (a read from memory, most of the rule's cost)
        if ctx[_C_VERTICES]:
            v = carray(_as_pointer(ctx[_C_VERTICES] + owner * 16), 3, dtype=np.float32)
            ax = np.float64(v[0]) - ctxf[_C_CLIP_PO]
            ay = np.float64(v[1]) - ctxf[_C_CLIP_PO + 1]
            az = np.float64(v[2]) - ctxf[_C_CLIP_PO + 2]
        else:
            cen = carray(_as_pointer(ctx[_C_CENTRES] + owner * 24), 3, dtype=np.float64)
            ax, ay, az = cen[0] - geo[0], cen[1] - geo[1], cen[2] - geo[2]
        bx, by, bz = hx_ - geo[0], hy_ - geo[1], hz_ - geo[2]
        rho2 = ax * ax + ay * ay
        ra2 = rho2 + az * az
        rb2 = bx * bx + by * by + bz * bz
        if rho2 * 1e12 <= ra2 or rb2 == 0.0:
            return False  # on the pole's axis (or at the primary): any column
        rho = math.sqrt(rho2)
        inv_ra = 1.0 / math.sqrt(ra2)
        inv_rb = 1.0 / math.sqrt(rb2)
        ex, ey, ez = bx * inv_rb - ax * inv_ra, by * inv_rb - ay * inv_ra, bz * inv_rb - az * inv_ra
        sin_theta = rho * inv_ra
        u_theta = ((ex * ax + ey * ay) * az / rho - ez * rho) * inv_ra
        if abs(u_theta) >= 1.5 * geo[4]:
            return True
        u_phi = (ey * ax - ex * ay) / rho
        return abs(u_phi) >= max(1.5 * geo[5] * sin_theta, 0.5 * geo[5] * sin_theta + geo[4])
    n_edges = ctx[_C_CLIP_NEDGES]
    edges = carray(_as_pointer(ctx[_C_CLIP_EDGES]), max(n_edges, 1), dtype=np.float64)
    cen = carray(_as_pointer(ctx[_C_CENTRES] + owner * 24), 3, dtype=np.float64)
    vc, hc = _primary_cell(geo, edges, n_edges, cen[0], cen[1], cen[2])
    vx, hx = _primary_cell(geo, edges, n_edges, hx_, hy_, hz_)
    nh = np.int64(geo[7])
    dv = vx - vc
    dh = (hx - hc) % nh
    if 2 * dh > nh:
        dh -= nh
    if dv == 0 and dh == 0:
        return False
    if -1 <= dv <= 1 and -1 <= dh <= 1:
        return (bits >> silhouette_bit((dv + 1) * 3 + dh + 1)) & 1 == 1
    if dv < -1 or dv > 1:
        return True  # a disc reaching two pulses would take the next one's silhouette pulse
    if (bits >> silhouette_bit((dv + 1) * 3 + (1 if dh > 0 else -1) + 1)) & 1 == 1:
        return True  # beyond the next pulse on a silhouette side: a silhouette pulse further on too
    # columns narrower than a row (towards the poles, a beam table's): as many as a row's height holds
    rho = math.sqrt((cen[0] - geo[0]) ** 2 + (cen[1] - geo[1]) ** 2)
    r = math.sqrt(rho * rho + (cen[2] - geo[2]) ** 2)
    if rho * geo[5] * 1e6 <= geo[4] * r:
        return False  # on the pole's axis: any column
    return abs(dh) > max(1.0, math.floor(geo[4] * r / (rho * geo[5])))


@lazy.cfunc(types.void(types.voidptr), cache=True, nopython=True)  # compiled on the first cast (slr_ray.lazy)
def FILTER(fargs):
    """RTCFilterFunctionN, for each valid ray of the packet: skip discs holding the ray
    origin; in tie mode, record the candidate whose centre is nearest the ray (then
    lowest id) and reject all; in one-pass mode, keep every candidate within the window
    of the nearest hit so far and accept it with the ray's end moved past that window
    (package docstring)."""
    a = carray(fargs, 6, dtype=np.int64)
    n = a[5] & 0xFFFFFFFF  # unsigned int N
    valid = carray(_as_pointer(a[0]), n, dtype=np.int32)
    ctx = carray(_as_pointer(a[2]), _CTX_WORDS, dtype=np.int64)
    ctxf = carray(_as_pointer(a[2]), _CTX_WORDS, dtype=np.float64)
    ray = carray(_as_pointer(a[3]), 12 * n, dtype=np.float32)
    rayu = carray(_as_pointer(a[3]), 12 * n, dtype=np.uint32)
    hit = carray(_as_pointer(a[4]), 8 * n, dtype=np.uint32)
    for i in range(n):
        if valid[i] == 0:
            continue
        b = _C_LANES + np.int64(rayu[_ID * n + i]) * _LANE_WORDS
        prim = np.int64(hit[(_PRIM - 12) * n + i])
        div = ctx[_C_DIV]
        owner = prim if div == 1 else prim // div  # discs: a disc a primitive, no division
        # float32 radii with a stride: for discs, the radius column of Embree's own vertex buffer
        rad_at = ctx[_C_RADII] + owner * ctx[_C_RSTRIDE]
        mode = ctx[b + _L_MODE]
        if mode & MODE_SKIP:
            reach = np.float64(carray(_as_pointer(rad_at), 1, dtype=np.float32)[0]) * ctxf[_C_REACH]
            far = False
            if ctx[_C_VERTICES]:
                # the float32 centre Embree has just read (in cache) settles all but a thin band
                # around the reach; the float64 one (a read from memory) decides within it
                v = carray(_as_pointer(ctx[_C_VERTICES] + owner * 16), 3, dtype=np.float32)
                vx = np.float64(v[0]) - ctxf[_C_LOCAL]
                vy = np.float64(v[1]) - ctxf[_C_LOCAL + 1]
                vz = np.float64(v[2]) - ctxf[_C_LOCAL + 2]
                margin = 1e-6 * (abs(np.float64(v[0])) + abs(np.float64(v[1])) + abs(np.float64(v[2]))
                                 + abs(ctxf[_C_LOCAL]) + abs(ctxf[_C_LOCAL + 1]) + abs(ctxf[_C_LOCAL + 2])) + 1e-9
                far = math.sqrt(vx * vx + vy * vy + vz * vz) > reach + margin
            if not far:
                cen = carray(_as_pointer(ctx[_C_CENTRES] + owner * 24), 3, dtype=np.float64)
                cx = cen[0] - ctxf[_C_ORG]
                cy = cen[1] - ctxf[_C_ORG + 1]
                cz = cen[2] - ctxf[_C_ORG + 2]
                if cx * cx + cy * cy + cz * cz <= reach * reach:
                    valid[i] = 0
                    continue
        if mode & _MODE_CLIP and _clipped(ctx, ctxf, owner, np.float64(ray[_TFAR * n + i]), ctxf[b + _L_DIR],
                                          ctxf[b + _L_DIR + 1], ctxf[b + _L_DIR + 2]):
            valid[i] = 0
            continue
        if not mode & (_MODE_TIES | _MODE_ONE_PASS):
            continue
        if mode & _MODE_TIES:
            dx, dy, dz = ctxf[b + _L_DIR], ctxf[b + _L_DIR + 1], ctxf[b + _L_DIR + 2]
            cen = carray(_as_pointer(ctx[_C_CENTRES] + owner * 24), 3, dtype=np.float64)
            s = _tie_score(cen[0] - ctxf[_C_ORG], cen[1] - ctxf[_C_ORG + 1], cen[2] - ctxf[_C_ORG + 2],
                           dx, dy, dz, ctxf[_C_ASPECT])
            if s < ctxf[b + _L_SCORE] or (s == ctxf[b + _L_SCORE] and owner < ctx[b + _L_BEST]):
                ctxf[b + _L_SCORE] = s
                ctx[b + _L_BEST] = owner
                ctx[b + _L_BEST_PRIM] = prim
                ctxf[b + _L_BEST_T] = ray[_TFAR * n + i]
            valid[i] = 0
            continue
        # one pass: Embree has put the candidate's distance in tfar; accepting the hit keeps the
        # tfar this filter leaves (Embree's rtcSetGeometryOccludedFilterFunction page: filters
        # set tfar for a committed hit), so nothing within the window is culled
        t = np.float64(ray[_TFAR * n + i])
        if ctx[b + _L_FIRST_OWNER] < 0 or t <= ctxf[b + _L_FIRST_T]:
            # a new nearest hit (the later of equals, as a plain query's last accepted)
            nb = ctx[_C_NBYTES]
            nx = ny = nz = 0.0
            if nb == 4:
                nrm = carray(_as_pointer(ctx[_C_NORMALS] + owner * 12), 3, dtype=np.float32)
                nx, ny, nz = np.float64(nrm[0]), np.float64(nrm[1]), np.float64(nrm[2])
            elif nb == 8:
                nrm8 = carray(_as_pointer(ctx[_C_NORMALS] + owner * 24), 3, dtype=np.float64)
                nx, ny, nz = nrm8[0], nrm8[1], nrm8[2]
            dx, dy, dz = ctxf[b + _L_DIR], ctxf[b + _L_DIR + 1], ctxf[b + _L_DIR + 2]
            rad = np.float64(carray(_as_pointer(rad_at), 1, dtype=np.float32)[0])
            w = _tie_window(ctxf[_C_TIES], rad, nb > 0, nx, ny, nz, dx, dy, dz)
            first = ctx[b + _L_FIRST_OWNER] < 0
            if not first and np.float64(np.float32(t + w)) > ctxf[b + _L_CULL]:
                # its window reaches past where traversal has already culled: the caller
                # queries the window again
                ctx[b + _L_INCOMPLETE] = 1
            ctxf[b + _L_FIRST_T] = t
            ctx[b + _L_FIRST_OWNER] = owner
            ctx[b + _L_FIRST_PRIM] = prim
            cull = np.float64(np.float32(t + _CULL_PAD * w))
            if not ctx[b + _L_INCOMPLETE] and (first or cull < ctxf[b + _L_CULL]):
                ctxf[b + _L_CULL] = cull
        if ctx[b + _L_INCOMPLETE]:
            continue  # a plain query from here on: only the nearest hit matters
        m = ctx[b + _L_NCAND]
        if m == _MAX_CANDIDATES:  # full: drop those beyond the cut, else give up on one pass
            kept = 0
            for j in range(m):
                k = b + _L_CAND + 4 * j
                if ctxf[k] <= ctxf[b + _L_CULL]:
                    for q in range(4):
                        ctx[b + _L_CAND + 4 * kept + q] = ctx[k + q]
                    kept += 1
            m = kept
            ctx[b + _L_NCAND] = m
            if m == _MAX_CANDIDATES:
                ctx[b + _L_INCOMPLETE] = 1
                continue
        k = b + _L_CAND + 4 * m
        ctxf[k] = t
        ctx[k + 1] = owner
        ctx[k + 2] = prim  # its score only if it is in the final window (cast_packets)
        ctx[b + _L_NCAND] = m + 1
        if not ctx[_C_VERTICES]:
            # the caller reads the float64 centres of the candidates in the window: start the load
            _prefetch(ctx[_C_CENTRES] + owner * 24)
            _prefetch(ctx[_C_CENTRES] + owner * 24 + 23)
        ray[_TFAR * n + i] = np.float32(ctxf[b + _L_CULL])


@njit(cache=True, nogil=True)
def _aligned(n):
    """``n`` float32 zeros starting on a 64-byte boundary (rtcIntersect16 wants 64)."""
    buf = np.zeros(n + 16, np.float32)
    off = ((64 - (buf.ctypes.data % 64)) % 64) // 4
    return buf[off:off + n]


@njit(cache=True, nogil=True, inline="always")
def _packet(W):
    """A packet of ``W`` rays' buffers: the RTCRayHitW (floats ``rh``, the same bytes as words ``ru``),
    the valid mask and each lane's ray; the lanes' fields Embree only reads (time, mask, lane id,
    flags) set once for every packet."""
    rh = _aligned(max(_RAYHIT_ROWS * W, 24))
    ru = rh.view(np.uint32)
    valid = _aligned(W).view(np.int32)
    for k in range(W):
        rh[_TIME * W + k] = 0.0
        ru[_MASK * W + k] = INVALID_ID
        ru[_ID * W + k] = k  # the lane: the filter's state of this ray
        ru[_FLAGS * W + k] = 0
    return rh, ru, valid, np.empty(W, np.int64)


@njit(cache=True, nogil=True, inline="always")
def _open_lane(rh, ru, W, k, tnear, tfar):
    """Lane ``k`` of a packet ready for a new ray: its span and no hit yet (its direction and origin
    are the caller's)."""
    rh[_TNEAR * W + k] = tnear
    rh[_TFAR * W + k] = tfar
    ru[_PRIM * W + k] = INVALID_ID
    ru[_GEOM * W + k] = INVALID_ID
    ru[_INST * W + k] = INVALID_ID
    ru[_INST_PRIM * W + k] = INVALID_ID


@njit(cache=True, nogil=True, inline="always")
def _misses_box(ox, oy, oz, dx, dy, dz, box, tnear, tfar):
    """Whether the ray surely misses the axis-aligned box ``(lo, hi)`` on [tnear, tfar]
    (float64 slab test; the box is padded, so a True is never a ray Embree would hit)."""
    t0 = tnear
    t1 = tfar
    for a in range(3):
        o = (ox, oy, oz)[a]
        d = (dx, dy, dz)[a]
        lo = box[a]
        hi = box[a + 3]
        if d == 0.0:
            if o < lo or o > hi:
                return True
        else:
            inv = 1.0 / d
            ta = (lo - o) * inv
            tb = (hi - o) * inv
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
            if t0 > t1:
                return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _score_bounds(vertices, owner, local, dx, dy, dz, aspect):
    """Bounds ``(lo, hi)`` on the float64 tie score (:func:`_tie_score`) of disc ``owner``,
    from its float32 centre in Embree's vertex buffer (in cache: Embree has just read it)
    instead of the float64 one: the rounding of the vertex to float32 moves the centre
    by at most 2^-23 of its coordinates; the bounds take that, float64 rounding and a
    wide margin. ``(0, inf)`` where the pulse-unit score is undecided (a centre near the
    plane through the origin normal to the ray)."""
    v = carray(_as_pointer(vertices + owner * 16), 3, dtype=np.float32)
    v0, v1, v2 = np.float64(v[0]), np.float64(v[1]), np.float64(v[2])
    cx, cy, cz = v0 - local[0], v1 - local[1], v2 - local[2]
    m = abs(cx) + abs(cy) + abs(cz)
    err = (2.0 ** -22 * (abs(v0) + abs(v1) + abs(v2))
           + 1e-15 * (m + abs(local[0]) + abs(local[1]) + abs(local[2])) + 1e-30)
    t = cx * dx + cy * dy + cz * dz
    ex, ey, ez = cx - t * dx, cy - t * dy, cz - t * dz
    p2 = ex * ex + ey * ey + ez * ez
    if aspect > 0.0 and t + err >= 0.0:
        if t - err <= 0.0:
            return 0.0, np.inf
        # sqrt(score) = N(e) / t with N a norm on the plane normal to the ray, N <= k |e|
        rho = max(math.sqrt(dx * dx + dy * dy), _MIN_RHO)
        k = aspect / rho
        lip = max(1.0, k)
        e_az = (ey * dx - ex * dy) / rho
        nq = math.sqrt(max(p2 - e_az * e_az, 0.0) + (e_az * k) * (e_az * k))
        a = max(nq - lip * err, 0.0) / (t + err)
        z = (nq + lip * err) / (t - err)
        slack = 1e-13 * (lip * (m + err) / (t - err)) ** 2
        return a * a - slack, z * z + slack
    p = math.sqrt(p2)
    a = max(p - err, 0.0)
    z = p + err
    slack = 1e-13 * (m + err) ** 2
    return a * a - slack, z * z + slack


@njit(cache=True, nogil=True, inline="always")
def _pick(ctx, ctxf, b, lo, hi, centres, org64, vertices, local, dx, dy, dz, aspect):
    """The tie rule over lane ``b``'s candidates within [lo, hi]: ``(owner, t, primitive)``
    of the one whose float64 score is least, then the lowest owner; ``owner`` -1 for
    fewer than two (the nearest hit is the answer). For discs, bounds from the float32
    vertices first: only candidates that could be the least read their float64 centres
    (a candidate whose lower bound exceeds another's upper bound cannot)."""
    n = ctx[b + _L_NCAND]
    inside = 0
    cut = np.inf  # the least upper bound of a score
    for j in range(n):
        c = b + _L_CAND + 4 * j
        if lo <= ctxf[c] <= hi:
            inside += 1
            if vertices:
                s_lo, s_hi = _score_bounds(vertices, ctx[c + 1], local, dx, dy, dz, aspect)
                ctxf[c + 3] = s_lo
                if s_hi < cut:
                    cut = s_hi
    best = best_prim = np.int64(-1)
    best_t = 0.0
    if inside < 2:
        return best, best_t, best_prim  # one candidate: the nearest hit itself (no centre to read)
    survivors = inside
    if vertices:
        survivors = 0
        for j in range(n):
            c = b + _L_CAND + 4 * j
            if lo <= ctxf[c] <= hi and not ctxf[c + 3] > cut:
                survivors += 1
    score = np.inf
    for j in range(n):
        c = b + _L_CAND + 4 * j
        tc = ctxf[c]
        if lo <= tc <= hi and not (vertices and ctxf[c + 3] > cut):
            oc = ctx[c + 1]
            if survivors == 1:
                return oc, tc, ctx[c + 2]
            s = _tie_score(centres[oc, 0] - org64[0], centres[oc, 1] - org64[1],
                           centres[oc, 2] - org64[2], dx, dy, dz, aspect)
            if s < score or (s == score and oc < best):
                score, best, best_t, best_prim = s, oc, tc, ctx[c + 2]
    return best, best_t, best_prim


@njit(cache=True, nogil=True)
def cast_packets(isect, width, scene, filt, org32, org64, dirs, tnear, tfar, mode_first, ties, one_pass, aspect,
              centres, radii, normals, div, reach, box, prim_out, owner_out, t_out, vertices, local, dmap, face,
              clip_bits, clip_geo, clip_edges):
    """Cast rays ``dirs`` from ``org32`` (scene frame) into ``*_out``, ``width`` at a time
    (``isect``: the address of rtcIntersect1 for 1, else of rtcIntersect<width>).

    Rays that miss ``box`` (the scene's padded bounds, scene frame), or whose
    direction falls in an unmarked cell of ``dmap`` (:func:`.cull.direction_map`
    from ``org32``; empty: no such test), are answered here without a call into
    Embree: a call costs about as much as a short traversal, and most rays of a
    scan from outside a cloud's bounds miss it; a packet holds the next
    ``width`` rays that do not.
    With ``ties`` and ``one_pass``, one query collects the tie candidates (the
    filter's one-pass mode); a second query over the window only for the rare ray
    whose candidates it could not all keep (a packet of those)."""
    W = width
    rh, ru, valid, lane_ray = _packet(W)
    lane_prim = np.empty(W, np.int64)
    lane_owner = np.empty(W, np.int64)
    lane_t = np.empty(W, np.float64)
    ctx = np.zeros(_CTX_WORDS, np.int64)
    ctxf = ctx.view(np.float64)
    for j in range(4):
        ctx[j] = -1  # instance ids: RTC_INVALID_GEOMETRY_ID
    ctx[_C_CENTRES] = centres.ctypes.data
    ctx[_C_RADII] = radii.ctypes.data
    ctx[_C_RSTRIDE] = radii.strides[0]
    ctx[_C_DIV] = div
    ctxf[_C_ORG] = org64[0]
    ctxf[_C_ORG + 1] = org64[1]
    ctxf[_C_ORG + 2] = org64[2]
    ctxf[_C_REACH] = reach
    ctxf[_C_ASPECT] = aspect
    ctx[_C_VERTICES] = vertices
    if vertices:
        ctxf[_C_LOCAL], ctxf[_C_LOCAL + 1], ctxf[_C_LOCAL + 2] = local[0], local[1], local[2]
    ctxf[_C_TIES] = ties
    if clip_bits.shape[0] > 0:
        ctx[_C_CLIP] = clip_bits.ctypes.data
        ctx[_C_CLIP_GEO] = clip_geo.ctypes.data
        ctx[_C_CLIP_EDGES] = clip_edges.ctypes.data
        ctx[_C_CLIP_NEDGES] = clip_edges.shape[0]
        for k in range(3):  # the scene frame: that of the ray origin ``local``
            ctxf[_C_CLIP_PO + k] = clip_geo[k] - org64[k] + local[k]
        d2 = (org64[0] - clip_geo[0]) ** 2 + (org64[1] - clip_geo[1]) ** 2 + (org64[2] - clip_geo[2]) ** 2
        ctxf[_C_CLIP_T2] = d2 / (SILHOUETTE_PARALLAX * SILHOUETTE_PARALLAX)
        mode_first |= _MODE_CLIP
    has_normals = normals.shape[0] > 0
    if has_normals:
        ctx[_C_NORMALS] = normals.ctypes.data
        ctx[_C_NBYTES] = normals.itemsize
    args = np.zeros(8, np.int64)  # RTCIntersectArguments (32 bytes used)
    args[0] = RAY_QUERY_FLAG_INVOKE_ARGUMENT_FILTER | (FEATURE_FLAGS_ALL << 32)
    args[1] = ctx.ctypes.data
    args[2] = filt
    rh_ptr = np.int64(rh.ctypes.data)
    args_ptr = np.int64(args.ctypes.data)
    valid_ptr = np.int64(valid.ctypes.data)
    one = ties > 0.0 and one_pass
    mode = mode_first | (_MODE_ONE_PASS if one else 0)
    first_args = args_ptr if mode else np.int64(0)
    ox, oy, oz = np.float64(org32[0]), np.float64(org32[1]), np.float64(org32[2])
    t_lo, t_hi = np.float64(tnear), np.float64(tfar)
    for k in range(W):  # the origin: Embree only reads it, the same for every packet
        rh[_ORG * W + k], rh[(_ORG + 1) * W + k], rh[(_ORG + 2) * W + k] = org32[0], org32[1], org32[2]
    n_rays = dirs.shape[0]
    i = 0
    while i < n_rays:
        # a packet: the next W rays that meet the box
        k = 0
        while k < W and i < n_rays:
            dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
            if not could_hit(dmap, face, dx, dy, dz) or _misses_box(ox, oy, oz, dx, dy, dz, box, t_lo, t_hi):
                prim_out[i] = -1
                owner_out[i] = -1
                t_out[i] = np.inf
                i += 1
                continue
            _open_lane(rh, ru, W, k, tnear, tfar)  # tnear: a second query moves it
            rh[_DIR * W + k], rh[(_DIR + 1) * W + k], rh[(_DIR + 2) * W + k] = dx, dy, dz
            b = _C_LANES + k * _LANE_WORDS
            ctx[b + _L_MODE] = mode
            ctxf[b + _L_DIR], ctxf[b + _L_DIR + 1], ctxf[b + _L_DIR + 2] = dx, dy, dz
            if one:
                ctx[b + _L_FIRST_OWNER] = -1
                ctx[b + _L_NCAND] = 0
                ctx[b + _L_INCOMPLETE] = 0
                ctxf[b + _L_CULL] = np.float64(tfar)
            valid[k] = -1
            lane_ray[k] = i
            k += 1
            i += 1
        if k == 0:
            break
        for q in range(k, W):
            valid[q] = 0
        if W > 1:
            _call4(isect, valid_ptr, scene, rh_ptr, first_args)
        else:
            _call3(isect, scene, rh_ptr, first_args)
        again = 0
        for q in range(k):
            r = lane_ray[q]
            b = _C_LANES + q * _LANE_WORDS
            valid[q] = 0
            if ru[_GEOM * W + q] == INVALID_ID:
                prim_out[r] = -1
                owner_out[r] = -1
                t_out[r] = np.inf
                continue
            if one:
                # the nearest hit is the filter's, not the ray's (which holds the last accepted)
                t0 = np.float32(ctxf[b + _L_FIRST_T])
                prim = ctx[b + _L_FIRST_PRIM]
                owner = ctx[b + _L_FIRST_OWNER]
            else:
                t0 = rh[_TFAR * W + q]
                prim = np.int64(ru[_PRIM * W + q])
                owner = prim if div == 1 else prim // div
            t_hit = np.float64(t0)
            if ties > 0.0:
                dx, dy, dz = ctxf[b + _L_DIR], ctxf[b + _L_DIR + 1], ctxf[b + _L_DIR + 2]
                nx = ny = nz = 0.0
                if has_normals:
                    nx, ny, nz = np.float64(normals[owner, 0]), np.float64(normals[owner, 1]), np.float64(normals[owner, 2])
                window = _tie_window(ties, np.float64(radii[owner]), has_normals, nx, ny, nz, dx, dy, dz)
                lo = np.float32(max(np.float64(tnear), t0 - window))
                hi = np.float32(t0 + window)
                if one and not ctx[b + _L_INCOMPLETE]:
                    # the candidates within [lo, hi]: those a second query over the window would meet
                    best, best_t, best_prim = _pick(ctx, ctxf, b, lo, hi, centres, org64, vertices, local,
                                                    dx, dy, dz, aspect)
                    if best >= 0 and best != owner:
                        owner = best
                        prim = best_prim
                        t_hit = best_t
                else:
                    # the window again, in tie mode: a packet of the rays that need it
                    rh[_TNEAR * W + q] = lo
                    rh[_TFAR * W + q] = hi
                    ru[_PRIM * W + q] = INVALID_ID
                    ru[_GEOM * W + q] = INVALID_ID
                    ctx[b + _L_MODE] = mode_first | _MODE_TIES
                    ctx[b + _L_BEST] = -1
                    ctxf[b + _L_SCORE] = np.inf
                    lane_prim[q], lane_owner[q], lane_t[q] = prim, owner, t_hit
                    valid[q] = -1
                    again += 1
                    continue
            prim_out[r] = prim
            owner_out[r] = owner
            t_out[r] = t_hit
        if again:
            if W > 1:
                _call4(isect, valid_ptr, scene, rh_ptr, args_ptr)
            else:
                _call3(isect, scene, rh_ptr, args_ptr)
            for q in range(k):
                if valid[q] == 0:
                    continue
                r = lane_ray[q]
                b = _C_LANES + q * _LANE_WORDS
                prim, owner, t_hit = lane_prim[q], lane_owner[q], lane_t[q]
                best = ctx[b + _L_BEST]
                if best >= 0 and best != owner:
                    owner = best
                    prim = ctx[b + _L_BEST_PRIM]
                    t_hit = ctxf[b + _L_BEST_T]
                prim_out[r] = prim
                owner_out[r] = owner
                t_out[r] = t_hit


@njit(cache=True, nogil=True)
def cast_each(isect, width, scene, origins, dirs, tnear, tfar, prim_out, t_out):
    """The first hit of every ray from its own origin (``origins`` float32-exact, scene frame; one a
    ray), ``width`` rays a call, no filter: the rays of a fitted sensor, each laser firing from its own
    point (:meth:`~slr_ray.raycast.RayScene.intersect_each`)."""
    W = width
    rh, ru, valid, lane_ray = _packet(W)
    rh_ptr = np.int64(rh.ctypes.data)
    valid_ptr = np.int64(valid.ctypes.data)
    n_rays = dirs.shape[0]
    i = 0
    while i < n_rays:
        k = 0
        while k < W and i < n_rays:
            for a in range(3):
                rh[(_ORG + a) * W + k] = origins[i, a]
                rh[(_DIR + a) * W + k] = dirs[i, a]
            _open_lane(rh, ru, W, k, tnear, tfar)
            valid[k] = -1
            lane_ray[k] = i
            k += 1
            i += 1
        for q in range(k, W):
            valid[q] = 0
        if W > 1:
            _call4(isect, valid_ptr, scene, rh_ptr, np.int64(0))
        else:
            _call3(isect, scene, rh_ptr, np.int64(0))
        for q in range(k):
            r = lane_ray[q]
            if ru[_GEOM * W + q] == INVALID_ID:
                prim_out[r] = -1
                t_out[r] = np.inf
            else:
                prim_out[r] = np.int64(ru[_PRIM * W + q])
                t_out[r] = np.float64(rh[_TFAR * W + q])
