"""The embree backend: points splatted as small discs, one ray per pulse.

Each point becomes a disc (a polygon of ``segments`` vertices that contains
the disc, as ``segments - 2`` triangles); all discs go into one Embree BVH (embreex), and one ray is
cast through the centre of every pulse. The point whose disc is hit first is
returned. Where the binning backend answers "the closest point in the pulse's
pyramid", this answers "the first surface along the pulse's centre ray", with
the surface reconstructed from the points: it exposes binning artefacts (a
point far behind a surface, returned only because no point of the surface
fell in that pulse).

Choices, all options of :class:`DiscScene`, with the defaults picked from
``benchmarks/bench_tradeoff.py`` (README, "Speed and accuracy"):

radius
    a fixed value in metres, an ``(n,)`` array, ``"spacing"`` (``radius_scale``
    times the mean distance to the ``k`` nearest neighbours: adapts to any
    cloud) or ``"footprint"`` (``radius_scale`` times the primary pulse
    footprint ``R_primary * tan(primary_resolution)``: needs
    ``primary_origin`` and ``primary_resolution``).
    Default ``"spacing"``: as accurate as any other setting measured, and
    it needs nothing but the cloud; fixed 2 cm discs were the least
    accurate, half-size discs leak, double-size discs hide.
orientation
    ``"billboard"``: discs face the scanning position (a BVH per position);
    ``"normal"`` (default): discs lie along normals estimated from the ``k``
    nearest neighbours (one BVH, reused for every position). Same accuracy
    against pulse-centre truth, 3-4 times less time per position.
segments
    rim vertices of each disc's polygon (``segments - 2`` triangles).
    Default 3 (one triangle): as accurate as 5 or 7 and the fastest to
    build and cast.

Embree works in float32: coordinates are recentred in float64 (on the scanner
for billboards, on the cloud's centre for shared BVHs) before conversion, and
ranges are recomputed in float64 from the input points. Points closer to the
scanner than the reach of their own polygon are not splatted (it could contain
the ray origin and hide everything), and points the pattern cannot see (range
limits, field of view) are not returned.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..arrays import as_origin, as_points
from ..errors import InputValueError, MissingDependencyError
from ..pattern import ScanPattern
from .binning import default_threads, pulse_keys

__all__ = ["DiscScene", "scan_points", "disc_radii", "estimate_normals"]

RADIUS_MODES = ("spacing", "footprint")
ENGINES = ("embreex", "open3d")
ORIENTATIONS = ("billboard", "normal")


def _embree():
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as exc:  # pragma: no cover - embreex is a dependency
        raise MissingDependencyError("the embree backend needs embreex: pip install embreex") from exc
    return rtcore_scene, TriangleMesh


def _knn(points, k):
    from scipy.spatial import cKDTree

    c = points.mean(axis=0)
    tree = cKDTree(points - c)
    k = min(k + 1, len(points))
    d, i = tree.query(points - c, k=k, workers=-1)
    return d[:, 1:], i[:, 1:]


def disc_radii(points, radius="spacing", *, k: int = 6, radius_scale: float = 1.0,
               primary_origin=None, primary_resolution=None, knn=None) -> np.ndarray:
    """Disc radius of every point, ``(n,) float64`` (see the module docstring).

    ``knn``: the ``(distances, indices)`` of at least ``k`` nearest neighbours
    (excluding the point itself) if already computed.
    """
    n = len(points)
    if isinstance(radius, str):
        if radius == "spacing":
            if n < 2:
                return np.full(n, 0.01 * radius_scale)
            d = (knn if knn is not None else _knn(points, k))[0][:, :k]
            r = d.mean(axis=1)
        elif radius == "footprint":
            if primary_origin is None or primary_resolution is None:
                raise InputValueError("radius='footprint' needs primary_origin and primary_resolution")
            rp = np.linalg.norm(points - as_origin(primary_origin, "primary_origin"), axis=1)
            r = rp * np.tan(np.radians(float(primary_resolution)))
        else:
            raise InputValueError(f"radius must be a number, an array or one of {RADIUS_MODES}, got {radius!r}")
    else:
        r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,)).copy()
    r = r * radius_scale
    if not np.all(np.isfinite(r)) or np.any(r <= 0):
        raise InputValueError(f"disc radii must be finite and > 0 ({np.count_nonzero(~(r > 0))} are not)")
    return r


def estimate_normals(points, k: int = 10, knn=None) -> np.ndarray:
    """Unit normals ``(n, 3)`` by PCA of the ``k`` nearest neighbours (smallest
    eigenvector); ``knn`` as in :func:`disc_radii`."""
    if len(points) < 3:
        return np.tile([0.0, 0.0, 1.0], (len(points), 1))
    idx = (knn if knn is not None else _knn(points, k))[1][:, :k]
    out = np.empty((len(points), 3))
    step = 1 << 20
    for s in range(0, len(points), step):
        nb = points[idx[s:s + step]]
        nb = nb - nb.mean(axis=1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", nb, nb)
        _, vec = np.linalg.eigh(cov)
        out[s:s + step] = vec[:, :, 0]
    return out


def _frames(normals):
    """Two unit vectors spanning the plane orthogonal to each normal."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, [2]]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(n, u)


