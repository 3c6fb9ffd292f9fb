"""Each source frame's own sensor: its pulse grid, its range image, its discs.

A source frame's pattern is the source sensor's beam table fitted to the frame
where each point's beam is known (a ``ring`` field, or a KITTI ``.bin``'s scan
order: :func:`slr_ray.sensors.fitted_pattern`), else the table as given; the
frame's range image is its nearest point per pulse of that pattern, at its own
origin. From them:

**See-through removal of moving objects** (:class:`SeeThrough`): a point of
frame ``s`` is removed where other frames of ``s``'s neighbourhood (``half``
either side) saw through it: from such a frame ``f``, the point's pulse and
the four pulses beside it all return from more than ``margin`` metres beyond
the point, in ``f``'s own range image; ``votes`` such frames remove it. A
moving object is where the road or a wall was when the other frames passed:
they saw through its place. Needs no labels; a static point is removed where
two frames saw past it (a thin object, a pulse that grazed an edge), which
the five-pulse test and the two votes keep rare
(``benchmarks/sequence_free_space.py``).

**Discs from each source frame's own pulse grid** (:func:`source_discs`,
the ``embree-sources`` estimator): each frame's points get the embree
backend's pulse-grid spacing and normals from *that frame's* grid at *its*
origin (:func:`slr_ray.backends.embree.pulse_grid_spacing_normals`, as the
backend does for its one primary; radii half the backend's,
:data:`SOURCE_RADIUS_SCALE`), in the frame's own axes, then moved into the
world. Each frame is one Embree scene, built once while the frame is held and
cast from every target whose window holds it (:func:`cast_sources`): the first
disc met along a target pulse's centre ray over the window's frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..backends import prepare
from ..backends.embree import disc_radii, pulse_grid_spacing_normals
from ..backends.embree.options import DEFAULT_MAX_INCIDENCE
from ..errors import InputValueError
from ..sensors import fitted_pattern, scan_order_beams
from ..sensors import sensor as shipped_sensor
from .estimators import PulseReturns

__all__ = ["SeeThrough", "known_beams", "ring_beams", "source_sensor_problem", "SourceView", "source_view", "seen_through_votes", "source_discs", "cast_sources",
           "REMOVE_MOVING", "SOURCE_TIES",
           "SOURCE_RADIUS_SCALE"]

#: ``--remove-moving``: labelled moving classes, see-through, both, neither
REMOVE_MOVING = ("labels", "visibility", "both", "none")
#: the tie window of per-source discs (in radii): the embree backend's for a beam-table primary
SOURCE_TIES = 3.0
#: per-source discs' radius: this times the backend's (the mean distance to the pulse-grid
#: neighbours). A frame's discs of the backend's size cover its own gaps; in a union the other
#: frames' discs fill them, and full-size discs of foliage and thin things stand in front of what the
#: target saw through (benchmarks/sequence_sources.py: 0.3, 0.5, 0.7, 1 measured; 0.5 best on both)
SOURCE_RADIUS_SCALE = 0.5


@dataclass(frozen=True)
class SeeThrough:
    """See-through removal (module docstring): ``sensor`` the source frames' own (a shipped name or
    a beam table; fitted to each frame whose beams are known), ``margin`` metres, ``votes`` frames,
    ``half`` frames either side of the point's frame."""

    sensor: object = "velodyne_hdl64e_s2"
    margin: float = 1.0
    votes: int = 2
    half: int = 2

    def __post_init__(self):
        if not (isinstance(self.margin, (int, float)) and math.isfinite(self.margin) and self.margin >= 0):
            raise InputValueError(f"the see-through margin must be metres >= 0, got {self.margin!r}")
        if not (isinstance(self.votes, (int, np.integer)) and self.votes >= 1):
            raise InputValueError(f"the see-through votes must be an integer >= 1, got {self.votes!r}")
        if not (isinstance(self.half, (int, np.integer)) and self.half >= 1):
            raise InputValueError(f"the see-through half width must be an integer >= 1, got {self.half!r}")
        base_pattern(self.sensor)  # an unknown name fails here

    @property
    def key(self) -> tuple:
        """What the removal depends on besides the sensor (a cache key)."""
        return (float(self.margin), int(self.votes), int(self.half))

    def to_dict(self) -> dict:
        name = self.sensor if isinstance(self.sensor, str) else getattr(self.sensor, "name", "a beam table")
        return {"sensor": name, "margin_m": float(self.margin), "votes": int(self.votes), "half": int(self.half)}


