"""The embree backend's scanner: a cloud as discs in one BVH, one ray per pulse
(:class:`DiscScanner`; the package docstring describes the options)."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from numba import njit

from ...arrays import as_origin, as_points, bounds, release_pages
from ...core import ranges_of
from ...errors import InputValueError, refuse_memory
from ...pattern import as_pattern, pulse_rays
from ...progress import step
from ...raycast import CELLS_AND_SILHOUETTES, CELLS_OFF, CELLS_ONLY, Open3DScene, RayScene, disc_vertices, padded_rows
from ...scan import Scan
from ..base import Backend, Scanner
from .fit import fit_primary_pattern, fitted_grid_holds
from .discs import (PULSE_REACH_CAP, chunk_normals, disc_radii, fallback_directions, fan_polygons, limit_incidence,
                    neighbourhoods, pulse_centre_reach)
from .options import EmbreeOptions, refuse_cast
from .pulsegrid import pulse_grid_spacing_normals, require_a_scan_from

__all__ = ["DiscScanner", "PRIMARY_VIEW_TOLERANCE", "ENCLOSED_SHARE", "same_pulse_grid"]

#: a scan whose rays stop, more than this share of them, on discs within two of their radii of its origin
#: stands among points (a bush, a car, a tree's crown around it: KITTI frame 0's augment positions, 0.57 and
#: 0.64; open street 0.00): the discs, surfaces, hide what lies beyond them, where binning's points leave
#: gaps to see through (2,658 and 14,212 points against binning's 20,527 and 32,510; open street 96,897
#: against 96,473), said by ``slr-ray augment`` (``Scan.info['enclosed_share']``)
ENCLOSED_SHARE = 0.2

#: metres: a scan from this close to ``primary_origin`` with the primary's own pattern is its own view
PRIMARY_VIEW_TOLERANCE = 1e-6


def _initial_normals(pts, o: EmbreeOptions, need_normals, grid, ndtype):
    """The discs' normals before the neighbour pass: the given ones (checked), the primary's
    directions, the fallback for fewer than two points, kNN's zeroed rows to fill, or None."""
    n = len(pts)
    normals = None
    if o.orientation == "normal":
        # kNN normals are filled chunk by chunk below, pulse-grid ones come whole; fewer than two
        # points have no neighbours and keep the fallback direction
        if not need_normals:
            normals = np.asarray(as_points(o.normals, "normals"), np.float64)
        elif n < 2:
            normals = np.array(fallback_directions(pts, o.primary_origin, ndtype))
        elif not grid:
            normals = padded_rows(n, ndtype)  # shared with Embree, not copied
        if normals is not None and len(normals) != n:
            raise InputValueError(f"normals has {len(normals)} rows for {n} points")
    elif o.orientation == "primary":
        # float32: what Embree holds anyway (a float64 copy would be 24 B a point of peak memory)
        normals = fallback_directions(pts, o.primary_origin, np.float32)
    return normals


def _check_pulse_cells(o: EmbreeOptions) -> None:
    """``pulse_cells`` refused without the primary's origin and pattern (checked when the scanner is made,
    not with the options: ``slr-ray scan`` adds a file's own primary to them later)."""
    if o.pulse_cells and (o.primary_origin is None or o.primary_grid is None):
        raise InputValueError("pulse_cells needs primary_origin and primary_resolution (or primary_pattern)")


def _reaching_pulse_centres(pts, normals, o: EmbreeOptions, radii):
    """``radii`` grown, with ``pulse_cells``, to hold each point's own pulse's centre ray (at most
    :data:`~.discs.PULSE_REACH_CAP` times)."""
    step("discs reaching their pulse centres")
    reach = pulse_centre_reach(pts, normals if o.orientation != "billboard" else None, o.primary_origin,
                               o.primary_grid)
    return np.maximum(radii, np.minimum(reach, PULSE_REACH_CAP * radii))