def _fan(centres, normals, radii, segments):
    """Splats as polygons: vertices (n * segments, 3) float32, faces (n * (segments - 2), 3).

    Each disc is a regular polygon of ``segments`` rim vertices that contains
    the disc, triangulated as a fan from its first rim vertex. There is no
    vertex at the disc centre: a ray through a point exactly (the common case
    when a scan is scanned again from its own origin) would hit six triangles
    at their shared vertex, which Embree's fast intersection test can miss.
    With an odd ``segments`` no edge passes through the centre either.
    """
    n = len(centres)
    u, w = _frames(normals)
    ang = 2 * np.pi * (np.arange(segments) + 0.25) / segments
    rim = radii / np.cos(np.pi / segments)  # the polygon circumscribes the disc
    verts = np.empty((n, segments, 3), dtype=np.float32)
    for j, a in enumerate(ang):
        verts[:, j] = centres + rim[:, None] * (np.cos(a) * u + np.sin(a) * w)
    base = (np.arange(n, dtype=np.int64) * segments)[:, None]
    j = np.arange(1, segments - 1)
    faces = np.empty((n, segments - 2, 3), dtype=np.int32)
    faces[:, :, 0] = base
    faces[:, :, 1] = base + j
    faces[:, :, 2] = base + j + 1
    return verts.reshape(-1, 3), faces.reshape(-1, 3)