def base_pattern(sensor):
    """A shipped sensor by name, or the beam table given."""
    return shipped_sensor(sensor) if isinstance(sensor, str) else sensor


@dataclass
class SourceView:
    """A source frame's own sensor: its pattern, each point's beam (None: not known) and its range
    image (``(rows, cols)``, NaN: no return), at its own origin."""

    pattern: object
    beams: np.ndarray | None
    image: np.ndarray


def ring_beams(ring, base, what: str) -> np.ndarray:
    """A ``ring`` field as beams of ``base``'s table (int64), refused naming ``what`` (the frame or its
    file) where it holds non-integers or beams outside the table (another sensor's frame: --source-sensor)."""
    try:
        base.rows_of_beams(ring)
    except InputValueError as e:
        raise InputValueError(f"{what}: its ring field: {e} (a frame of another sensor? --source-sensor)") from None
    return np.asarray(ring, np.int64)


#: a card whose beams are its elevation bands (``meta["beams_from"]``: fitted from frames without a ring field)
BEAMS_FROM_BANDS = "elevation bands"


def known_beams(points, attributes, base, what: str = "a frame"):
    """Each point's beam in ``base``'s table: a ``ring`` field (checked: :func:`ring_beams`, naming
    ``what``), else the file's scan order
    (:func:`~slr_ray.sensors.scan_order_beams`: the table's rows, given as its ids), else, for a card fitted from frames without rings
    (``meta["beams_from"]`` :data:`BEAMS_FROM_BANDS`: its beams *are* its elevation bands), the band
    each point falls in (-1 outside them); ``None`` where none tells. The beams are ``base``'s ids (table
    positions) whichever gave them: the scan order's rows are taken to ids (``base.beam_of_row``)."""
    ring = attributes.get("ring")
    if ring is not None:
        return ring_beams(ring, base, what)
    order = scan_order_beams(points, base.n_beams)
    if order is not None:  # the file's rows as the table's beam ids, as a ring field gives them
        return np.asarray(base.beam_of_row)[order]
    if getattr(base, "meta", {}).get("beams_from") == BEAMS_FROM_BANDS and len(points):
        bands = base.with_(min_range=None, max_range=None)  # the band by elevation alone, at any range
        keys, _ = bands.pulse_ids(np.asarray(points, np.float64), np.zeros(3))
        rows = np.where(keys >= 0, keys // base.columns, -1)
        return np.where(rows >= 0, np.asarray(base.beam_of_row)[np.maximum(rows, 0)], -1).astype(np.int64)
    return None


def beams_are_rows(points, attributes, base) -> bool:
    """Whether the frame's beams come from its file's scan order (ring 0 the highest, a KITTI ``.bin``'s:
    ``base``'s range-image rows), not a ring field. :func:`known_beams` gives them as the table's ids
    either way (``beam_of_row[row]``): an HDL-64E's, a VLP-16's or a Pandar64's table does not list its
    beams top first, and every frame of a sequence has its beams by the same rule (a mixed sequence's
    lasers, fits and meshes by id)."""
    return attributes.get("ring") is None and scan_order_beams(points, base.n_beams) is not None


def source_sensor_problem(points, attributes, base) -> str | None:
    """Why the frame ``points`` (its ``attributes``) seems not of the sensor ``base`` (None when it
    fits): its beams not known by ``base`` (no ring field, not in its scan order), or a ring field on
    under half its beams. A cheap check of a named source sensor."""
    beams = known_beams(points, attributes, base)
    if beams is None:
        return f"not in {base.name}'s scan order of {base.n_beams} rings and no ring field"
    used = len(np.unique(beams[beams >= 0]))
    if 2 * used < base.n_beams:
        return f"its points lie on {used} of {base.name}'s {base.n_beams} beams"
    return None


def source_view(local, attributes, base, what: str = "a frame") -> SourceView:
    """The view of a frame (``what``, in messages) whose points are ``local`` (its own frame, float64) by
    the beam table ``base``."""
    ring = attributes.get("ring")
    if ring is not None and len(ring) == len(local):
        beams = ring_beams(ring, base, what)
    else:
        beams = scan_order_beams(local, base.n_beams)
        beams = None if beams is None else np.asarray(base.beam_of_row)[beams]  # rows to ids: known_beams'
    pat = fitted_pattern(local, beams, base) if beams is not None else base
    keys, ranges, _ = pat.reduce(local, np.zeros(3))
    img = np.full(pat.n_pulses, np.nan)
    img[np.asarray(keys)] = ranges
    return SourceView(pat, beams, img.reshape(pat.shape))


def seen_through_votes(n: int, local_of, views, margin: float) -> np.ndarray:
    """Per point of ``n``, how many of ``views`` saw through it. ``views``: ``(pose, SourceView)`` of
    the other frames; ``local_of(pose)``: the points in that frame's axes (float64)."""
    votes = np.zeros(n, np.int64)
    for pose, view in views:
        pts = local_of(pose)
        rows, cols = view.pattern.shape
        keys, r = view.pattern.pulse_ids(pts, np.zeros(3))
        free = keys >= 0
        v, h = keys // cols, keys % cols
        for dv, dh in ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)):
            val = view.image[np.clip(v + dv, 0, rows - 1), (h + dh) % cols]
            with np.errstate(invalid="ignore"):
                free &= np.isfinite(val) & (val > r + margin)
        votes += free
    return votes


