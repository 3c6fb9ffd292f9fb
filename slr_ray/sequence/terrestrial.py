"""Which grid a held-out frame is scored on: a spinning unit's beam table, or a terrestrial scanner's own grid.

A held-out frame is scored on its sensor's grid (every method fills it; the target is the frame's
points in its view). Two kinds of sensor (:data:`KINDS`):

``spinning``
    A unit of beams (a Velodyne, Ouster, Hesai... or a card): its beam table fitted to the frame
    (:func:`slr_ray.sensors.fitted_pattern`) where the frame's beams are known (a ``ring`` field,
    the scan order of a KITTI ``.bin``). Named by ``sensor`` (``--source-sensor``).
``terrestrial``
    A terrestrial laser scanner: one uniform angular grid about its origin, fitted to the frame's
    own points (:func:`terrestrial_grid`: the embree backend's primary fit,
    :func:`slr_ray.backends.embree.fit.fit_primary_pattern`, as ``slr-ray scan`` and ``augment``
    fit a primary; its zenith rows cut to those the frame fired), never a spinning unit's table. The frame has no beams: methods that need the
    frames' beam table (``needs_source_sensor``) are refused, and ``rays`` casts the grid's pulse
    centres (:func:`slr_ray.sequence.rays.cast_grid_rays`).

``sensor="auto"`` (:data:`AUTO`; ``sequence evaluate`` without ``--source-sensor``) decides for
each held-out frame (:func:`auto_sensor`): a frame with a ``ring`` field or in the scan order of
:data:`DEFAULT_SPINNING` (KITTI's) is spinning, on that table, as before; a ring-less frame in the scan
order of another shipped sensor (a VLP-16's ``.bin``: 16 rings), or whose points lie on a shipped
sensor's elevation bands (not in scan order), is spinning on that sensor's table; any other frame is
terrestrial. A frame that is neither (no ring, no scan order, no uniform grid holds it as a scan)
is refused, naming ``--source-sensor``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backends.embree.fit import FIT_MIN_SINGLE, fit_primary_pattern, fit_quality
from ..errors import InputValueError
from ..sensors import SENSORS, scan_order_beams
from ..sensors import sensor as shipped_sensor
from .sources import BEAMS_FROM_BANDS, known_beams

__all__ = ["AUTO", "SPINNING", "TERRESTRIAL", "KINDS", "DEFAULT_SPINNING", "ScoringGrid", "sensor_kind", "auto_sensor",
           "terrestrial_grid", "is_terrestrial", "column_phase", "turn"]

#: decide the kind from each held-out frame (``--source-sensor`` not given)
AUTO = "auto"
SPINNING, TERRESTRIAL = "spinning", "terrestrial"
KINDS = (SPINNING, TERRESTRIAL)
#: the spinning unit taken where none is named and a frame is in its scan order (KITTI's)
DEFAULT_SPINNING = "velodyne_hdl64e_s2"


@dataclass(frozen=True)
class ScoringGrid:
    """A held-out frame's scoring grid: its ``kind`` (:data:`KINDS`), the ``pattern`` every method
    fills, the frame's ``beams`` (spinning, where known), the frames' beam table ``base`` (spinning;
    None for a terrestrial scanner) and ``how``, one line saying which grid and why."""

    kind: str
    pattern: object
    beams: np.ndarray | None
    base: object | None
    how: str
    yaw: float = 0.0    # radians: the grid's first column's edge, from the frame's x axis (terrestrial)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "how": self.how, "yaw_deg": float(np.degrees(self.yaw))}

    def turned(self, points) -> np.ndarray:
        """``points`` (the frame's own axes) in the grid's: turned by ``-yaw`` about z (float64)."""
        return turn(points, self.yaw)

    def turned_pose(self, pose) -> np.ndarray:
        """The frame's ``pose`` (its axes to the world) with the grid's axes: ``pose @ Rz(yaw)``."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        out = np.array(pose, np.float64, copy=True)
        out[:3, :2] = np.column_stack([pose[:3, 0] * c + pose[:3, 1] * s, -pose[:3, 0] * s + pose[:3, 1] * c])
        return out


def turn(points, yaw: float) -> np.ndarray:
    """``points`` turned by ``-yaw`` about z (float64; ``yaw`` 0: themselves)."""
    p = np.asarray(points, np.float64)
    if yaw == 0.0:
        return p
    c, s = np.cos(yaw), np.sin(yaw)
    out = p.copy()
    out[:, 0] = p[:, 0] * c + p[:, 1] * s
    out[:, 1] = -p[:, 0] * s + p[:, 1] * c
    return out


def is_terrestrial(sensor) -> bool:
    """Whether ``sensor`` (a held-out evaluation's ``sensor``) asks for the terrestrial grid."""
    return isinstance(sensor, str) and sensor == TERRESTRIAL


def sensor_kind(points, attributes, base, what: str = "a frame") -> str:
    """:data:`SPINNING` where the frame's beams are known in ``base``'s table (a ``ring`` field, its
    scan order), else :data:`TERRESTRIAL` (a ring field outside the table refused naming ``what``)."""
    return SPINNING if known_beams(points, attributes, base, what) is not None else TERRESTRIAL


#: a ring-less frame not in scan order is a shipped sensor's where this share of its points lies within
#: :data:`BAND_TOLERANCE_DEG` (or a quarter of the table's least beam spacing) of one of its beams' elevations
BAND_SHARE = 0.9
#: a frame in the scan order of a shipped table's ring count is that sensor's where its rings' median
#: elevations lie within this of the table's (median over the rings; another unit of the model: tenths)
SCAN_ORDER_TOLERANCE_DEG = 1.0
BAND_TOLERANCE_DEG = 0.1


def auto_sensor(points, attributes, what: str = "a frame"):
    """The shipped sensor's table a frame's beams are known in, for ``sensor="auto"`` (module docstring);
    None: terrestrial. A ``ring`` field or :data:`DEFAULT_SPINNING`'s scan order: that table (a ring
    field outside it refused naming ``what``); else the shipped table of the frame's ring count in whose
    scan order it is, its rings' elevations near the table's (:data:`SCAN_ORDER_TOLERANCE_DEG`; several:
    the nearest); else the table
    on whose elevation bands its points lie (:data:`BAND_SHARE`), marked as giving its beams by its bands
    (``meta["beams_from"]``: :func:`~slr_ray.sequence.sources.known_beams`). Decided by HDL-64E's scan
    order alone, a ring-less VLP-16 drive was terrestrial."""
    default = shipped_sensor(DEFAULT_SPINNING)
    if known_beams(points, attributes, default, what) is not None:
        return default
    p = np.asarray(points, np.float64)
    if len(p) < 2:
        return None
    tables = [shipped_sensor(name) for name in SENSORS]
    u = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    n = int(np.floor((u.max() - u[0]) / (2 * np.pi) + 1e-9)) + 1  # the rings, were it in scan order
    same = [t for t in tables if t.n_beams == n]
    rings = scan_order_beams(p, n) if same else None
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    az = np.arctan2(p[:, 1], p[:, 0])
    if rings is not None:
        cut = np.searchsorted(rings, np.arange(n + 1))
        med = np.array([np.median(el[a:b]) for a, b in zip(cut[:-1], cut[1:])])  # highest first
        cols = _columns(az, rings)
        off = {t.name: float(np.median(np.abs(np.sort(t.elevation_deg)[::-1] - med))) for t in same}
        near = [t for t in same if off[t.name] <= SCAN_ORDER_TOLERANCE_DEG]  # a scan of 38 rows is no Pandar40P
        if near:
            return min(near, key=lambda t: (round(off[t.name], 2), abs(np.log(cols / t.columns))))
    fits = []
    for t in tables:
        e = np.sort(np.asarray(t.elevation_deg, np.float64))
        if len(e) < 2:
            continue
        tol = min(BAND_TOLERANCE_DEG, float(np.min(np.diff(e))) / 4)
        k = np.clip(np.searchsorted(e, el), 1, len(e) - 1)
        near = np.where(np.abs(el - e[k]) < np.abs(el - e[k - 1]), k, k - 1)
        on = np.abs(el - e[near]) <= tol
        share = float(np.mean(on))
        if share >= BAND_SHARE:  # tables of one fan (a VLP-16's, an XT16's): the nearer column count
            fits.append(((-round(share, 2), abs(np.log(_columns(az[on], near[on]) / t.columns))), t))
    if not fits:
        return None
    best = min(fits, key=lambda f: f[0])[1]
    return best.with_(meta={**best.meta, "beams_from": BEAMS_FROM_BANDS})


def _columns(az, rings) -> float:
    """Columns a turn from the median azimuth step between points of one ring next in azimuth."""
    o = np.lexsort((az, rings))
    a, r = az[o], rings[o]
    d = np.diff(a)[(np.diff(r) == 0)]
    d = d[d > 1e-9]
    return float(2 * np.pi / np.median(d)) if len(d) else 1.0


def terrestrial_grid(points, what: str, turn_columns: bool = True) -> tuple:
    """``(pattern, how, yaw)``: the uniform grid fitted to ``points`` (the scanner at the origin, its
    zenith axis the frame's z), a line saying so with the fit's quality (the share of occupied pulses
    holding one point), and where its columns start (radians from the frame's x axis; 0 unless
    ``turn_columns``): a scan exported in world axes (a campaign's LAS) has its columns turned by its
    setup's heading, and a grid whose columns start at 0 would split them
    (:func:`column_phase`). Refused, naming ``what`` and ``--source-sensor``, where the points show
    no grid or the fitted one holds them as no scan would (under
    :data:`~slr_ray.backends.embree.fit.FIT_MIN_SINGLE`)."""
    p = np.asarray(points, np.float64)
    why, yaw = None, 0.0
    try:
        pattern, _, quality = fit_primary_pattern(p, np.zeros(3), min_quality=0.0)
    except InputValueError:
        why = "its points show no grid of rows and columns about its origin"
    else:
        if getattr(pattern, "has_beams", False):  # in the fit's beam-table scan order: a spinning unit's
            why = "it is stored ring after ring as a spinning unit's frame"
        elif turn_columns:
            yaw = column_phase(p, pattern)
            quality = fit_quality(turn(p, yaw), pattern)
        if why is None and not quality >= FIT_MIN_SINGLE:
            why = (f"the uniform grid fitted to it holds one point in {quality:.0%} of its occupied pulses "
                   f"(a scan's: {FIT_MIN_SINGLE:.0%} or more)")
    if why is not None:
        raise InputValueError(f"{what}: not a terrestrial scan ({why}) and no spinning unit's beams known (no ring "
                              "field, not in a shipped table's scan order): name the frames' sensor "
                              "(--source-sensor NAME or card.json)")
    pattern = _zenith_extent(pattern, turn(p, yaw))
    how = (f"terrestrial: a uniform grid fitted to the frame, {pattern.zenith_resolution:.5g} deg (zenith) x "
           f"{pattern.azimuth_resolution:.5g} deg (azimuth), zenith {pattern.zenith_range[0]:.4g} to {pattern.zenith_range[1]:.4g} deg; one "
           f"point in {quality:.1%} of its occupied pulses" + (f"; its columns from {np.degrees(yaw):.4g} deg azimuth"
                                                            if yaw else ""))
    return pattern, how, yaw


def column_phase(points, pattern) -> float:
    """Where the columns of ``pattern``'s azimuth step start (radians, within a column of 0), from
    ``points``: a scan's points sit mid-column, so the circular mean of their azimuth modulo a
    column, less half a column, is the columns' start."""
    p = np.asarray(points, np.float64)
    step = 2 * np.pi / pattern.shape[1]
    ang = np.arctan2(p[:, 1], p[:, 0]) * (2 * np.pi / step)
    keep = np.hypot(p[:, 0], p[:, 1]) > 0
    if not keep.any():
        return 0.0
    phase = np.arctan2(np.mean(np.sin(ang[keep])), np.mean(np.cos(ang[keep]))) / (2 * np.pi) * step
    yaw = float(np.mod(phase - step / 2, step))
    yaw = yaw - step if yaw > step / 2 else yaw  # within half a column of 0
    return 0.0 if abs(yaw) < 1e-4 * step else yaw


def _zenith_extent(pattern, points):
    """``pattern`` (a uniform grid fitted to ``points``) cut to the zenith rows the scan fired: from its
    highest row that holds a point to its lowest, whole rows (the grid's rows unmoved). A scanner fires
    no pulse above its field of view (30 deg from the zenith, say): a grid from the zenith would score
    the other setups' points there as returns the frame dropped."""
    keys, _ = pattern.pulse_ids(points, np.zeros(3))
    rows = keys[keys >= 0] // pattern.shape[1]
    if not len(rows):
        return pattern
    lo, hi = pattern.zenith_range
    step = pattern.zenith_resolution
    return pattern.with_(zenith_range=(lo + int(rows.min()) * step, min(hi, lo + (int(rows.max()) + 1) * step)),
                         name="fitted to the frame")