class DiscScene:
    """Points as discs in an Embree BVH, ready to scan from many positions.

    Parameters
    ----------
    points : (n, 3) float
    radius : float, (n,) float, {'spacing', 'footprint'}
    orientation : {'normal', 'billboard'}
        ``'normal'`` builds one BVH now and reuses it for every :meth:`scan`;
        ``'billboard'`` builds a BVH per scan, facing that scan's origin.
    segments : int
        Rim vertices of the polygon standing for a disc (>= 3; it is made of
        ``segments - 2`` triangles). Odd values keep every triangle edge off
        the disc centre.
    normals : (n, 3) float, optional
        Normals to use with ``'normal'`` instead of estimating them.
    k : int
        Neighbours for ``'spacing'`` radii and for normals.
    radius_scale : float
        Multiplies every radius.
    primary_origin, primary_resolution
        For ``radius='footprint'``: the primary scanner and its resolution (deg).
    engine : {'embreex', 'open3d'}
        The Embree front end: embreex (default; copies triangles into Embree
        slowly, about 0.8 s per million) or Open3D's ``RaycastingScene``
        (copies fast, casts on all cores; needs open3d and libusb).
    robust : bool
        Embree's robust mode (watertight edges; slower; embreex only). With the default
        False, fans still do not leak: rays through the shared edges of a
        fan hit one of its triangles.
    n_threads : int, optional
        Threads casting rays (default: all cores).

    Attributes
    ----------
    radii : (n,) float64
    build_seconds : float
        Time to build the last BVH.
    nbytes : int
        Bytes of the vertex and index arrays handed to Embree (the BVH itself
        takes about as much again).
    """

    def __init__(self, points, radius="spacing", orientation="normal", segments: int = 3, *,
                 normals=None, k: int = 6, radius_scale: float = 1.0, primary_origin=None,
                 primary_resolution=None, robust: bool = False, n_threads: int | None = None,
                 engine: str = "embreex"):
        self.points = as_points(points).astype(np.float64, copy=False)
        if orientation not in ORIENTATIONS:
            raise InputValueError(f"orientation must be one of {ORIENTATIONS}, got {orientation!r}")
        if int(segments) != segments or segments < 3:
            raise InputValueError(f"segments must be an integer >= 3, got {segments!r}")
        if engine not in ENGINES:
            raise InputValueError(f"engine must be one of {ENGINES}, got {engine!r}")
        self.engine = engine
        self.orientation = orientation
        self.segments = int(segments)
        self.robust = bool(robust)
        self.n_threads = int(n_threads or default_threads())
        t0 = time.perf_counter()
        knn = None
        if isinstance(radius, str) and radius == "spacing" and orientation == "normal" and normals is None \
                and len(self.points) >= 3:
            knn = _knn(self.points, max(k, 6))  # one neighbour query serves radii and normals
        self.radii = disc_radii(self.points, radius, k=k, radius_scale=radius_scale,
                                primary_origin=primary_origin, primary_resolution=primary_resolution, knn=knn)
        self.prepare_seconds = time.perf_counter() - t0
        self.options = {"radius": radius if isinstance(radius, str) else "fixed",
                        "orientation": orientation, "segments": self.segments, "engine": engine,
                        "radius_scale": radius_scale, "k": k}
        self._scene = None
        self.build_seconds = 0.0
        self.nbytes = 0
        if orientation == "normal":
            t0 = time.perf_counter()
            if normals is None:
                normals = estimate_normals(self.points, max(k, 6), knn=knn)
                del knn
            else:
                normals = as_points(normals, "normals").astype(np.float64)
                if len(normals) != len(self.points):
                    raise InputValueError(f"normals has {len(normals)} rows for {len(self.points)} points")
            self.normals = normals
            self.prepare_seconds += time.perf_counter() - t0
            self._centre = 0.5 * (self.points.min(axis=0) + self.points.max(axis=0)) if len(self.points) else np.zeros(3)
            self._ids = np.arange(len(self.points))
            self._build(self.points, self.normals, self.radii, self._centre, self._ids)

    def _build(self, pts, normals, radii, centre, ids):
        if self.engine == "open3d":
            return self._build_open3d(pts, normals, radii, centre, ids)
        rtcore_scene, TriangleMesh = _embree()
        t0 = time.perf_counter()
        scene = rtcore_scene.EmbreeScene(robust=self.robust) if self.robust else rtcore_scene.EmbreeScene()
        if len(pts):
            verts, faces = _fan(pts - centre, normals, radii, self.segments)
            TriangleMesh(scene, verts, faces)
            self.nbytes = verts.nbytes + faces.nbytes
        self._scene, self._scene_ids, self._scene_centre = scene, ids, centre
        self.build_seconds = time.perf_counter() - t0

    def _build_open3d(self, pts, normals, radii, centre, ids):
        try:
            import open3d as o3d
        except ImportError as exc:
            raise MissingDependencyError(
                "engine='open3d' needs open3d (pip install open3d; apt-get install libusb-1.0-0)") from exc
        t0 = time.perf_counter()
        scene = o3d.t.geometry.RaycastingScene()
        if len(pts):
            verts, faces = _fan(pts - centre, normals, radii, self.segments)
            scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(faces.astype(np.uint32)))
            self.nbytes = verts.nbytes + faces.nbytes
        self._scene, self._scene_ids, self._scene_centre = scene, ids, centre
        self.build_seconds = time.perf_counter() - t0

    def _cast_open3d(self, origin_local, dirs, tfar):
        import open3d as o3d

        rays = np.empty((len(dirs), 6), np.float32)
        rays[:, :3] = origin_local
        rays[:, 3:] = dirs
        ans = self._scene.cast_rays(o3d.core.Tensor(rays), nthreads=self.n_threads)
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        t = ans["t_hit"].numpy()
        prim[(prim == o3d.t.geometry.RaycastingScene.INVALID_ID) | ~(t <= tfar)] = -1
        return prim, t

    def _cast(self, origin_local, dirs, tfar):
        if self.engine == "open3d":
            return self._cast_open3d(origin_local, dirs, tfar)
        o32 = np.broadcast_to(origin_local.astype(np.float32), dirs.shape).copy()
        d32 = dirs.astype(np.float32)
        prim = np.empty(len(dirs), np.int32)
        dists = np.full(len(dirs), tfar, np.float32)
        n_threads = min(self.n_threads, max(1, len(dirs) // 50_000))
        bounds = np.linspace(0, len(dirs), n_threads + 1).astype(int)

        def run(i):
            a, b = bounds[i], bounds[i + 1]
            out = self._scene.run(o32[a:b], d32[a:b], dists=dists[a:b].copy(), output=True)
            prim[a:b] = out["primID"]
            dists[a:b] = out["tfar"]

        if n_threads > 1:
            with ThreadPoolExecutor(n_threads) as pool:
                list(pool.map(run, range(n_threads)))
        else:
            run(0)
        return prim, dists

    def _prepare(self, origin, pattern):
        """Pulse keys and ranges of every point from ``origin``; (re)build the BVH if needed."""
        keys, ranges = pulse_keys(self.points, origin, pattern)
        seen = keys >= 0
        build = 0.0
        # the polygon standing for a disc reaches out to radius / cos(pi / segments)
        reach = self.radii / math.cos(math.pi / self.segments)
        if self.orientation == "billboard":
            # splat only what the pattern can see, and nothing whose polygon holds the origin
            ids = np.flatnonzero(seen & (ranges > reach))
            pts = self.points[ids]
            self._build(pts, origin - pts, self.radii[ids], origin, ids)
            build = self.build_seconds
        else:
            ids_close = np.flatnonzero(ranges <= reach)
            if len(ids_close):
                # discs holding the origin would hide everything: rebuild without them
                keep = np.setdiff1d(self._ids, ids_close)
                self._build(self.points[keep], self.normals[keep], self.radii[keep], self._centre, keep)
                build = self.build_seconds
            elif self._scene_ids is not self._ids:
                self._build(self.points, self.normals, self.radii, self._centre, self._ids)
                build = self.build_seconds
        return seen, ranges, build

    def _hits(self, origin, pattern, rays_per_batch=1 << 21):
        """Every ray that hits a disc: (point index, t, v, h) arrays."""
        from ..meshscan import _pulse_grid

        local = origin - self._scene_centre
        rmin, rmax = pattern.range_limits
        reach = self.radii.max(initial=0.0) / math.cos(math.pi / self.segments)
        tfar = float(np.float32(min(rmax + 2 * reach, 3e37)))
        nv, nh = pattern.shape
        rows_per = max(1, rays_per_batch // nh)
        parts = []
        for r0 in range(0, nv, rows_per):
            dirs, vv, hh = _pulse_grid(pattern, slice(r0, min(nv, r0 + rows_per)), 1)
            prim, t = self._cast(local, dirs, tfar)
            hit = prim >= 0
            parts.append((self._scene_ids[prim[hit] // (self.segments - 2)], t[hit], vv[hit], hh[hit]))
        if not parts:
            return np.empty(0, np.int64), np.empty(0, np.float32), np.empty(0, np.int64), np.empty(0, np.int64)
        return tuple(np.concatenate([p[j] for p in parts]) for j in range(4))

    def ray_hits(self, origin, pattern):
        """Per-ray answer: for every pulse whose centre ray hits a disc, the point.

        Returns
        -------
        pulses : (k, 2) int64
            ``(v, h)`` of each ray that hit.
        indices : (k,) intp
            The point whose disc it hit first (a point may appear for several pulses).
        distances : (k,) float32
            Distance along the ray to the disc.
        """
        from ..scan import _check_pattern

        pattern = _check_pattern(pattern)
        origin = as_origin(origin)
        self._prepare(origin, pattern)
        pt, t, v, h = self._hits(origin, pattern)
        return np.column_stack([v, h]), pt.astype(np.intp), t

    def scan(self, origin, pattern, rays_per_batch: int = 1 << 21):
        """Scan the discs from ``origin`` with ``pattern``; returns a :class:`~slr_ray.Scan`.

        A point hit by several rays appears once, with the pulse of its
        nearest ray. ``info`` of the result holds ``build_seconds`` (0 when
        the BVH was reused), ``cast_seconds``, ``rays`` and ``ray_hits``
        (rays that hit a disc).
        """
        return self.scan_and_rays(origin, pattern, rays_per_batch)[0]

    def scan_and_rays(self, origin, pattern, rays_per_batch: int = 1 << 21):
        """:meth:`scan` and :meth:`ray_hits` from one cast: ``(scan, (pulses, indices, distances))``."""
        from ..scan import Scan, _check_pattern

        pattern = _check_pattern(pattern)
        origin = as_origin(origin)
        t_start = time.perf_counter()
        seen, ranges, build = self._prepare(origin, pattern)
        t_cast = time.perf_counter()
        pt, tt, v, h = self._hits(origin, pattern, rays_per_batch)
        cast = time.perf_counter() - t_cast
        rays = (np.column_stack([v, h]), pt.astype(np.intp), tt)
        n_ray_hits = len(pt)
        ok = seen[pt]  # points the pattern itself would not see are not returned
        pt, tt, v, h = pt[ok], tt[ok], v[ok], h[ok]
        order = np.lexsort((tt, pt))  # per point, its nearest ray first
        pt, v, h = pt[order], v[order], h[order]
        first = np.ones(len(pt), bool)
        first[1:] = pt[1:] != pt[:-1]
        idx = pt[first].astype(np.intp)
        scan = Scan(indices=idx, ranges=ranges[idx], pulses=np.column_stack([v[first], h[first]]),
                    origin=origin, pattern=pattern, backend="embree", n_input=len(self.points),
                    seconds=time.perf_counter() - t_start,
                    info={"build_seconds": round(build, 6), "cast_seconds": round(cast, 6),
                          "rays": int(pattern.n_pulses), "ray_hits": int(n_ray_hits),
                          **self.options})
        return scan, rays


def scan_points(points, origin, pattern: ScanPattern, radius="spacing", orientation="normal",
                segments: int = 3, **options):
    """The embree backend behind :func:`slr_ray.simulate_scan` (one position).

    Builds a :class:`DiscScene` and scans it once; use :class:`DiscScene`
    directly to scan one cloud from many positions.
    """
    scene = DiscScene(points, radius=radius, orientation=orientation, segments=segments, **options)
    scan = scene.scan(origin, pattern)
    scan.info["prepare_seconds"] = round(scene.prepare_seconds, 6)
    return scan
