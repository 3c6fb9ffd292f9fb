"""Embree scenes of triangles or discs (:class:`RayScene`); the compiled cast loop is in :mod:`.cast`.

The package docstring (:mod:`slr_ray.raycast`) describes the float32
boundary, the tie rule and the discs that hold the scanner.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..arrays import SERIAL_ROWS, as_origin, bounds, release_pages
from ..errors import InputValueError
from ..threads import default_threads
from .cast import FILTER, MODE_SKIP, NO_CLIP, PACKET_WIDTHS, cast_each, cast_packets
from .cull import FACE, direction_map, float32_margin, voxel_boxes
from .library import (BUFFER_INDEX, BUFFER_NORMAL, BUFFER_VERTEX, FORMAT_FLOAT3, FORMAT_FLOAT4, FORMAT_UINT3,
                      GEOMETRY_DISC_POINT, GEOMETRY_ORIENTED_DISC_POINT, GEOMETRY_TRIANGLE, SCENE_FLAG_COMPACT,
                      SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS, embree_library)
from .library import BUILD_QUALITY_LOW, SCENE_FLAG_DYNAMIC

__all__ = ["RayScene", "RayHits", "padded_rows", "disc_vertices"]

#: rays of one task handed to a thread: at least this many (a task costs ~20 us to start)...
_TASK_RAYS = 32768
#: ... and at most this many (small enough that a stopped scan stops soon); in between, eight tasks
#: a thread (a 3.1 M-ray cast on 2 threads: 0.092 s in tasks of 131,072 against 0.095 s in 32,768)
_TASK_RAYS_MAX = 131072
#: casts of fewer rays than this, or than the scene has voxel boxes, skip the direction map (.cull):
#: making it costs more than it saves (25-50 ns a box, against at most ~40 ns saved a ray; 14,000 rays
#: a cast of a 200 k-disc scene's 49 k boxes: 12.5 ms with the map, 9.0 ms without)
_CULL_RAYS = 4096


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
        the triangle index divided by ``prims_per_owner``. -1 on a miss. Where
        every primitive is its own owner (discs, and triangles that stand for
        no discs), ``owners`` *is* ``primitives``: one array (copy it before
        changing one of them in place).
    distances : (m,) float64
        Distance along the (unit) ray, ``inf`` on a miss.
    """

    primitives: np.ndarray
    owners: np.ndarray
    distances: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.owners >= 0


class Owners(NamedTuple):
    """The points a scene's primitives stand for (the tie rule's): their float64 centres, their
    radii, primitives per owner, the reach, their normals (or None); ``present`` False for a
    scene with none (a bare mesh)."""

    centres: np.ndarray
    radii: np.ndarray
    per_primitive: int = 1
    reach: float = 1.0
    normals: np.ndarray | None = None
    present: bool = True