def source_discs(world, local, view: SourceView, pose, keep=None):
    """An embree scanner of one frame's points (``world``, ``local`` the same in its own axes; ``keep``
    the points kept) with discs from the frame's own pulse grid at its origin (module docstring)."""
    spacing, normals = pulse_grid_spacing_normals(local, np.zeros(3), view.pattern, None, True, True, np.float64,
                                                  max_incidence=DEFAULT_MAX_INCIDENCE, beams=view.beams,
                                                  spacing_kind="mean")
    radii = disc_radii(local, "spacing", spacing=spacing, radius_scale=SOURCE_RADIUS_SCALE)
    R = np.asarray(pose, np.float64)[:3, :3]
    nw = normals @ R.T
    if keep is not None:
        world, radii, nw = world[keep], radii[keep], nw[keep]
    if not len(world):
        return None
    return prepare(world, "embree", radius=radii, normals=nw, ties=SOURCE_TIES)


def cast_sources(scanners, pose, pattern, centres=None) -> PulseReturns:
    """One return per pulse of ``pattern`` at ``pose`` (sensor to world): the first disc met along each
    pulse's centre ray over ``scanners`` (``(scanner, offset)``: a frame's scene and the index of its
    first point in the union's numbering). The return is where the ray meets that disc (in the
    target's frame); ``index`` the disc's point."""
    T = np.asarray(pose, np.float64)
    R, o = T[:3, :3], T[:3, 3]
    dirs, v, h = pattern.rays()
    world_dirs = dirs @ R.T
    rmin, rmax = pattern.range_limits
    best_t = np.full(len(dirs), np.inf)
    best_i = np.full(len(dirs), -1, np.int64)
    for sc, offset in scanners:
        if sc is None:
            continue
        idx, t = sc.cast(o, world_dirs, max_range=rmax)
        better = (idx >= 0) & (t < best_t) & (t >= rmin)
        best_t[better], best_i[better] = t[better], idx[better] + offset
    hit = np.flatnonzero(best_i >= 0)
    keys = v[hit] * pattern.columns + h[hit]
    order = np.argsort(keys, kind="stable")
    hit = hit[order]
    if centres is not None:  # the disc's own point (its centre), in the target's frame
        pts = (centres[best_i[hit]] - o) @ R
        return PulseReturns(keys[order].astype(np.int64), np.linalg.norm(pts, axis=1), pts, best_i[hit])
    return PulseReturns(keys[order].astype(np.int64), best_t[hit], dirs[hit] * best_t[hit, None], best_i[hit])
