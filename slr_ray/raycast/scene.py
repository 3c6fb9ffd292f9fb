"""Embree scenes of triangles or discs and the compiled cast loop (:class:`RayScene`).

The package docstring (:mod:`slr_ray.raycast`) describes the float32
boundary, the tie rule and the discs that hold the scanner.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from llvmlite import ir
from numba import carray, cfunc, njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..arrays import as_origin, bounds
from ..errors import InputValueError
from ..threads import default_threads
from .library import (BUFFER_INDEX, BUFFER_NORMAL, BUFFER_VERTEX, FEATURE_FLAGS_ALL, FORMAT_FLOAT3, FORMAT_FLOAT4,
                      FORMAT_UINT3, GEOMETRY_DISC_POINT, GEOMETRY_ORIENTED_DISC_POINT, GEOMETRY_TRIANGLE, INVALID_ID,
                      RAY_QUERY_FLAG_INVOKE_ARGUMENT_FILTER, SCENE_FLAG_COMPACT,
                      SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS, embree_library)

__all__ = ["RayScene", "RayHits", "padded_rows", "disc_vertices"]

#: RTCRayHit: RTCRay (48 bytes) + RTCHit (48 bytes with instID[1], instPrimID[1]),
#: each 16-byte aligned; in float32 slots: ray 0-11, hit 12-23
_RAYHIT_FLOATS = 24
_TFAR, _MASK, _PRIM, _GEOM, _INST = 8, 9, 17, 18, 19

#: rays of one task handed to a thread: small enough that a stopped scan stops soon
_TASK_RAYS = 32768

# --- compiled part --------------------------------------------------------------------------

@intrinsic
def _as_pointer(typingctx, address):
    """An integer address as a ``void*`` (for numba.carray)."""
    sig = types.voidptr(address)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return sig, codegen


@intrinsic
def _call3(typingctx, fptr, a, b, c):
    """Call the C function at address ``fptr`` with three pointer-sized arguments."""
    if not all(isinstance(x, types.Integer) for x in (fptr, a, b, c)):
        return None
    sig = types.void(fptr, a, b, c)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        fnty = ir.FunctionType(ir.VoidType(), [i64, i64, i64])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(f, [builder.zext(x, i64) if x.type.width < 64 else x for x in args[1:]])
        return context.get_dummy_value()

    return sig, codegen


# query context: RTCRayQueryContext (slots 0-3, 32 bytes reserved) then ours
_C_MODE, _C_CENTRES, _C_RADII, _C_DIV, _C_BEST = 4, 5, 6, 7, 8
_C_SCORE, _C_ORG, _C_DIR, _C_REACH, _C_BEST_T, _C_RSTRIDE, _C_ASPECT = 9, 10, 13, 16, 17, 18, 19
# one-pass ties: the normals (address, 4 or 8 bytes a value, 0: none), the tie factor, the
# nearest hit so far (t, owner, primitive), the far end of its window, the candidates
_C_NORMALS, _C_NBYTES, _C_TIES, _C_FIRST_T, _C_FIRST_OWNER, _C_FIRST_PRIM = 20, 21, 22, 23, 24, 25
_C_CULL, _C_NCAND, _C_INCOMPLETE, _C_BEST_PRIM = 26, 27, 28, 29
# discs: the float32 vertex buffer (0: none) and the ray origin in its frame (float64)
_C_VERTICES, _C_LOCAL, _C_CAND = 30, 31, 34
#: candidates a ray can hold in one pass (t, owner, primitive and a spare word each); beyond, a second query
_MAX_CANDIDATES = 64
_CTX_WORDS = _C_CAND + 4 * _MAX_CANDIDATES
#: sin(zenith) below which a ray counts as polar in the pulse-unit tie score
_MIN_RHO = 1e-9
#: the tie window stops growing beyond 20 radii (incidence above ~87 deg)
_MIN_COS = 0.05
_MODE_SKIP, _MODE_TIES, _MODE_ONE_PASS = 1, 2, 4
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


@cfunc(types.void(types.voidptr), cache=True, nopython=True)
def _filter(fargs):
    """RTCFilterFunctionN: skip discs holding the ray origin; in tie mode, record
    the candidate whose centre is nearest the ray (then lowest id) and reject all;
    in one-pass mode, keep every candidate within the window of the nearest hit so far
    and accept it with the ray's end moved to that window's far end (module docstring)."""
    a = carray(fargs, 6, dtype=np.int64)
    valid = carray(_as_pointer(a[0]), 1, dtype=np.int32)
    ctx = carray(_as_pointer(a[2]), _CTX_WORDS, dtype=np.int64)
    ctxf = carray(_as_pointer(a[2]), _CTX_WORDS, dtype=np.float64)
    ray = carray(_as_pointer(a[3]), 12, dtype=np.float32)
    hit = carray(_as_pointer(a[4]), 8, dtype=np.uint32)
    prim = np.int64(hit[5])
    owner = prim // ctx[_C_DIV]
    # float32 radii with a stride: for discs, the radius column of Embree's own vertex buffer
    rad = carray(_as_pointer(ctx[_C_RADII] + owner * ctx[_C_RSTRIDE]), 1, dtype=np.float32)
    mode = ctx[_C_MODE]
    if mode & _MODE_SKIP:
        reach = np.float64(rad[0]) * ctxf[_C_REACH]
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
                valid[0] = 0
                return
    if mode & (_MODE_TIES | _MODE_ONE_PASS):
        dx, dy, dz = ctxf[_C_DIR], ctxf[_C_DIR + 1], ctxf[_C_DIR + 2]
        if mode & _MODE_TIES:
            cen = carray(_as_pointer(ctx[_C_CENTRES] + owner * 24), 3, dtype=np.float64)
            s = _tie_score(cen[0] - ctxf[_C_ORG], cen[1] - ctxf[_C_ORG + 1], cen[2] - ctxf[_C_ORG + 2],
                           dx, dy, dz, ctxf[_C_ASPECT])
            if s < ctxf[_C_SCORE] or (s == ctxf[_C_SCORE] and owner < ctx[_C_BEST]):
                ctxf[_C_SCORE] = s
                ctx[_C_BEST] = owner
                ctx[_C_BEST_PRIM] = prim
                ctxf[_C_BEST_T] = ray[_TFAR]
            valid[0] = 0
            return
        # one pass: Embree has put the candidate's distance in tfar; accepting the hit keeps the
        # tfar this filter leaves (Embree's rtcSetGeometryOccludedFilterFunction page: filters
        # set tfar for a committed hit), so nothing within the window is culled
        t = np.float64(ray[_TFAR])
        if ctx[_C_FIRST_OWNER] < 0 or t <= ctxf[_C_FIRST_T]:
            # a new nearest hit (the later of equals, as a plain query's last accepted)
            nb = ctx[_C_NBYTES]
            nx = ny = nz = 0.0
            if nb == 4:
                nrm = carray(_as_pointer(ctx[_C_NORMALS] + owner * 12), 3, dtype=np.float32)
                nx, ny, nz = np.float64(nrm[0]), np.float64(nrm[1]), np.float64(nrm[2])
            elif nb == 8:
                nrm8 = carray(_as_pointer(ctx[_C_NORMALS] + owner * 24), 3, dtype=np.float64)
                nx, ny, nz = nrm8[0], nrm8[1], nrm8[2]
            w = _tie_window(ctxf[_C_TIES], np.float64(rad[0]), nb > 0, nx, ny, nz, dx, dy, dz)
            first = ctx[_C_FIRST_OWNER] < 0
            if not first and np.float64(np.float32(t + w)) > ctxf[_C_CULL]:
                # its window reaches past where traversal has already culled: the caller
                # queries the window again
                ctx[_C_INCOMPLETE] = 1
            ctxf[_C_FIRST_T] = t
            ctx[_C_FIRST_OWNER] = owner
            ctx[_C_FIRST_PRIM] = prim
            cull = np.float64(np.float32(t + _CULL_PAD * w))
            if not ctx[_C_INCOMPLETE] and (first or cull < ctxf[_C_CULL]):
                ctxf[_C_CULL] = cull
        if ctx[_C_INCOMPLETE]:
            return  # a plain query from here on: only the nearest hit matters
        n = ctx[_C_NCAND]
        if n == _MAX_CANDIDATES:  # full: drop those beyond the window, else give up on one pass
            m = 0
            for j in range(n):
                k = _C_CAND + 4 * j
                if ctxf[k] <= ctxf[_C_CULL]:
                    for q in range(4):
                        ctx[_C_CAND + 4 * m + q] = ctx[k + q]
                    m += 1
            n = m
            ctx[_C_NCAND] = n
            if n == _MAX_CANDIDATES:
                ctx[_C_INCOMPLETE] = 1
                return
        k = _C_CAND + 4 * n
        ctxf[k] = t
        ctx[k + 1] = owner
        ctx[k + 2] = prim  # its score only if it is in the final window (_cast_rays)
        ctx[_C_NCAND] = n + 1
        ray[_TFAR] = np.float32(ctxf[_C_CULL])


@njit(cache=True, nogil=True)
def _aligned(n_floats):
    buf = np.zeros(n_floats + 4, np.float32)
    off = ((16 - (buf.ctypes.data % 16)) % 16) // 4
    return buf[off:off + n_floats]


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


@njit(cache=True, nogil=True)
def _cast_rays(isect, scene, filt, org32, org64, dirs, tnear, tfar, mode_first, ties, one_pass, aspect,
               centres, radii, normals, div, reach, box, prim_out, owner_out, t_out, vertices, local):
    """Cast rays ``dirs`` from ``org32`` (scene frame) into ``*_out``.

    Rays that miss ``box`` (the scene's padded bounds, scene frame) are answered
    here without a call into Embree: a call costs about as much as a short
    traversal, and most rays of a scan from outside a cloud's bounds miss it.
    With ``ties`` and ``one_pass``, one query collects the tie candidates (the
    filter's one-pass mode); a second query over the window only for the rare ray
    whose candidates it could not all keep."""
    rh = _aligned(_RAYHIT_FLOATS)
    ru = rh.view(np.uint32)
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
    one = ties > 0.0 and one_pass
    mode = mode_first | (_MODE_ONE_PASS if one else 0)
    first_args = args_ptr if mode else np.int64(0)
    ox, oy, oz = np.float64(org32[0]), np.float64(org32[1]), np.float64(org32[2])
    t_lo, t_hi = np.float64(tnear), np.float64(tfar)
    for i in range(dirs.shape[0]):
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        if _misses_box(ox, oy, oz, dx, dy, dz, box, t_lo, t_hi):
            prim_out[i] = -1
            owner_out[i] = -1
            t_out[i] = np.inf
            continue
        rh[0], rh[1], rh[2], rh[3] = org32[0], org32[1], org32[2], tnear
        rh[4], rh[5], rh[6], rh[7] = dx, dy, dz, 0.0
        rh[_TFAR] = tfar
        ru[_MASK] = INVALID_ID
        ru[10] = 0
        ru[11] = 0
        ru[_PRIM] = INVALID_ID
        ru[_GEOM] = INVALID_ID
        ru[_INST] = INVALID_ID
        ru[_INST + 1] = INVALID_ID
        ctx[_C_MODE] = mode
        ctxf[_C_DIR], ctxf[_C_DIR + 1], ctxf[_C_DIR + 2] = dx, dy, dz
        if one:
            ctx[_C_FIRST_OWNER] = -1
            ctx[_C_NCAND] = 0
            ctx[_C_INCOMPLETE] = 0
            ctxf[_C_CULL] = np.float64(tfar)
        _call3(isect, scene, rh_ptr, first_args)
        if ru[_GEOM] == INVALID_ID:
            prim_out[i] = -1
            owner_out[i] = -1
            t_out[i] = np.inf
            continue
        if one:
            # the nearest hit is the filter's, not the ray's (which holds the last accepted)
            t0 = np.float32(ctxf[_C_FIRST_T])
            prim = ctx[_C_FIRST_PRIM]
            owner = ctx[_C_FIRST_OWNER]
        else:
            t0 = rh[_TFAR]
            prim = np.int64(ru[_PRIM])
            owner = prim // div
        t_hit = t0
        if ties > 0.0:
            nx = ny = nz = 0.0
            if has_normals:
                nx, ny, nz = np.float64(normals[owner, 0]), np.float64(normals[owner, 1]), np.float64(normals[owner, 2])
            window = _tie_window(ties, np.float64(radii[owner]), has_normals, nx, ny, nz, dx, dy, dz)
            lo = np.float32(max(np.float64(tnear), t0 - window))
            hi = np.float32(t0 + window)
            best = best_prim = np.int64(-1)
            best_t = 0.0
            if one and not ctx[_C_INCOMPLETE]:
                # the candidates within [lo, hi]: those a second query over the window would meet
                score = np.inf
                inside = 0
                for j in range(ctx[_C_NCAND]):
                    if lo <= ctxf[_C_CAND + 4 * j] <= hi:
                        inside += 1
                # one candidate: the nearest hit itself (no float64 centre to read)
                for j in range(ctx[_C_NCAND] if inside > 1 else 0):
                    k = _C_CAND + 4 * j
                    tc = ctxf[k]
                    if lo <= tc <= hi:
                        oc = ctx[k + 1]
                        s = _tie_score(centres[oc, 0] - org64[0], centres[oc, 1] - org64[1],
                                       centres[oc, 2] - org64[2], dx, dy, dz, aspect)
                        if s < score or (s == score and oc < best):
                            score, best, best_t, best_prim = s, oc, tc, ctx[k + 2]
            else:
                rh[3] = lo
                rh[_TFAR] = hi
                ru[_PRIM] = INVALID_ID
                ru[_GEOM] = INVALID_ID
                ctx[_C_MODE] = mode_first | _MODE_TIES
                ctx[_C_BEST] = -1
                ctxf[_C_SCORE] = np.inf
                _call3(isect, scene, rh_ptr, args_ptr)
                best, best_t, best_prim = ctx[_C_BEST], ctxf[_C_BEST_T], ctx[_C_BEST_PRIM]
            if best >= 0 and best != owner:
                owner = best
                prim = best_prim
                t_hit = best_t
        prim_out[i] = prim
        owner_out[i] = owner
        t_out[i] = t_hit


@dataclass(frozen=True)
class RayHits:
    """What :meth:`RayScene.intersect` returns, one entry per ray.

    Attributes
    ----------
    primitives : (m,) int64
        Primitive hit (triangle or disc index), -1 on a miss; with ``ties``,
        the primitive of the answer (``owners == primitives // prims_per_owner``).
    owners : (m,) int64
        The primitive's owner: for discs the disc (point) index; for triangles
        the triangle index divided by ``prims_per_owner``. -1 on a miss.
    distances : (m,) float64
        Distance along the (unit) ray, ``inf`` on a miss.
    """

    primitives: np.ndarray
    owners: np.ndarray
    distances: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.owners >= 0


class RayScene:
    """One Embree scene of triangles or discs, built once and queried many times.

    Use the constructors :meth:`triangles` and :meth:`discs`. Geometry is kept
    in float32 around ``centre`` (float64); the arrays handed to Embree are
    held by the scene (Embree shares them, it does not copy).

    Attributes
    ----------
    kind : {'triangles', 'discs', 'oriented discs'}
    centre : (3,) float64
    n_primitives : int
    build_seconds : float
    nbytes : int
        Bytes of the buffers shared with Embree (the BVH comes on top).
    """

    def __init__(self, kind, geometry_type, buffers, n_primitives, centre, owner_centres, owner_radii,
                 prims_per_owner=1, reach=1.0, owner_normals=None, has_owners=True, compact=False):
        self.kind = kind
        self.centre = centre
        self.n_primitives = int(n_primitives)
        self._buffers = buffers
        # float64 data of the owners (the points) for the filter: contiguous, kept alive here
        self._owner_centres = np.ascontiguousarray(owner_centres, np.float64)
        # float32 (what Embree holds): for discs a view of the vertex buffer's radius column
        r = np.asarray(owner_radii)
        self._owner_radii = r if r.dtype == np.float32 and r.ndim == 1 else np.ascontiguousarray(r, np.float32)
        if owner_normals is None:
            self._owner_normals = np.zeros((0, 3))
        else:
            nrm = np.asarray(owner_normals)
            nrm = np.ascontiguousarray(nrm, np.float32 if nrm.dtype == np.float32 else np.float64)
            if _all_unit(nrm):  # already unit (the backend's are): shared, not copied
                self._owner_normals = nrm
            else:
                self._owner_normals = np.empty_like(nrm)
                _unit_rows(nrm, self._owner_normals)
        self.prims_per_owner = int(prims_per_owner)
        self.reach = float(reach)
        self.nbytes = int(sum(b[4].nbytes for b in buffers))
        self._has_owners = bool(has_owners)
        # discs: the float32 centres of Embree's vertex buffer (the filter's quick test before the float64 one)
        self._vertex_centres = int(buffers[0][4].ctypes.data) if geometry_type != GEOMETRY_TRIANGLE else 0
        # vertex rows (a triangle buffer's spare row excluded): the bounds rays are tested against first
        self._box = _padded_bounds(buffers[0][4], buffers[0][5] if self.n_primitives else 0,
                                   geometry_type != GEOMETRY_TRIANGLE)
        lib = self._lib = embree_library()
        t0 = time.perf_counter()
        self._scene = lib.new_scene(lib.device)
        lib.set_scene_flags(self._scene, SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS
                            | (SCENE_FLAG_COMPACT if compact else 0))
        if self.n_primitives:
            geom = lib.new_geometry(lib.device, geometry_type)
            for btype, slot, fmt, stride, arr, count in buffers:
                lib.set_shared_buffer(geom, btype, slot, fmt, arr.ctypes.data, 0, stride, count)
            lib.commit_geometry(geom)
            lib.attach_geometry(self._scene, geom)
            lib.release_geometry(geom)
        lib.commit_scene(self._scene)
        lib.check("building the scene")
        self.build_seconds = time.perf_counter() - t0

    # --- constructors -------------------------------------------------------------------
    @classmethod
    def triangles(cls, vertices, faces, centre=None, *, owners=None) -> "RayScene":
        """A triangle mesh.

        Parameters
        ----------
        vertices : (v, 3) float
        faces : (f, 3) int
        centre : (3,) float, optional
            Recentring point (default: the middle of the bounding box).
        owners : tuple, optional
            ``(centres (n, 3), radii (n,), prims_per_owner, reach, normals (n, 3))``
            when the triangles stand for discs (polygon fans of
            ``prims_per_owner`` triangles each): enables ``ties`` and
            ``skip_containing`` with the owners' float64 centres.
        """
        v = np.asarray(vertices, np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise InputValueError(f"vertices must be (v, 3) and faces (f, 3), got {v.shape} and {f.shape}")
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise InputValueError("faces index vertices that do not exist")
        centre = _centre_of(v) if centre is None else as_origin(centre, "centre")
        vbuf = np.zeros((len(v) + 1, 3), np.float32)  # one spare row: Embree reads 16 bytes per vertex
        vbuf[:len(v)] = v - centre
        fbuf = np.ascontiguousarray(f, np.uint32)
        scene = cls.__new__(cls)
        scene._vertices64, scene._faces = v, f
        has_owners = owners is not None
        if owners is None:
            owners = (np.zeros((1, 3)), np.ones(1), 1, 1.0, None)
        oc, orad, per, reach, onrm = owners
        cls.__init__(scene, "triangles", GEOMETRY_TRIANGLE,
                     [(BUFFER_VERTEX, 0, FORMAT_FLOAT3, 12, vbuf, len(v)),
                      (BUFFER_INDEX, 0, FORMAT_UINT3, 12, fbuf, len(f))],
                     len(f), centre, oc, orad, per, reach, onrm, has_owners)
        return scene

    @classmethod
    def discs(cls, centres, radii, normals=None, centre=None, compact: bool = True) -> "RayScene":
        """Discs of Embree's point primitives.

        Parameters
        ----------
        centres : (n, 3) float64
            Disc centres (kept by reference for the float64 tie rule).
        radii : (n,) float
            Radii in metres, > 0. The radius column of :func:`disc_vertices`
            becomes Embree's vertex buffer (filled in place, not copied).
        normals : (n, 3) float, optional
            Disc normals (any length > 0): ``ORIENTED_DISC_POINT``. Without,
            ``DISC_POINT``: every disc faces the ray that meets it. A float32
            C-contiguous array with spare bytes after it (:func:`padded_rows`)
            is shared with Embree, not copied (12 bytes a point less): do not
            change it while the scene lives.
        centre : (3,) float, optional
        compact : bool
            Embree's compact BVH (``RTC_SCENE_FLAG_COMPACT``; default): the
            same hits; on 58 M discs it built in 19.9 s instead of 22.1 s, cast
            3.1 M rays in 0.71 s instead of 0.65 s, same peak memory
            (``benchmarks/bench_compact_bvh.py``).
        """
        c = np.asarray(centres, np.float64)
        r = np.asarray(radii)
        if c.ndim != 2 or c.shape[1] != 3 or r.shape != (len(c),):
            raise InputValueError(f"centres must be (n, 3) and radii (n,), got {c.shape} and {r.shape}")
        shared = _vertex_column(r, len(c))  # the radius column of disc_vertices(n): filled in place
        r = r.astype(np.float32, copy=False)  # Embree's precision; a float32 input is not copied
        if len(r) and not (np.all(np.isfinite(r)) and r.min() > 0):
            bad = np.count_nonzero(~(np.isfinite(r) & (r > 0)))
            raise InputValueError(f"disc radii must be finite and > 0 in float32 ({bad} are not)")
        centre = _centre_of(c) if centre is None else as_origin(centre, "centre")
        vbuf = shared if shared is not None else np.empty((len(c), 4), np.float32)
        _fill_vertices(c, centre, r, vbuf)  # one parallel pass, no float64 temporaries
        buffers = [(BUFFER_VERTEX, 0, FORMAT_FLOAT4, 16, vbuf, len(c))]
        if normals is not None:
            nrm = np.asarray(normals)
            if nrm.shape != c.shape:
                raise InputValueError(f"normals has shape {nrm.shape}, centres {c.shape}")
            if nrm.dtype == np.float32 and nrm.flags.c_contiguous and _spare_bytes(nrm) >= 4:
                nbuf = nrm  # shared: Embree's 16-byte reads of the last row stay inside the allocation
            else:
                nbuf = padded_rows(len(c))
                nbuf[:] = nrm
            buffers.append((BUFFER_NORMAL, 0, FORMAT_FLOAT3, 12, nbuf, len(c)))
            gtype, kind = GEOMETRY_ORIENTED_DISC_POINT, "oriented discs"
        else:
            gtype, kind = GEOMETRY_DISC_POINT, "discs"
        scene = cls.__new__(cls)
        # the tie rule reads the float32 normals Embree has (12 B a point), not a float64 copy (24 B)
        owner_normals = buffers[1][4] if normals is not None else None
        del r  # the radii live on in the vertex buffer, which the tie rule reads
        cls.__init__(scene, kind, gtype, buffers, len(c), centre, c, vbuf[:, 3], 1, 1.0, owner_normals,
                     compact=compact)
        return scene

    @property
    def owner_radii(self) -> np.ndarray:
        """``(n,) float32`` radii of the discs (or of the discs a triangle fan stands
        for) as Embree and the tie rule use them; for discs, a read-only view of
        the vertex buffer."""
        v = self._owner_radii.view()
        v.flags.writeable = False
        return v

    @property
    def owner_normals(self) -> np.ndarray | None:
        """``(n, 3)`` unit normals of the discs as the tie rule uses them (for
        oriented discs, a read-only view of Embree's float32 normal buffer), or
        ``None`` for billboards and plain triangles."""
        if len(self._owner_normals) == 0:
            return None
        v = self._owner_normals.view()
        v.flags.writeable = False
        return v

    # --- queries ------------------------------------------------------------------------
    def intersect(self, origin, directions, *, tnear: float = 0.0, tfar: float = math.inf,
                  ties: float = 0.0, skip_containing: bool = False, exact: bool = False,
                  n_threads: int | None = None, pulse_aspect: float | None = None,
                  one_pass: bool = True) -> RayHits:
        """First hit of every ray from ``origin``.

        Parameters
        ----------
        origin : (3,) float
            Ray origin, in the coordinates of the geometry (float64).
        directions : (m, 3) float
            Unit directions.
        tnear, tfar : float
            The ray segment (metres).
        ties : float
            Tie window in units of the first hit's disc radius, divided by
            the cosine of the ray's incidence on that disc (at most 20 radii;
            module docstring); 0 keeps Embree's first hit. Needs discs or owners.
        skip_containing : bool
            Ignore discs whose reach holds ``origin`` (module docstring).
        exact : bool
            Triangles only: distances recomputed in float64 on the hit
            triangle's plane.
        n_threads : int, optional
            Default: all cores.
        pulse_aspect : float, optional
            With ``ties``: the rays are pulse centres of a scan pattern whose
            zenith step over azimuth step is this; candidates are then ranked
            by their angular offset from the ray in pulse units (the azimuth
            offset divided by sin(zenith), as pulses narrow towards the poles),
            not by their distance from it, so a ray keeps the point of its own
            pulse. None: nearest to the ray.
        one_pass : bool
            With ``ties``: collect the candidates in the first query (default);
            False: a second query over the window for every ray that hits (the
            rule of earlier versions, the same answers; a reference for tests
            and benchmarks).

        Returns
        -------
        RayHits
        """
        o = as_origin(origin)
        if pulse_aspect is not None and not (math.isfinite(pulse_aspect) and pulse_aspect > 0):
            raise InputValueError(f"pulse_aspect must be a finite number > 0, got {pulse_aspect!r}")
        d = np.ascontiguousarray(directions, np.float64)
        if d.ndim != 2 or d.shape[1] != 3:
            raise InputValueError(f"directions must be (m, 3), got {d.shape}")
        if (ties > 0 or skip_containing) and not self._has_owners:
            raise InputValueError("ties and skip_containing need discs (or triangles with owners)")
        if not (ties >= 0 and math.isfinite(ties)):
            raise InputValueError(f"ties must be a finite number >= 0, got {ties!r}")
        m = len(d)
        prim = np.empty(m, np.int64)
        owner = np.empty(m, np.int64)
        t = np.empty(m, np.float64)
        if m == 0:
            return RayHits(prim, owner, t)
        lib = embree_library()
        local = o - self.centre
        org32 = local.astype(np.float32)
        tf = float(np.float32(min(tfar, 3.0e38)))
        mode = _MODE_SKIP if skip_containing else 0
        n_threads = max(1, min(int(n_threads or default_threads()), -(-m // _TASK_RAYS)))

        def run(a):
            # one task: rays a .. a + _TASK_RAYS (threads take tasks in turn)
            e = min(m, a + _TASK_RAYS)
            _cast_rays(lib.intersect1, self._scene, _filter.address, org32, o, d[a:e],
                         np.float32(tnear), np.float32(tf), mode, float(ties), bool(one_pass),
                         float(pulse_aspect or 0.0),
                         self._owner_centres, self._owner_radii, self._owner_normals, self.prims_per_owner,
                         self.reach, self._box, prim[a:e], owner[a:e], t[a:e], self._vertex_centres, local)

        starts = range(0, m, _TASK_RAYS)
        if n_threads == 1:
            for a in starts:  # a signal (Ctrl-C, SIGTERM) is handled between tasks
                run(a)
        else:
            pool = ThreadPoolExecutor(n_threads)
            try:
                list(pool.map(run, starts))
            finally:
                # on an exception here (a signal), tasks not yet started are dropped: the
                # call returns after the running ones, not after the whole cast
                pool.shutdown(wait=True, cancel_futures=True)
        if exact:
            if self.kind != "triangles":
                raise InputValueError("exact=True is for triangle scenes")
            hit = prim >= 0
            f = prim[hit]
            v = self._vertices64
            a = v[self._faces[f, 0]]
            nrm = np.cross(v[self._faces[f, 1]] - a, v[self._faces[f, 2]] - a)
            nd = np.einsum("ij,ij->i", nrm, d[hit])
            t[hit] = np.einsum("ij,ij->i", nrm, a - o) / nd
        return RayHits(prim, owner, t)

    def __del__(self):
        scene = getattr(self, "_scene", None)
        if scene:
            try:
                self._lib.release_scene(scene)
            except Exception:  # pragma: no cover - interpreter shutdown
                pass
            self._scene = None


def disc_vertices(n: int) -> np.ndarray:
    """An uninitialised ``(n,) float32`` radius column of an ``(n, 4)`` vertex buffer:
    radii written here and handed to :meth:`RayScene.discs` are shared with Embree,
    not copied (4 bytes a point less at the peak of a build)."""
    return np.empty((n, 4), np.float32)[:, 3]


def _vertex_column(r, n):
    """The ``(n, 4)`` float32 buffer whose radius column ``r`` is (:func:`disc_vertices`), else None."""
    base = r.base if isinstance(r, np.ndarray) else None
    if (base is None or r.dtype != np.float32 or base.dtype != np.float32 or base.shape != (n, 4)
            or not base.flags.c_contiguous or r.shape != (n,) or r.strides != (16,)
            or r.ctypes.data != base.ctypes.data + 12):
        return None
    return base


def padded_rows(n: int, dtype=np.float32) -> np.ndarray:
    """An uninitialised ``(n, 3)`` array followed, in the same allocation, by two
    spare rows: Embree reads a float3 buffer 16 bytes at a time, so normals made
    in one of these are shared with :meth:`RayScene.discs` instead of copied."""
    buf = np.empty((n + 2, 3), dtype)
    buf[n:] = 0
    return buf[:n]


def _spare_bytes(a: np.ndarray) -> int:
    """Bytes of ``a``'s allocation after its last element (``a`` C-contiguous)."""
    owner = a
    while isinstance(owner.base, np.ndarray):
        owner = owner.base
    if not owner.flags.c_contiguous:
        return 0
    return int(owner.ctypes.data + owner.nbytes - (a.ctypes.data + a.nbytes))


@njit(cache=True, parallel=True)
def _fill_vertices(c, centre, r, out):
    """Embree's float4 vertices: centre-relative float32 coordinates and the radius."""
    for i in prange(c.shape[0]):
        out[i, 0] = np.float32(c[i, 0] - centre[0])
        out[i, 1] = np.float32(c[i, 1] - centre[1])
        out[i, 2] = np.float32(c[i, 2] - centre[2])
        out[i, 3] = r[i]


def _padded_bounds(vbuf, n, with_radius):
    """``(lo, hi)`` float64 of the vertex buffer's first ``n`` rows (scene frame),
    grown by the largest radius (discs) and a margin far above float32 rounding:
    a ray that misses it misses the scene. Empty scene: an empty box."""
    if n == 0:
        return np.array([np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf])
    lo, hi = bounds(vbuf[:n])
    grow = float(vbuf[:n, 3].max()) if with_radius else 0.0
    # Embree's own bounds are conservative in float32; 1e-5 of the extent (and 1 µm) is
    # far beyond its rounding, so no ray it could report a hit for is answered here
    pad = grow + 1e-5 * float(np.max(hi - lo)) + 1e-5 * float(np.max(np.abs(np.concatenate([lo, hi])))) + 1e-6
    return np.concatenate([lo - pad, hi + pad])


def _centre_of(points: np.ndarray) -> np.ndarray:
    if len(points) == 0:
        return np.zeros(3)
    lo, hi = bounds(points)
    return 0.5 * (lo + hi)


@njit(cache=True, parallel=True)
def _unit_rows(a, out):
    """Rows of ``a`` scaled to unit length (zero rows stay zero): one pass, no temporaries."""
    for i in prange(a.shape[0]):
        n = math.sqrt(a[i, 0] * a[i, 0] + a[i, 1] * a[i, 1] + a[i, 2] * a[i, 2])
        s = 1.0 / n if n > 0 else 0.0
        out[i, 0] = a[i, 0] * s
        out[i, 1] = a[i, 1] * s
        out[i, 2] = a[i, 2] * s


def _all_unit(a) -> bool:
    return _all_unit_within(a, 1e-12 if a.dtype == np.float64 else 1e-6)


@njit(cache=True)
def _all_unit_within(a, tol):
    for i in range(a.shape[0]):
        n2 = float(a[i, 0]) ** 2 + float(a[i, 1]) ** 2 + float(a[i, 2]) ** 2
        if abs(n2 - 1.0) > tol:
            return False
    return True