class _Query(NamedTuple):
    """The options of one :meth:`RayScene.intersect` call, as its cast reads them."""

    tnear: float
    tfar: float
    ties: float
    skip_containing: bool
    n_threads: int | None
    pulse_aspect: float | None
    one_pass: bool
    packet: int | None
    cull: bool


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

    def __init__(self, kind, geometry_type, buffers, n_primitives, centre, owners: Owners, compact=False,
                 quick=False):
        owner_centres, owner_radii, prims_per_owner, reach, owner_normals, has_owners = owners
        self.kind = kind
        self.centre = centre
        self.n_primitives = int(n_primitives)
        self._buffers = buffers
        # float64 data of the owners (the points) for the filter: contiguous, kept alive here
        # (read-only, radii strided, no normals float32: every scene hands cast_packets one type, one compile)
        self._owner_centres = _read_only(np.ascontiguousarray(owner_centres, np.float64))
        # float32 (what Embree holds): for discs a view of the vertex buffer's radius column
        r = np.asarray(owner_radii)
        self._owner_radii = r if r.dtype == np.float32 and r.ndim == 1 and _typed_strided(r) else _strided(r)
        if owner_normals is None:
            self._owner_normals = np.zeros((0, 3), np.float32)
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
        # vertex rows (a triangle buffer's spare row excluded), bounded once: the box rays are tested
        # against first, and the occupied voxels' boxes whose directions a cast marks (.cull)
        rows = buffers[0][4][:buffers[0][5] if self.n_primitives else 0]
        extent = bounds(rows)
        self._box = _padded_bounds(rows, extent, geometry_type != GEOMETRY_TRIANGLE)
        lib = self._lib = embree_library()
        t0 = time.perf_counter()
        # the occupied voxels' boxes (.cull): made on the first cast that culls (intersect_each never does)
        self._cull_of = (buffers[0][4], buffers[1][4] if geometry_type == GEOMETRY_TRIANGLE else None,
                         self.n_primitives, extent)
        self._cull = None
        self._scene = lib.new_scene(lib.device)
        lib.set_scene_flags(self._scene, SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS
                            | (SCENE_FLAG_COMPACT if compact else 0) | (SCENE_FLAG_DYNAMIC if quick else 0))
        if quick:
            lib.set_scene_build_quality(self._scene, BUILD_QUALITY_LOW)
        if self.n_primitives:
            geom = lib.new_geometry(lib.device, geometry_type)
            if quick:
                lib.set_geometry_build_quality(geom, BUILD_QUALITY_LOW)
            for btype, slot, fmt, stride, arr, count in buffers:
                lib.set_shared_buffer(geom, btype, slot, fmt, arr.ctypes.data, 0, stride, count)
            lib.commit_geometry(geom)
            lib.attach_geometry(self._scene, geom)
            lib.release_geometry(geom)
        lib.commit_scene(self._scene)
        lib.check("building the scene")
        self.build_seconds = time.perf_counter() - t0

    @property
    def _cull_boxes(self) -> np.ndarray:
        if self._cull is None:
            v, f, n, extent = self._cull_of
            self._cull = voxel_boxes(v, f, n, extent=extent)
        return self._cull

    # --- constructors -------------------------------------------------------------------
    @classmethod
    def triangles(cls, vertices, faces, centre=None, *, owners=None, quick: bool = False) -> "RayScene":
        """A triangle mesh.

        Parameters
        ----------
        vertices : (v, 3) float
            Finite, and within float32 range of ``centre`` (else ``InputValueError``).
        faces : (f, 3) int
        centre : (3,) float, optional
            Recentring point (default: the middle of the bounding box).
        owners : tuple, optional
            ``(centres (n, 3), radii (n,), prims_per_owner, reach, normals (n, 3))``
            when the triangles stand for discs (polygon fans of
            ``prims_per_owner`` triangles each): enables ``ties`` and
            ``skip_containing`` with the owners' float64 centres.
        quick : bool
            Embree's quick (Morton) BVH build (a dynamic scene of low build quality): the same
            hits; a KITTI frame's ring mesh (232 k triangles) built in ~0.03 CPU s instead of
            ~0.09, cast ~30 % slower: for a mesh built for a few casts (``embree-rays``).
        """
        v = np.asarray(vertices, np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise InputValueError(f"vertices must be (v, 3) and faces (f, 3), got {v.shape} and {f.shape}")
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise InputValueError("faces index vertices that do not exist")
        centre = _centre_of(v) if centre is None else as_origin(centre, "centre")
        vbuf = np.zeros((len(v) + 1, 3), np.float32)  # one spare row: Embree reads 16 bytes per vertex
        with np.errstate(invalid="ignore", over="ignore"):  # refused just below, with a count
            vbuf[:len(v)] = v - centre
        _check_finite(vbuf, len(v), "vertices")
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
                     len(f), centre, Owners(oc, orad, per, reach, onrm, has_owners), quick=quick)
        return scene

    @classmethod
    def discs(cls, centres, radii, normals=None, centre=None, compact: bool = True) -> "RayScene":
        """Discs of Embree's point primitives.

        Parameters
        ----------
        centres : (n, 3) float64
            Disc centres (kept by reference for the float64 tie rule); finite,
            and within float32 range of ``centre`` (else ``InputValueError``).
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
        _fill_vertices(_read_only(c), centre, r, vbuf)  # one parallel pass, no float64 temporaries
        _check_finite(vbuf, len(c), "centres")
        # Embree builds from its float32 buffer: a file-mapped primary's pages (24 B a point) need not stay
        # resident through the build; the tie rule reads back the few it needs
        release_pages(c)
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
        cls.__init__(scene, kind, gtype, buffers, len(c), centre, Owners(c, vbuf[:, 3], 1, 1.0, owner_normals),
                     compact=compact)
        return scene

    @property
    def owner_radii(self) -> np.ndarray:
        """``(n,) float32`` radii of the discs (or of the discs a triangle fan stands
        for) as Embree and the tie rule use them; for discs, a read-only view of
        the vertex buffer."""
        v = self._owner_radii[:len(self._owner_centres)]  # not _strided's padding
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
                  one_pass: bool = True, packet: int | None = None, cull: bool = True, clip=None) -> RayHits:
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
        packet : {1, 4, 8, 16}, optional
            Rays per call into Embree (its ray packets); default: the widest
            this CPU traces natively (Embree's ``NATIVE_RAY16_SUPPORTED`` and
            the like). The same answers; 1 casts one ray at a time (the
            reference for tests).
        cull : bool
            Answer a ray as a miss without Embree when its direction meets
            none of the boxes of the scene's occupied voxels (default; a
            cube map of directions made for each call of 4,096 rays or more,
            and of at least as many rays as the scene has occupied voxels, at
            most 64^3: :mod:`slr_ray.raycast.cull`). The same answers; it pays where
            many rays meet the scene's bounding box and nothing in it (a scan
            from outside a cloud, its sky). False: every ray that meets the
            bounding box goes to Embree (the reference for tests).
        clip : tuple, optional
            The silhouette rule (scenes with owners): ``(bits, geo, edges)``, each
            owner's silhouette bits ``(n,) uint8``, the primary's grid
            ``(8,) float64`` (origin xyz, zenith min, zenith step, azimuth
            step, rows, columns; radians) and its band edges as ``-cos``
            ascending (empty for a uniform grid). A hit on a disc beyond the
            3 x 3 pulses of the primary around its owner's (seen from the
            primary's origin) is not a hit, nor one in a pulse next to its
            owner's where the owner's bit is set (that pulse's own return
            lies behind, or it has none).

        Returns
        -------
        RayHits
        """
        o, d, clip = self._checked_rays(origin, directions, ties, skip_containing, packet, pulse_aspect, clip)
        m = len(d)
        prim = np.empty(m, np.int64)
        # a primitive its own owner (discs, plain triangles): one array for both, one write less a ray
        owner = prim if self.prims_per_owner == 1 else np.empty(m, np.int64)
        t = np.empty(m, np.float64)
        if m == 0:
            return RayHits(prim, owner, t)
        self._cast_all(o, d, (prim, owner, t), clip, _Query(tnear, tfar, ties, skip_containing, n_threads,
                                                            pulse_aspect, one_pass, packet, cull))
        if exact:
            self._exact_distances(o, d, prim, t)
        return RayHits(prim, owner, t)

    def _checked_rays(self, origin, directions, ties, skip_containing, packet, pulse_aspect, clip) -> tuple:
        """:meth:`intersect`'s rays and options refused where they are none: ``(origin, directions, clip)``."""
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
        if packet is not None and (not isinstance(packet, (int, np.integer)) or packet not in PACKET_WIDTHS):
            raise InputValueError(f"packet must be one of {PACKET_WIDTHS}, got {packet!r}")
        if clip is None:
            clip = NO_CLIP
        elif not self._has_owners or len(clip[0]) != len(self._owner_centres):
            raise InputValueError("clip (the silhouette rule) needs owners (discs) and one byte an owner")
        else:
            clip = (np.ascontiguousarray(clip[0], np.uint8), np.ascontiguousarray(clip[1], np.float64),
                    np.ascontiguousarray(clip[2], np.float64))
        return o, d, clip

    def _cast_all(self, o, d, out, clip, q: _Query) -> None:
        """Every ray cast by Embree into ``out`` (``(prim, owner, t)``), in tasks shared by threads."""
        prim, owner, t = out
        m = len(d)
        tnear, tfar, ties, skip_containing, n_threads, pulse_aspect, one_pass, packet, cull = q
        lib = embree_library()
        local = o - self.centre
        org32 = local.astype(np.float32)
        tf = float(np.float32(min(tfar, 3.0e38)))
        mode = MODE_SKIP if skip_containing else 0
        width = lib.native_width if packet is None else int(packet)
        n_threads = max(1, min(int(n_threads or default_threads()), -(-m // _TASK_RAYS)))
        task = min(max(_TASK_RAYS, -(-m // (8 * n_threads))), _TASK_RAYS_MAX)
        if cull and m >= max(_CULL_RAYS, len(self._cull_boxes)) and len(self._cull_boxes):
            dmap = direction_map(self._cull_boxes, org32.astype(np.float64), FACE)
        else:
            dmap = np.zeros(0, np.uint8)

        def run(a):
            # one task: rays a .. a + task (threads take tasks in turn)
            e = min(m, a + task)
            cast_packets(lib.intersect[width], width, self._scene, FILTER.address, org32, o, d[a:e],
                           np.float32(tnear), np.float32(tf), mode, float(ties), bool(one_pass),
                           float(pulse_aspect or 0.0),
                           self._owner_centres, self._owner_radii, self._owner_normals, self.prims_per_owner,
                           self.reach, self._box, prim[a:e], owner[a:e], t[a:e], self._vertex_centres, local, dmap,
                           FACE, *clip)

        starts = range(0, m, task)
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

    def _exact_distances(self, o, d, prim, t) -> None:
        """Triangles only: each hit's distance recomputed in float64 on its triangle's plane (into ``t``)."""
        if self.kind != "triangles":
            raise InputValueError("exact=True is for triangle scenes")
        hit = prim >= 0
        f = prim[hit]
        v = self._vertices64
        a = v[self._faces[f, 0]]
        nrm = np.cross(v[self._faces[f, 1]] - a, v[self._faces[f, 2]] - a)
        nd = np.einsum("ij,ij->i", nrm, d[hit])
        t[hit] = np.einsum("ij,ij->i", nrm, a - o) / nd

    def intersect_each(self, origins, directions, *, tnear: float = 0.0, tfar: float = math.inf,
                       n_threads: int | None = None, packet: int | None = None) -> RayHits:
        """First hit of every ray from its own origin (``origins`` (m, 3) float64, the geometry's
        coordinates; ``directions`` (m, 3) unit): Embree's first hit, no tie rule, no culling (the
        rays of a fitted sensor, each laser firing from its own point). ``owners`` is ``primitives``."""
        o = np.asarray(origins, np.float64)
        d = np.ascontiguousarray(directions, np.float32)
        if d.ndim != 2 or d.shape[1] != 3 or o.shape != d.shape:
            raise InputValueError(f"origins and directions must both be (m, 3), got {o.shape} and {d.shape}")
        if packet is not None and packet not in PACKET_WIDTHS:
            raise InputValueError(f"packet must be one of {PACKET_WIDTHS}, got {packet!r}")
        m = len(d)
        prim = np.empty(m, np.int64)
        t = np.empty(m, np.float64)
        if m == 0:
            return RayHits(prim, prim, t)
        org = np.ascontiguousarray(o - self.centre, np.float32)
        lib = embree_library()
        width = lib.native_width if packet is None else int(packet)
        tn, tf = np.float32(tnear), np.float32(min(tfar, 3.0e38))
        n_threads = max(1, min(int(n_threads or default_threads()), -(-m // _TASK_RAYS)))
        task = -(-m // n_threads)

        def run(a):
            e = min(m, a + task)
            cast_each(lib.intersect[width], width, self._scene, org[a:e], d[a:e], tn, tf, prim[a:e], t[a:e])

        if n_threads == 1:
            run(0)
        else:
            with ThreadPoolExecutor(n_threads) as pool:
                list(pool.map(run, range(0, m, task)))
        return RayHits(prim, prim, t)

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


def _read_only(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


def _typed_strided(r) -> bool:
    return len(r) > 1 and not r.flags.c_contiguous


def _strided(r) -> np.ndarray:
    """``r`` as float32 in a column of an ``(n, 2)`` buffer (at least 2 rows, zeros after ``r``):
    strided as the radius column of a disc scene's vertex buffer is (numba calls 1 row
    contiguous), so numba compiles cast_packets for one layout (about 8 s each) whatever the scene."""
    out = np.zeros((max(len(r), 2), 2), np.float32)[:, 0]
    out[:len(r)] = r
    return out


def _check_finite(vbuf, n, what):
    """Refuse rows of the float32 buffer that are not finite: NaN or infinite input, or a
    coordinate too far from the scene's centre for float32 (Embree would answer no ray)."""
    bad = _nonfinite_rows(vbuf, n) if n >= SERIAL_ROWS else _nonfinite_rows_serial(vbuf, n)
    if bad:
        raise InputValueError(f"{what} must be finite and within float32 range of the scene's centre "
                              f"(|coordinate - centre| < 3.4e38): {bad} of {n} rows are not")


@njit(cache=True)
def _row_nonfinite(vbuf, i):
    """1 where row ``i`` of ``vbuf[:, :3]`` holds a NaN or an infinity, else 0."""
    return 0 if np.isfinite(vbuf[i, 0]) and np.isfinite(vbuf[i, 1]) and np.isfinite(vbuf[i, 2]) else 1


@njit(cache=True, parallel=True)
def _nonfinite_rows(vbuf, n):
    """Rows of ``vbuf[:n, :3]`` with a NaN or an infinity (one parallel pass, no temporaries)."""
    bad = 0
    for i in prange(n):
        bad += _row_nonfinite(vbuf, i)
    return bad


@njit(cache=True)
def _nonfinite_rows_serial(vbuf, n):
    """:func:`_nonfinite_rows` on one thread (small scenes: waking the others costs more)."""
    bad = 0
    for i in range(n):
        bad += _row_nonfinite(vbuf, i)
    return bad


@njit(cache=True, parallel=True)
def _fill_vertices(c, centre, r, out):
    """Embree's float4 vertices: centre-relative float32 coordinates and the radius."""
    for i in prange(c.shape[0]):
        out[i, 0] = np.float32(c[i, 0] - centre[0])
        out[i, 1] = np.float32(c[i, 1] - centre[1])
        out[i, 2] = np.float32(c[i, 2] - centre[2])
        out[i, 3] = r[i]


def _padded_bounds(rows, extent, with_radius):
    """The vertex ``rows``' bounds ``extent`` (float64, scene frame) grown by the largest
    radius (discs) and a margin far above float32 rounding: a ray that misses it misses
    the scene. Empty scene: an empty box."""
    if len(rows) == 0:
        return np.array([np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf])
    lo, hi = extent
    pad = (float(rows[:, 3].max()) if with_radius else 0.0) + float32_margin(lo, hi)
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