class DiscScanner(Scanner):
    """A cloud as discs in one Embree BVH, ready to scan from many positions.

    Made by ``slr_ray.prepare(points, backend="embree", **options)``; options
    are those of :class:`EmbreeOptions`. Neighbours, radii, normals and the
    BVH are computed here, once; :meth:`scan` only casts rays.

    Attributes
    ----------
    radii : (n,) float32
        The disc radii as Embree uses them (for the ``embree`` engine, a
        read-only view of its vertex buffer).
    normals : (n, 3) float64 or None
        None for ray-facing discs (``orientation='billboard'``) and for discs
        facing the primary scanner (``orientation='primary'``: the direction
        to ``primary_origin``, not kept to save 24 bytes a point).
    build_seconds : float
        Time to build the BVH.
    neighbour_seconds : float
        Time for neighbours, radii and normals.
    nbytes : int
        Bytes of the arrays shared with the ray engine (the BVH comes on top).
    """

    backend = Backend.EMBREE
    casts_rays = costly_prepare = True  # capabilities (slr_ray.backends.base.Scanner)

    @classmethod
    def primary_options(cls, origin, primary, fast: bool = False) -> dict:
        """The primary's origin and resolution or pattern; ``fast``: footprint discs facing it (no neighbours)."""
        key = "primary_resolution" if isinstance(primary, (int, float)) else "primary_pattern"
        return {**({"radius": "footprint", "orientation": "primary"} if fast else {}),
                "primary_origin": origin, key: primary}

    def __init__(self, points, options: EmbreeOptions | None = None):
        t0 = time.perf_counter()
        options = options or EmbreeOptions()
        pts = as_points(points).astype(np.float64, copy=False)
        #: how ``primary_pattern='fit'`` was fitted (None: given), and the fit's quality
        #: (:func:`~.fit.fit_quality`: the share of its occupied pulses that hold one point)
        self.primary_fit = self.primary_fit_quality = None
        if options.fit_pending:
            fitted, self.primary_fit, self.primary_fit_quality = fit_primary_pattern(pts, options.primary_origin)
            options = dataclasses.replace(options, primary_pattern=fitted)
        _check_pulse_cells(options)
        super().__init__(pts, options)
        o = options
        n = len(pts)
        need_spacing = isinstance(o.radius, str) and o.radius == "spacing"
        need_normals = o.orientation == "normal" and o.normals is None
        spacing = np.zeros(n) if need_spacing else None
        # estimated normals in float32 for Embree (its precision; 12 B a point less at the peak)
        ndtype = np.float32 if o.engine == "embree" else np.float64
        grid = (need_spacing or need_normals) and o.neighbours == "pulse-grid"
        if o.primary_beams is not None:
            o.primary_grid.rows_of_beams(o.primary_beams, n)  # a bad length or beam id fails here, used or not
        if o.engine != "embree":  # polygon fans: vertices (24 B) and faces (24 B) per segment, before any work
            refuse_memory(48.0 * n * o.segments, f"discs as fans of {o.segments:,} segments for {n:,} points",
                          "use fewer segments (3 to 16 is plenty) or engine='embree'")
        normals = _initial_normals(pts, o, need_normals, grid, ndtype)
        self._clip = None
        if grid and n >= 2:
            step("pulse-grid neighbours and normals")  # the phase the caller runs this in says it, once named
            clip = (np.zeros(n, np.uint8) if o.silhouettes and o.primary_beams is None and o.engine != "open3d"
                    else None)
            # one fused pass: no neighbour arrays (spacing 0 where none: the floor applies)
            spacing, grid_normals = pulse_grid_spacing_normals(pts, o.primary_origin, o.primary_grid,
                                                               o.grid_gate, need_spacing, need_normals, ndtype,
                                                               max_incidence=o.max_incidence,
                                                               beams=o.primary_beams,
                                                               spacing_kind=o.grid_spacing,
                                                               silhouette=clip)
            if clip is not None:
                self._clip = (clip, *_grid_geometry(o.primary_origin, o.primary_grid,
                                                    CELLS_AND_SILHOUETTES if o.pulse_cells else CELLS_OFF))
            if need_normals:
                normals = grid_normals
        elif need_spacing or need_normals:
            # one neighbour query per chunk serves radii and normals
            for s, d, idx in neighbourhoods(pts, o.k, o.chunk):
                step("neighbours and normals" if need_normals else "neighbours", s / n)
                if need_spacing:
                    spacing[s:s + len(d)] = d.mean(axis=1)
                if need_normals:
                    normals[s:s + len(idx)] = chunk_normals(pts, np.arange(s, s + len(idx)), idx,
                                                             o.primary_origin)
        if o.pulse_cells and self._clip is None:  # the cut alone (no silhouette bits here)
            self._clip = (np.zeros(n, np.uint8), *_grid_geometry(o.primary_origin, o.primary_grid, CELLS_ONLY))
        if need_normals and n >= 2 and o.max_incidence < 90 and not grid:  # the grid pass turns its own
            limit_incidence(pts, normals, as_origin(o.primary_origin, "primary_origin"),
                             math.cos(math.radians(o.max_incidence)))
        # float32, Embree's precision (4 B a point instead of 8: 0.8 GB on a 209 M-point primary); for
        # the embree engine written straight into the radius column of Embree's vertex buffer (shared)
        step("disc radii")
        if isinstance(o.radius, str) and o.radius == "footprint" and not grid:  # the grid pass checked it
            require_a_scan_from(pts, o.primary_origin, o.primary_grid)  # else discs as wide as crowded pulses
        r64 = disc_radii(pts, o.radius, k=o.k, radius_scale=o.radius_scale,
                         primary_origin=o.primary_origin, primary_resolution=o.primary_grid,
                         min_radius=o.min_radius, fallback_radius=o.fallback_radius, spacing=spacing)
        del spacing
        if o.pulse_cells and n:  # each disc holds its own pulse's centre ray (the cell cut keeps it there)
            r64 = _reaching_pulse_centres(pts, normals, o, r64)
        self.radii = disc_vertices(n) if o.engine == "embree" else np.empty(n, np.float32)
        self.radii[:] = r64
        del r64
        self.normals = normals
        self.neighbour_seconds = time.perf_counter() - t0
        t1 = time.perf_counter()
        self._build_scene(pts, normals, o)
        self._max_radius = float(self.radii.max(initial=0.0))  # read by every scan: computed once
        self.nbytes = self._scene.nbytes
        self.build_seconds = time.perf_counter() - t1
        self.prepare_seconds = time.perf_counter() - t0

    def _build_scene(self, pts, normals, o: EmbreeOptions) -> None:
        """The ray scene of the discs (Embree's discs, or polygon fans for Embree or Open3D)."""
        n = len(pts)
        self._centre = 0.5 * np.add(*bounds(pts)) if n else np.zeros(3)
        self._scene = None
        step("BVH")
        if o.engine == "embree":
            self._scene = RayScene.discs(pts, self.radii, normals, centre=self._centre)
            self.radii = self._scene.owner_radii  # a view of Embree's buffer: no second copy
            self._per_point = 1
        else:
            self._per_point = o.segments - 2
            verts, faces = fan_polygons(pts, normals, self.radii, o.segments)
            if o.engine == "fan":
                self._scene = RayScene.triangles(verts, faces, centre=self._centre,
                                                 owners=(pts, self.radii, self._per_point, o.reach, normals))
            else:
                self._scene = Open3DScene(verts, faces, pts, self.radii, self._per_point, o.reach,
                                          centre=self._centre)
            del verts, faces
        if o.engine == "embree" and normals is not None:
            # Embree and the tie rule hold their own float32 copy: the float64 one (24 B a point, 5 GB on
            # a 209 M-point primary) is not kept; ``normals`` is a read-only view of Embree's
            self.normals = normals = self._scene.owner_normals

    def _cast(self, origin, dirs, tfar, aspect=None):
        o = self.options
        if o.engine == "open3d":  # no tie rule in Open3D (slr_ray.raycast.open3d_scene)
            hits = self._scene.intersect(origin, dirs, tfar=tfar, skip_containing=True, n_threads=o.n_threads)
        else:
            hits = self._scene.intersect(origin, dirs, tfar=tfar, ties=self._ties_at(origin), skip_containing=True,
                                         n_threads=o.n_threads, pulse_aspect=aspect, clip=self._clip)
        return hits.owners, hits.distances

    def _ties_at(self, origin) -> float:
        """The tie window of a cast from ``origin``: ``ties``, and 0 with ``pulse_cells`` at the primary's
        origin (within :data:`PRIMARY_VIEW_TOLERANCE`), where the discs are cut to their pulses: no two
        discs of one surface overlap there, and the first one met is the nearest of a pulse's points."""
        o = self.options
        if o.pulse_cells and float(np.max(np.abs(as_origin(origin) - as_origin(o.primary_origin)))) \
                <= PRIMARY_VIEW_TOLERANCE:
            return 0.0
        return o.ties

    def primary_view(self, origin, pattern) -> bool:
        """Whether a scan from ``origin`` with ``pattern`` is the primary's own view:
        ``primary_image`` on, ``origin`` within :data:`PRIMARY_VIEW_TOLERANCE` of
        ``primary_origin`` and ``pattern`` the primary's pulse grid (range limits aside; a
        uniform grid fitted by ``primary_pattern='fit'``: within what the fit can tell,
        :func:`~.fit.fitted_grid_holds`). Each pulse then returns the primary's own return in it (:meth:`scan`)."""
        o = self.options
        if not o.primary_image or o.primary_origin is None or o.primary_grid is None:
            return False
        po = as_origin(o.primary_origin, "primary_origin")
        if not float(np.max(np.abs(as_origin(origin) - po))) <= PRIMARY_VIEW_TOLERANCE:
            return False
        p, g = as_pattern(pattern), as_pattern(o.primary_grid)
        return same_pulse_grid(p, g) or (self.primary_fit is not None and fitted_grid_holds(p, g))

    def _hits(self, origin, pattern, rays_per_batch=1 << 21):
        """Every ray that hits a disc: (point index, t, v, h) arrays."""
        if self.primary_view(origin, pattern):
            # the primary's own view: the first surface along each of its pulses is the one it
            # recorded, the nearest point in the pulse (binning's image); discs would let a near
            # point's disc take a silhouette pulse whose own return lies behind it
            keys, ranges, idx = pattern.reduce(self.points, origin, self.options.n_threads)
            nh = pattern.shape[1]
            return idx.astype(np.int64), np.asarray(ranges, np.float64), keys // nh, keys % nh
        rmin, rmax = pattern.range_limits
        reach = self._max_radius * self.options.reach
        tfar = min(rmax + 2 * reach, 3e37)
        nv, nh = pattern.shape
        refuse_cast(pattern.n_pulses, "the embree scan")  # before the memory: a fine pattern's row may fit
        # a batch holds whole rows (directions, pulse ids, answers: about 100 B a ray)
        refuse_memory(100.0 * max(nh, min(rays_per_batch, nv * nh)),
                      f"a row of {nh:,} rays ({pattern.n_pulses:.3g} pulses in all)", "choose a coarser pattern")
        aspect = _pulse_aspect(pattern)
        rows_per = max(1, rays_per_batch // nh)
        parts = []
        for r0 in range(0, nv, rows_per):
            dirs, vv, hh = pulse_rays(pattern, slice(r0, min(nv, r0 + rows_per)))
            pt, t = self._cast(origin, dirs, tfar, aspect)
            hit = pt >= 0
            parts.append((pt[hit], t[hit], vv[hit], hh[hit]))
        if not parts:
            return np.empty(0, np.int64), np.empty(0), np.empty(0, np.int64), np.empty(0, np.int64)
        return tuple(np.concatenate([p[j] for p in parts]) for j in range(4))

    def ray_hits(self, origin, pattern):
        """Per-ray answer: for every pulse whose centre ray hits a disc, the point.

        Returns
        -------
        pulses : (k, 2) int64
            ``(v, h)`` of each ray that hit.
        indices : (k,) intp
            The point whose disc it hit (a point may appear for several pulses).
        distances : (k,) float64
            Distance along the ray to the disc.
        """
        pt, t, v, h = self._hits(as_origin(origin), as_pattern(pattern))
        return np.column_stack([v, h]), pt.astype(np.intp), t

    # --- hook for slr_ray.effects (sub-rays of a diverging beam, rays from moving poses) ---------------
    def cast(self, origin, directions, max_range: float = math.inf):
        """First disc met by each ray from ``origin`` along ``directions``.

        The tie rule (``ties``) ranks candidates by their distance from the ray
        (no pulse grid: the rays are anyone's), and discs holding ``origin``
        are skipped, as in :meth:`scan`.

        Parameters
        ----------
        origin : (3,) float
        directions : (m, 3) float
            Unit vectors.
        max_range : float
            Metres; discs beyond are not met.

        Returns
        -------
        indices : (m,) int64
            The point whose disc each ray meets, -1 on a miss.
        distances : (m,) float64
            Distance along the ray to the disc, ``inf`` on a miss.
        """
        if self.options.engine == "open3d":
            raise InputValueError("cast needs engine 'embree' or 'fan' (Open3D's scene has no tie rule)")
        d = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
        pt, t = self._cast(as_origin(origin), d, min(float(max_range), 3e37))
        if self.release_mapped:  # a file-mapped cloud: the pages the tie rule read (scan_and_rays)
            release_pages(self.points)
        return pt, np.where(pt >= 0, t, np.inf)

    def scan(self, origin, pattern, rays_per_batch: int = 1 << 21) -> Scan:
        """Scan the discs from ``origin`` with ``pattern``.

        A point hit by several rays appears once, with the pulse of its
        nearest ray. ``info`` of the result holds ``cast_seconds``, ``rays``
        and ``ray_hits`` (rays that hit a disc) and the options.
        """
        return self.scan_and_rays(origin, pattern, rays_per_batch)[0]

    def scan_and_rays(self, origin, pattern, rays_per_batch: int = 1 << 21):
        """:meth:`scan` and :meth:`ray_hits` from one cast: ``(scan, (pulses, indices, distances))``."""
        pattern = as_pattern(pattern)
        origin = as_origin(origin)
        t_start = time.perf_counter()
        pt, tt, v, h = self._hits(origin, pattern, rays_per_batch)
        cast = time.perf_counter() - t_start
        rays = (np.column_stack([v, h]), pt.astype(np.intp), tt)
        n_ray_hits = len(pt)
        # rays stopped on a disc within two of its radii of the origin: the scanner stands among points
        enclosed = float(np.mean(tt < 2.0 * self.radii[pt])) if n_ray_hits and not self.primary_view(
            origin, pattern) else 0.0
        # points the pattern itself would not see (range limits, field of view) are not returned
        uniq, inverse = np.unique(pt, return_inverse=True)
        keys, _ = pattern.pulse_ids(self.points[uniq], origin)
        nearest = _nearest_ray(inverse, tt, len(uniq))  # per point, its nearest ray (the first of equals)
        seen = keys >= 0
        idx = uniq[seen].astype(np.intp)
        nearest = nearest[seen]
        scan = Scan(indices=idx, ranges=ranges_of(self.points, idx, origin),
                    pulses=np.column_stack([v[nearest], h[nearest]]).astype(np.int64),
                    origin=origin, pattern=pattern, backend=self.backend, n_input=len(self.points),
                    seconds=time.perf_counter() - t_start,
                    info={"cast_seconds": round(cast, 6), "rays": int(pattern.n_pulses),
                          "primary_view": self.primary_view(origin, pattern),
                          **({"primary_pattern_fit": self.primary_fit,
                              "primary_pattern_fit_quality": round(self.primary_fit_quality, 4)}
                             if self.primary_fit else {}),
                          "ray_hits": int(n_ray_hits), "enclosed_share": round(enclosed, 4),
                          **self.options.to_dict()})
        # a file-mapped cloud (a validation's spilled primary): one scan's tie rule and gathers touch
        # nearly every page of it (the hits are spread over the whole cloud); released here, they do
        # not pile up over the positions (a page read again is a minor fault while the file is cached)
        if self.release_mapped:
            release_pages(self.points)
        return scan, rays


@njit(cache=True)
def _nearest_ray(group, t, n_groups):
    """Per group (a point), the index of its ray of least ``t``, the first of equals."""
    best = np.full(n_groups, -1, np.int64)
    for i in range(len(group)):
        g = group[i]
        b = best[g]
        if b < 0 or t[i] < t[b]:
            best[g] = i
    return best


def _grid_geometry(primary_origin, primary_grid, cells: float = CELLS_OFF):
    """The silhouette rule's description of the primary's pulse grid (RayScene.intersect's ``clip``);
    ``cells``: the pulse-cell cut's mode (``pulse_cells``; :data:`slr_ray.raycast.cast.CELLS_OFF`...)."""
    g = as_pattern(primary_grid).aligned()
    nv, nh = g.shape
    po = as_origin(primary_origin, "primary_origin")
    if getattr(g, "has_beams", False):
        edges = np.asarray(g.band_edges, np.float64)
        return (np.array([*po, edges[0], float(np.diff(edges).max()), 2 * math.pi / nh, nv, nh, cells]),
                -np.cos(edges))
    d_theta, d_phi, theta_min, _ = g.radians
    return np.array([*po, theta_min, d_theta, d_phi, nv, nh, cells]), np.zeros(0)


def same_pulse_grid(p, g) -> bool:
    """Whether pattern ``p`` bins directions into the pulses of ``g`` (range limits
    aside; a uniform grid may start its zenith range a whole number of rows later)."""
    if getattr(p, "has_beams", False) or getattr(g, "has_beams", False):
        if not (getattr(p, "has_beams", False) and getattr(g, "has_beams", False)):
            return False
        return (p.elevation_deg, p.columns, p.azimuth_offset_deg) == (g.elevation_deg, g.columns,
                                                                       g.azimuth_offset_deg)
    if (p.azimuth_resolution, p.zenith_resolution) != (g.azimuth_resolution, g.zenith_resolution):
        return False
    rows = (p.zenith_range[0] - g.zenith_range[0]) / g.zenith_resolution
    return rows >= 0 and abs(rows - round(rows)) <= 1e-9 and p.zenith_range[1] <= g.zenith_range[1]


def _pulse_aspect(pattern) -> float:
    """Zenith step over azimuth step of a pattern's pulses, the scale of the
    tie rule's pulse units."""
    d_theta, d_phi = pattern.pulse_steps
    return d_theta / d_phi
