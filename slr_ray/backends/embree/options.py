"""Options of the embree backend (:class:`EmbreeOptions`; the package docstring
describes what each does)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from ...arrays import as_points
from ...errors import InputValueError
from ...pattern import as_pattern
from ..base import BackendOptions

__all__ = ["EmbreeOptions", "RADIUS_MODES", "ORIENTATIONS", "ENGINES", "NEIGHBOURS", "GRID_SPACINGS",
           "DEFAULT_MAX_INCIDENCE", "MAX_RADIUS", "refuse_cast", "FAST_RAYS_PER_SECOND", "MAX_CAST_SECONDS"]

RADIUS_MODES = ("spacing", "footprint")
ORIENTATIONS = ("normal", "billboard", "primary")
ENGINES = ("embree", "fan", "open3d")
NEIGHBOURS = ("knn", "pulse-grid")
GRID_SPACINGS = ("mean", "step")
#: The largest disc radius (metres) and radius scale: beyond, float32 radii overflow and a disc covers
#: any scene.
MAX_RADIUS = 1e6
#: The most neighbours ``k`` a disc's spacing and normal take: far beyond any surface's (6-30 are
#: used), and a bound on the neighbour arrays (a chunk of them is sized to fit memory besides).
MAX_K = 1000
#: A fast machine's cast rate, rays a second: several threads at the ~15 M a second one thread casts
#: (docs/speed.md: 3.1 M rays in 0.21 s): a cast is estimated at this rate, never slower than it is.
FAST_RAYS_PER_SECOND = 1e8
#: A cast estimated longer than this (seconds, at :data:`FAST_RAYS_PER_SECOND`) is refused before it starts.
MAX_CAST_SECONDS = 3600.0


def refuse_cast(n_rays: float, what: str, hint: str = "choose a coarser pattern (--resolution)") -> None:
    """Raise :class:`InputValueError` before a cast of ``n_rays`` that would take more than
    :data:`MAX_CAST_SECONDS` even at :data:`FAST_RAYS_PER_SECOND` (the figure in the message), as
    memory is refused (:func:`slr_ray.errors.refuse_memory`): a 0.00001 deg pattern (6.5e14 rays)
    would run for months."""
    seconds = float(n_rays) / FAST_RAYS_PER_SECOND
    if seconds > MAX_CAST_SECONDS:
        raise InputValueError(f"{what}: {float(n_rays):.3g} rays would take about {seconds / 3600:,.0f} hours "
                              f"even at {FAST_RAYS_PER_SECOND:.0e} rays a second, more than "
                              f"{MAX_CAST_SECONDS / 3600:g} h: {hint}")


#: estimated disc normals are turned to meet the primary's line of sight at no more than this (degrees)
DEFAULT_MAX_INCIDENCE = 80.0


@dataclass(frozen=True)
class EmbreeOptions(BackendOptions):
    """Options of the embree backend (module docstring).

    Attributes
    ----------
    radius : float, (n,) float or {'spacing', 'footprint'}
        Disc radius in metres, or 'spacing' (mean distance to the k nearest
        neighbours) or 'footprint' (the primary pulse's width at the point).
    radius_scale : float
        Multiplies every radius.
    k : int
        Neighbours for ``'spacing'`` radii and for normals (1 to
        :data:`MAX_K`; a cloud of fewer points takes all the others).
    orientation : {'normal', 'billboard', 'primary'}
        Discs along the surface normal, facing each ray, or facing the
        primary scanner.
    engine : {'embree', 'fan', 'open3d'}
        Embree's exact discs, or polygon fans in Embree or Open3D (cross-checks).
    segments : int
        Rim vertices of a disc's polygon (fan engines only; >= 3).
    ties : float, optional
        Tie window in disc radii; 0 turns the tie rule off (so does
        ``pulse_cells`` for a cast from the primary's origin). Default 1, and 3
        when the primary is a beam table (``primary_pattern`` a sensor: real
        frames, whose discs are not coplanar: per-beam range offsets, beams
        not where the table says; a KITTI frame re-scanned with its own
        table, a VLP-16 or 0.4 deg, from its own origin or 1 m aside: 91-98 %
        of binning's points against 89-96 % with 1).
    primary_origin : (3,) float, optional
        The primary scanner (``radius='footprint'``, ``orientation='primary'``,
        and the fallback direction of degenerate normals).
    primary_resolution : float, optional
        Degrees: the primary was scanned with a uniform pattern of this
        resolution (``radius='footprint'``, ``neighbours='pulse-grid'``).
    primary_pattern : str, ScanPattern or BeamPattern, optional
        The primary's own pattern instead of ``primary_resolution`` when it
        is not uniform: a shipped sensor name (a KITTI frame:
        ``velodyne_hdl64e_s2``), a preset, or a pattern object; or ``'fit'``:
        estimated from the cloud seen from ``primary_origin`` when the
        scanner is prepared (a frame stored beam by beam: its fitted
        HDL-64E table; any other cloud: a uniform grid of its angular
        spacing; ``slr_ray.backends.embree.fit``), reported in each scan's
        ``info`` (``primary_pattern``, ``primary_pattern_fit``,
        ``primary_pattern_fit_quality``); refused (InputValueError) where the
        cloud is no scan from there (under 80 % of the fitted grid's occupied
        pulses hold one point: ``fit.FIT_MIN_SINGLE``). The pulse
        grid is then its rows (beams) and columns, and the footprint angle
        the root mean square of its row gap and column step.
    primary_beams : (n,) int, optional
        With ``primary_pattern`` a beam table: the beam (table position) that
        fired each point, -1 where unknown, as a frame's ``ring`` field or
        its scan order records it. The pulse grid then puts each point in its
        beam's row instead of the band its elevation falls in: a real unit's
        beams depart from any table, and a beam's vertical offset moves near
        points' elevation by degrees (KITTI frame: docs/sensors.md "Where the KITTI
        frame's VLP-16 re-scan loses its points").
    normals : (n, 3) float, optional
        Normals to use instead of estimating them (``orientation='normal'``).
    min_radius : float, optional
        Floor of computed radii (default: 0.1 x the median spacing).
    fallback_radius : float
        Radius when the cloud has no spacing (one point, identical points).
    chunk : int
        Points per neighbour query (bounds memory: about 100 bytes a point).
    n_threads : int, optional
        Threads casting rays (default: all cores).
    neighbours : {'knn', 'pulse-grid'}, optional
        Where 'spacing' radii and normals take neighbours from: the k nearest
        (kd-tree), or the 8 adjacent pulses of the primary's own pulse grid
        (needs primary_origin and primary_resolution or primary_pattern; no
        kd-tree). Default: 'pulse-grid' when the primary's origin and pattern
        are given (3.6x faster to prepare on 5 M points, and no holes between
        rings when re-scanned coarser: 100 % of binning's points against 85 %
        with kNN), else 'knn'. How the grid spaces its discs: ``grid_spacing``.
    max_incidence : float, optional
        Degrees. With estimated normals (``orientation='normal'``) and a known
        ``primary_origin``: a disc whose normal makes more than this angle
        with the line of sight to the primary scanner is turned towards the
        scanner until it makes exactly this angle. The primary recorded the
        point, so its pulse met a surface that faced it; a disc edge-on to the
        primary comes from a noisy normal (range noise and beam-to-beam range
        offsets of real sensors, on grazing ground), and a ray passing its
        centre misses it. Default 80 with pulse-grid neighbours and
        ``grid_spacing='mean'`` (a beam-table primary; the KITTI
        re-scans of ``ties``, with ``ties=3``: 91-98 % of binning's points
        against 89-97 % without; the same precision on the synthetic
        scenes with mean-spacing discs), 90 (off) otherwise: kNN normals of noiseless
        ground are exact, and turned they stand up in the way of other
        positions' rays (precision 96.9 -> 76.7 % on bare ground). Normals
        given by the user are never turned. docs/backends.md "Returned points on
        sparse clouds".
    grid_gate : float, optional
        With 'pulse-grid': an adjacent pulse's point is a neighbour only when
        its primary range is within this fraction of the point's (a jump in
        range is an edge, not the same surface). Default: the range step of
        a surface seen at 89 deg incidence, ``tan(89 deg)`` times the
        primary's pulse step, at most 0.1 (0.1 for pulses of 0.1 deg and
        coarser; 0.014 at 0.0144 deg, where 0.1 let discs at object edges take
        neighbours metres behind them and grow to 7 m).
    grid_spacing : {'mean', 'step'}, optional
        With 'pulse-grid' and 'spacing' radii: a point's spacing is the mean
        distance to its neighbours ('mean'), or twice the smaller of its two
        axis steps, the distance to the nearer point of the pulses above and
        below and of those left and right, and at least 1.5 x its range x
        the pattern's coarser angular step ('step': oblong pulses, a forest
        scan's 0.048 x 0.622 deg, are spaced by their long side). On grazing ground the
        range step between rows is long (``R dtheta / cos(incidence)``) and
        the azimuth step short; mean-spacing discs span the long step, and
        a disc's centre then stands in for true points up to a range step
        away (precision at 10 cm against truth on bare ground, 6 positions:
        70 % against kNN's 97 %); step discs are kNN's size there (97 %,
        the same coverage as kNN, 0.3 points below mean-spacing discs).
        Default: 'step', and 'mean' when the primary is a beam table
        (``primary_pattern`` a sensor: its rings are far apart, and mean
        discs close the holes between them). docs/backends.md "Grazing
        ground".
    primary_image : bool
        A scan from ``primary_origin`` (within a micrometre) with the
        primary's own pattern (with ``primary_pattern='fit'``: steps within
        2 % of the fitted ones) returns, pulse for pulse, the primary's own
        return in each pulse (the nearest point in it: binning's image):
        the first surface along a pulse is the one the primary recorded in
        it. Default True; False casts the discs there too (a near point's
        disc then takes silhouette pulses whose own return lies behind it:
        a KITTI frame re-scanned from itself lost 1.3 m of depth RMSE).
    silhouettes : bool
        With pulse-grid neighbours (and no ``primary_beams``): a disc stays,
        as seen from the primary's origin, within the pulses next to its own
        point's (in azimuth, where columns are narrower than a row, within
        as many as a row's height holds), and out of those next to it whose
        own return lies behind the point (the primary saw through there;
        empty pulses do not count: lost pulses, cells narrower than the
        noise near the poles). A disc of two pulses' radius would otherwise
        take the silhouette pulse beyond its neighbour. From the primary's
        origin each pulse then meets its own point's disc first (a step
        edge: no pulse wrong, against 46 of 5,724 without). Tested in
        Embree's filter against each point's silhouette bits (one byte a
        point, from the pulse-grid pass). Default True.
    pulse_cells : bool
        Each disc cut, as seen from the primary's origin, to its own point's
        pulse of the primary (needs ``primary_origin`` and the primary's
        pattern; with or without ``primary_beams``) and grown to hold its
        centre ray (up to 4x its radius; ``discs.pulse_centre_reach``):
        the discs tile the
        primary's pulses, and a ray of the primary's own pattern from its
        origin meets only the discs of its own pulse's points, so that the
        discs alone re-scan the frame they came from (``primary_image=False``;
        docs/backends.md "Discs that are right by themselves"). Further from
        the primary's origin the cut holds as the silhouette rule's does
        (hits at least four times as far from the ray's origin as that lies
        from the primary's, and only beyond the pulse by more than the
        parallax angle: the ray origin's distance from the primary's over
        the hit's distance), on top of ``silhouettes``. Casts from the
        primary's origin take no tie window then (the discs of one surface
        no longer overlap as seen from there, and a window of 3 radii would
        take a farther point of a pulse holding two: KITTI 000000, 0.30 m
        depth RMSE against 0.14 m). Default False (measured: docs/backends.md
        "Why pulse_cells is not the default").
    """

    radius: object = "spacing"
    radius_scale: float = 1.0
    k: int = 6
    orientation: str = "normal"
    engine: str = "embree"
    segments: int = 3
    ties: float | None = None
    primary_origin: object = None
    primary_resolution: float | None = None
    primary_pattern: object = None
    primary_beams: object = None
    normals: object = None
    min_radius: float | None = None
    fallback_radius: float = 0.01
    chunk: int = 1 << 20
    n_threads: int | None = None
    neighbours: str | None = None
    grid_gate: float | None = None
    max_incidence: float | None = None
    grid_spacing: str | None = None
    primary_image: bool = True
    silhouettes: bool = True
    pulse_cells: bool = False

    @classmethod
    def choices(cls) -> dict:
        return {"orientation": ORIENTATIONS, "engine": ENGINES, "neighbours": NEIGHBOURS,
                "grid_spacing": GRID_SPACINGS}

    @property
    def fit_pending(self) -> bool:
        """``primary_pattern='fit'``, not yet fitted (the scanner fits it to its cloud)."""
        return isinstance(self.primary_pattern, str) and self.primary_pattern == "fit"

    def __post_init__(self):
        if self.fit_pending:
            # the defaults that depend on the primary's pattern wait for it: preparing a scanner
            # fits it and checks these options in full with it (dataclasses.replace)
            if self.primary_origin is None:
                raise InputValueError("primary_pattern='fit' needs primary_origin (where the cloud was scanned "
                                      "from)")
            if self.primary_resolution is not None:
                raise InputValueError("give primary_resolution or primary_pattern, not both")
            return
        self._check_own_values()
        if self.ties is None:  # frozen: set through object.__setattr__
            beams = self.primary_pattern is not None and as_pattern(self.primary_pattern).has_beams
            object.__setattr__(self, "ties", 3.0 if beams else 1.0)
        if not (isinstance(self.ties, (int, float)) and math.isfinite(self.ties) and self.ties >= 0):
            raise InputValueError(f"ties must be a finite number >= 0, got {self.ties!r}")
        if self.min_radius is not None and not (math.isfinite(self.min_radius) and self.min_radius > 0):
            raise InputValueError(f"min_radius must be a finite number > 0, got {self.min_radius!r}")
        if self.orientation == "billboard" and self.engine != "embree":
            raise InputValueError("orientation='billboard' needs engine='embree' (ray-facing discs)")
        if self.primary_pattern is not None:
            if self.primary_resolution is not None:
                raise InputValueError("give primary_resolution or primary_pattern, not both")
            as_pattern(self.primary_pattern)  # an unknown name or type fails here, not in prepare
        if self.primary_beams is not None and not getattr(self.primary_grid, "has_beams", False):
            raise InputValueError("primary_beams (each point's beam) needs primary_pattern, the primary's "
                                  "beam table")
        if self.neighbours is None:  # frozen: set through object.__setattr__
            known = self.primary_origin is not None and self.primary_grid is not None
            object.__setattr__(self, "neighbours", "pulse-grid" if known else "knn")
        if self.neighbours not in NEIGHBOURS:
            raise InputValueError(f"neighbours must be one of {NEIGHBOURS}, got {self.neighbours!r}")
        if self.neighbours == "pulse-grid" and (self.primary_origin is None or self.primary_grid is None):
            raise InputValueError("neighbours='pulse-grid' needs primary_origin and primary_resolution "
                                  "(or primary_pattern)")
        if self.grid_spacing is None:  # frozen: set through object.__setattr__
            beams = self.primary_pattern is not None and as_pattern(self.primary_pattern).has_beams
            object.__setattr__(self, "grid_spacing", "mean" if beams else "step")
        if self.grid_spacing not in GRID_SPACINGS:
            raise InputValueError(f"grid_spacing must be one of {GRID_SPACINGS}, got {self.grid_spacing!r}")
        if self.max_incidence is None:  # frozen: set through object.__setattr__
            grid_normals = (self.neighbours == "pulse-grid" and self.orientation == "normal"
                            and self.grid_spacing == "mean")
            object.__setattr__(self, "max_incidence", DEFAULT_MAX_INCIDENCE if grid_normals else 90.0)
        if not (isinstance(self.max_incidence, (int, float)) and 0 < self.max_incidence <= 90):
            raise InputValueError(f"max_incidence must be degrees in (0, 90], got {self.max_incidence!r}")
        if self.max_incidence < 90 and self.primary_origin is None:
            raise InputValueError("max_incidence needs primary_origin (the scanner the discs turn towards)")
        if self.grid_gate is not None and not (isinstance(self.grid_gate, (int, float)) and self.grid_gate > 0):
            raise InputValueError(f"grid_gate must be a number > 0, got {self.grid_gate!r}")
        if self.orientation == "primary" and self.primary_origin is None:
            raise InputValueError("orientation='primary' needs primary_origin")
        if isinstance(self.radius, str) and self.radius == "footprint" and (
                self.primary_origin is None or self.primary_grid is None):
            raise InputValueError("radius='footprint' needs primary_origin and primary_resolution "
                                  "(or primary_pattern)")
        if self.pulse_cells and self.engine == "open3d":
            raise InputValueError("pulse_cells needs engine 'embree' or 'fan' (Open3D's scene has no filter)")
        for name in ("primary_image", "silhouettes", "pulse_cells"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InputValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if int(self.chunk) != self.chunk or self.chunk < 1:
            raise InputValueError(f"chunk must be an integer >= 1, got {self.chunk!r}")

    def _check_own_values(self) -> None:
        """Each field's own value refused where it is no value of it (radius, normals, orientation,
        engine, segments, k, radius_scale, fallback_radius, the largest radius, n_threads)."""
        if isinstance(self.radius, str) and self.radius not in RADIUS_MODES:
            raise InputValueError(f"radius must be a number, an array or one of {RADIUS_MODES}, "
                                  f"got {self.radius!r}")
        if not isinstance(self.radius, str):
            try:
                r = np.asarray(self.radius, dtype=np.float64)
            except (TypeError, ValueError):
                raise InputValueError(f"radius must be a number, an array or one of {RADIUS_MODES}, "
                                      f"got {type(self.radius).__name__}") from None
            if np.asarray(self.radius).dtype.kind == "b":
                raise InputValueError(f"radius must be metres, got a boolean {self.radius!r}")
            if r.ndim > 1:
                raise InputValueError(f"radius must be a number or one number a point, got shape {r.shape}")
            bad = int(np.count_nonzero(~(np.isfinite(r) & (r > 0))))
            if bad:
                raise InputValueError(f"radius must be finite and > 0: {bad} of {r.size} value(s) are not")
        if self.normals is not None:
            nrm = as_points(self.normals, "normals")  # (n, 3), finite
            zero = int(np.count_nonzero(~(np.linalg.norm(nrm.astype(np.float64), axis=1) > 1e-6)))
            if zero:
                raise InputValueError(f"normals: {zero} of {len(nrm)} rows have (near) zero length: a disc needs "
                                      "a direction (its discs would be met by no ray)")
        if self.orientation not in ORIENTATIONS:
            raise InputValueError(f"orientation must be one of {ORIENTATIONS}, got {self.orientation!r}")
        if self.engine not in ENGINES:
            raise InputValueError(f"engine must be one of {ENGINES}, got {self.engine!r}")
        if int(self.segments) != self.segments or self.segments < 3:
            raise InputValueError(f"segments must be an integer >= 3, got {self.segments!r}")
        if int(self.k) != self.k or not 1 <= self.k <= MAX_K:
            raise InputValueError(f"k must be an integer in [1, {MAX_K}] (neighbours of a disc's spacing and "
                                  f"normal), got {self.k!r}")
        for name in ("radius_scale", "fallback_radius"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputValueError(f"{name} must be a finite number > 0, got {v!r}")
        for name in ("radius", "radius_scale", "fallback_radius", "min_radius"):  # Embree holds float32
            v = getattr(self, name)
            if not isinstance(v, str) and v is not None and np.size(v) and np.max(v) > MAX_RADIUS:
                raise InputValueError(f"{name} must be at most {MAX_RADIUS:g} (a disc of {MAX_RADIUS / 1000:g} km "
                                      f"holds a whole scene), got {float(np.max(v))!r}")
        if self.n_threads is not None and not (isinstance(self.n_threads, numbers.Integral)
                                               and not isinstance(self.n_threads, bool) and 1 <= self.n_threads <= 256):
            raise InputValueError(f"n_threads must be an integer in [1, 256] (binning's bound), got {self.n_threads!r}")

    def check_points(self, n: int) -> None:
        """Arrays of one value a point (``radius``, ``normals``) must have ``n`` (``primary_beams``: the
        scanner checks them against its table)."""
        if not isinstance(self.radius, str) and np.ndim(self.radius) == 1 and len(self.radius) != n:
            raise InputValueError(f"radius has {len(self.radius)} values for {n} points (one a point, or one "
                                  "number for all)")
        if self.normals is not None and len(self.normals) != n:
            raise InputValueError(f"normals has {len(self.normals)} rows for {n} points")

    @property
    def primary_grid(self):
        """The primary's pattern: ``primary_pattern`` as a pattern object, or
        ``primary_resolution`` degrees (a float), or None when neither is given."""
        if self.primary_pattern is not None:
            return as_pattern(self.primary_pattern)
        return None if self.primary_resolution is None else float(self.primary_resolution)

    def to_dict(self) -> dict:
        out = super().to_dict()
        if self.primary_pattern is not None and not isinstance(self.primary_pattern, str):
            out["primary_pattern"] = as_pattern(self.primary_pattern).to_dict()
        return out

    @property
    def reach(self) -> float:
        """How far a disc's stand-in reaches, in radii (polygons circumscribe the disc)."""
        return 1.0 if self.engine == "embree" else 1.0 / math.cos(math.pi / self.segments)
