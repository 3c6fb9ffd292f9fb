"""Sensor cards fitted from frames: a spinning unit's beam table measured from what it recorded.

:func:`fit_card` takes one or more frames of one spinning unit, each in the
sensor's own axes (origin at the sensor), and returns a
:class:`~slr_ray.sensors.BeamPattern` whose ``meta`` holds the rest of the
card; :func:`~slr_ray.sensors.write_card` writes it as plain JSON and
:func:`~slr_ray.sensors.sensor` (``sensor("card.json")``, ``--sensor
card.json``) reads it back.

Each beam is the line ``z = z0 + rho tan(e)`` (``rho`` the horizontal
distance): ``e`` its elevation and ``z0`` where its ray crosses the spin axis
(a Velodyne's vertical offset, an Ouster's beam-origin offset), as
:mod:`slr_ray.sequence.rays` models a laser (its line fit is used here).
Which point belongs to which beam comes from

- the frame's ring field (``ring``, ``laser_number``, ``channel``,
  ``laser_id``), or a KITTI ``.bin`` in scan order; the beams are the rings
  seen, in ring order (``meta["ring"]``: each beam's ring number);
- otherwise from the points: every point votes, for each height ``z0`` on a
  grid, for the elevation ``atan(z/rho - z0/rho)``; a beam is a peak of the
  votes (at the height where its points agree best), points go to the beam
  whose line passes nearest, and the lines are fitted again. Beams at one
  elevation (some units fire two at one angle, apart in azimuth) are one
  beam of the card; a beam that returned nothing in any frame is not in it.

Then each beam's azimuth offset (where within a column it fires), the
columns per turn (the median azimuth step between a beam's neighbouring
points), the ranges seen (``min_range``, ``max_range``) and each beam's drop
rate (the share of its pulses, frames x columns, with no point).

Fit quality, in ``meta["fit"]``: the median angle of the points off their
beam's line and the share of points assigned (within their beam's band: half
the gap to the next beam); ``split_beams``, the beams that look like one beam
seen twice (a gap under a quarter of both gaps beside it: warned). Without a
ring field, a frame whose points do not all leave one origin (a moving unit's
frame deskewed, several sweeps merged: BALM's OS0-64-like frames) puts one
beam's points at two elevations that depend on range and azimuth, and the
votes find it twice (109 beams for 64 rings there): the warning says so.
A frame that is not a spinning unit's is refused
(:class:`~slr_ray.errors.InputValueError`, saying why): under half the turn
of azimuth seen, no beams, more than :data:`MAX_BEAMS` of them, or points
that do not lie on beams (under :data:`MIN_ASSIGNED` assigned, or a median
angle off their beams over :data:`MAX_RESIDUAL_DEG`).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from . import lazy
from .errors import InputValueError, SlrWarning
from .io import PointCloud, read_cloud
from .sensors import BeamPattern, scan_order_beams
from .sequence.rays import beam_lines

#: scipy.ndimage and scipy.signal, loaded on first use (slr_ray.lazy: the command line starts without them)
scipy_ndimage, scipy_signal = lazy.module("scipy.ndimage"), lazy.module("scipy.signal")

__all__ = ["fit_card", "RING_FIELDS", "MAX_BEAMS", "MIN_ASSIGNED", "MAX_RESIDUAL_DEG", "MAX_FOREIGN_SHARE",
           "MAX_RING_SHIFT_DEG", "merge_split_beams"]

#: the attributes that record each point's beam, first found used
RING_FIELDS = ("ring", "laser_number", "channel", "laser_id")
#: more beams than this is not a spinning multi-beam unit (a terrestrial scanner's rows)
MAX_BEAMS = 256
#: a spinning unit's frame has at least this share of its points on its beams
MIN_ASSIGNED = 0.8
#: ... and their median angle off their beam's line under this (degrees)
MAX_RESIDUAL_DEG = 0.1
#: the votes' elevation bins (degrees) and the heights tried (m)
_BIN_DEG = 0.01
_HEIGHTS = sorted(np.round(np.arange(-0.1, 0.1001, 0.005), 4), key=abs)  # 0 first: ties keep the least
#: points nearer the spin axis than this (m) are not used (their elevation says little)
_MIN_RHO = 0.05


def _frames(frames, input_format=None):
    """Each frame as ``(points, rings or None, label)``."""
    if isinstance(frames, (str, Path, PointCloud, np.ndarray)):
        frames = [frames]
    out = []
    for i, f in enumerate(frames):
        label = str(f) if isinstance(f, (str, Path)) else f"frame {i}"
        cloud = read_cloud(f, input_format, allow_empty=False) if isinstance(f, (str, Path)) else f
        if isinstance(cloud, PointCloud):
            pts, attrs = np.asarray(cloud.points, np.float64), cloud.attributes
            if cloud.origin is not None and np.any(np.asarray(cloud.origin) != 0):
                pts = pts - np.asarray(cloud.origin, np.float64)  # the sensor's axes: its origin at 0
        else:
            pts, attrs = np.asarray(cloud, np.float64), {}
            if pts.ndim != 2 or pts.shape[1] != 3:
                raise InputValueError(f"{label}: points must be (n, 3), got shape {pts.shape}")
        field = next((k for k in RING_FIELDS if k in attrs), None)
        rings = np.asarray(attrs[field]) if field else None
        if rings is not None and (rings.dtype.kind not in "iu" and not np.all(rings == np.round(rings))):
            raise InputValueError(f"{label}: its {field} field is not integers: not a ring")
        out.append((pts, None if rings is None else rings.astype(np.int64), label, field))
    if not out:
        raise InputValueError("fit_card needs one frame or more")
    return out


def _not_spinning(labels, why: str):
    raise InputValueError(f"{', '.join(labels[:3])}{' ...' if len(labels) > 3 else ''}: not a spinning "
                          f"multi-beam unit's frame in its own axes ({why}); no card fitted")


def _vote_beams(u, t):
    """Beams from points alone: ``(elevation deg, height m)`` of each peak of the points' elevations
    ``atan(z/rho - h/rho)``, ``h`` the one height of the grid that makes them sharpest (a frame's
    origin above or below the beams' crossing: an Ouster's 36 mm); each beam's own height is fitted after."""
    lo = math.degrees(math.atan(t.min())) - 1.0
    hi = math.degrees(math.atan(t.max())) + 1.0
    nb = int((hi - lo) / _BIN_DEG) + 1

    def votes_of(t, u, h):
        e = np.degrees(np.arctan(t - h * u))
        return np.bincount(np.clip(((e - lo) / _BIN_DEG).astype(np.int64), 0, nb - 1), minlength=nb).astype(float)

    def votes(h):
        return votes_of(t, u, h)

    far = u < 0.5  # beyond 2 m: a floor near the unit would collapse to one elevation at its own height
    sharp = [float(np.square(votes_of(t[far], u[far], h)).sum()) for h in _HEIGHTS] if far.sum() >= 1000 else [0]
    best = int(np.argmax(sharp))
    h = _HEIGHTS[best] if sharp[best] > 1.1 * sharp[0] else 0.0  # ties, and a gain under 10 %: 0
    g = scipy_ndimage.gaussian_filter1d(votes(h), 1.0)
    peaks, _ = scipy_signal.find_peaks(g, prominence=3.0, distance=max(1, int(0.06 / _BIN_DEG)))
    return lo + (peaks + 0.5) * _BIN_DEG, np.full(len(peaks), h)


def _split_beams(el) -> int:
    """Beams that look like one beam seen twice: a gap to the next beam under a quarter of both gaps
    beside it (non-uniform units space their beams smoothly: a fine band has fine gaps both sides)."""
    g = np.diff(np.sort(np.asarray(el, np.float64)))
    if len(g) < 3:
        return 0
    inner = g[1:-1]
    return int(np.sum((inner < 0.25 * g[:-2]) & (inner < 0.25 * g[2:])))


def _warn_split(el, labels) -> int:
    """:func:`_split_beams` of ``el``, warned where there are any."""
    split = _split_beams(el)
    if split:
        warnings.warn(f"{', '.join(labels[:2])}{' ...' if len(labels) > 2 else ''}: {split} of the {len(el)} beams "
                      "fitted lie under a quarter of the gaps beside them from the next: one beam seen twice? "
                      "(frames not in the sensor's own axes, several sweeps merged, or a moving unit's frame): "
                      "check the card (its fit quality: split_beams)", SlrWarning, stacklevel=3)
    return split


def merge_split_beams(card: BeamPattern, max_gap_deg: float) -> BeamPattern:
    """``card`` (fitted without rings) with its split beams merged: the two beams closest in elevation,
    while under ``max_gap_deg`` apart, become one, repeatedly (a deskewed frame's beam seen at two
    elevations: BALM's OS0-64-like frames, 109 beams, merge at 0.45 deg into the unit's 64). A merged
    beam's elevation and height are its two's weighted by their points, its azimuth offset their
    weighted circular mean within a column, its drop rate what neither returned (``d1 + d2 - 1``, at
    least 0: the halves' pulses apart), its points their sum. ``meta["fit"]["merged"]`` says what was
    merged. Refused (ValueError naming the argument): a card whose beams are rings, a bound that is not
    a positive number, or one at half the merged beams' median gap or over (it would merge a unit's own
    neighbouring beams)."""
    if not (isinstance(max_gap_deg, (int, float)) and not isinstance(max_gap_deg, bool) and max_gap_deg > 0):
        raise InputValueError(f"max_gap_deg must be a number of degrees > 0, got {max_gap_deg!r}")
    meta = dict(card.meta)
    if "ring" in meta or meta.get("beams_from") != "elevation bands":  # fit_card's mark of a card without rings
        raise InputValueError(f"card {card.name!r}: its beams are the frames' rings, not voted from the points: "
                              "none is split (merge_split_beams, --merge-split-beams)")
    n = card.n_beams
    order = np.argsort(card.elevation_deg)

    def col(key, default):
        v = meta.get(key)
        return list(np.asarray(v if v is not None else [default] * n, float)[order])

    el, w, h = list(np.asarray(card.elevation_deg, float)[order]), col("points", 1.0), col("height_m", 0.0)
    d = col("drop_rate", 0.0)
    step = 360.0 / card.columns
    ph = list(np.exp(2j * np.pi * np.asarray(card.azimuth_offset_deg, float)[order] / step))
    while len(el) > 1:
        g = np.diff(el)
        i = int(np.argmin(g))
        if g[i] >= max_gap_deg:
            break
        a, b = w[i], w[i + 1]
        el[i:i + 2] = [(el[i] * a + el[i + 1] * b) / (a + b)]
        h[i:i + 2] = [(h[i] * a + h[i + 1] * b) / (a + b)]
        ph[i:i + 2] = [(ph[i] * a + ph[i + 1] * b) / (a + b)]
        d[i:i + 2] = [max(0.0, d[i] + d[i + 1] - 1.0)]
        w[i:i + 2] = [a + b]
    gaps = np.diff(el)
    if len(gaps) and max_gap_deg >= 0.5 * float(np.median(gaps)):
        raise InputValueError(f"max_gap_deg {max_gap_deg:g}: at half the merged beams' median gap "
                              f"({float(np.median(gaps)):.3g} deg) or over: it merges the unit's own neighbouring "
                              "beams, not one beam seen twice (--merge-split-beams)")
    off = np.angle(np.asarray(ph)) * step / (2 * np.pi)
    fit = dict(meta.get("fit", {}))
    fit["merged"] = {"max_gap_deg": max_gap_deg, "beams_before": n, "beams_merged": n - len(el)}
    fit["split_beams"] = _split_beams(el)
    meta |= {"height_m": [round(float(x), 5) + 0.0 for x in h], "drop_rate": [round(float(x), 5) + 0.0 for x in d],
             "points": [int(x) for x in w], "fit": fit}
    return BeamPattern(tuple(round(float(e), 5) + 0.0 for e in el), card.columns, tuple((np.round(off, 5) + 0.0).tolist()),
                       min_range=card.min_range, max_range=card.max_range, name=card.name, meta=meta)


def _apparent(el_deg, z0, rho):
    """The elevation, seen from the origin, of beams ``(el_deg, z0)`` at horizontal distance ``rho``."""
    return np.degrees(np.arctan(np.tan(np.radians(el_deg)) + z0 / rho))


def _assign(el, z0, u, t):
    """Each point's nearest beam line (index into ``el``) and its angle off it (degrees)."""
    order = np.argsort(el)
    el, z0 = el[order], z0[order]
    app = np.degrees(np.arctan(t))
    # the beams' apparent elevations at each point's range are in the order of their elevations nearly
    # always; the nearest by elevation and its two neighbours are compared exactly
    j = np.clip(np.searchsorted(el, app), 0, len(el) - 1)
    cand = np.stack([np.clip(j + k, 0, len(el) - 1) for k in (-2, -1, 0, 1)], axis=1)
    rho = 1.0 / u
    off = np.abs(_apparent(el[cand], z0[cand], rho[:, None]) - app[:, None])
    k = np.argmin(off, axis=1)
    return order[cand[np.arange(len(u)), k]], off[np.arange(len(u)), k]


def fit_card(frames, ring: str | bool = "auto", name: str | None = None, source: str | None = None,
             input_format: str | None = None, allow_mixed: bool = False) -> BeamPattern:
    """A spinning unit's card from ``frames`` (module docstring).

    Parameters
    ----------
    frames : path, PointCloud, (n, 3) array, or a list of them
        Frames of one unit, each in the sensor's axes (a file's recorded origin is subtracted).
    ring : 'auto', True or False
        'auto': a ring field where every frame has one (or every frame is a KITTI ``.bin`` in scan
        order), else from the points; True: a ring field required; False: from the points only.
    name, source : str, optional
        The card's name (default ``"fitted"``) and where its frames came from (default: their paths).
    input_format : str, optional
        Files' format, overriding their extension (``".pcd.bin"``).
    allow_mixed : bool
        Fit frames that look like two units' anyway. Default False: refused
        (:data:`MAX_FOREIGN_SHARE`, :data:`MAX_RING_SHIFT_DEG`), naming two frames that disagree.

    Returns
    -------
    BeamPattern
        ``meta``: ``height_m``, ``drop_rate``, ``points`` (each beam's), ``ring`` (each beam's ring
        number, where rings were read), ``fit`` (quality and how), ``source``.
    """
    if ring not in ("auto", True, False):
        raise InputValueError(f"ring must be 'auto', True or False, got {ring!r}")
    fr = _frames(frames, input_format)
    labels = [f[2] for f in fr]
    fr, use_rings = _rings(fr, ring)
    P = np.concatenate([f[0] for f in fr])
    fid = np.concatenate([np.full(len(f[0]), i) for i, f in enumerate(fr)])
    ok, r, az, seen = _spinning(P, labels)
    rho = np.hypot(P[:, 0], P[:, 1])
    u, t = 1.0 / rho[ok], P[ok, 2] / rho[ok]
    R, el0, z00, how, rings_seen = _first_beams(fr, ok, u, t, use_rings, labels)
    el, z0, R = _beam_lines(P[ok], R, el0, z00, u, t, use_rings)
    n = len(el0)
    off = np.abs(_apparent(el[R], z0[R], 1.0 / u) - np.degrees(np.arctan(t)))
    counts = np.bincount(R, minlength=n)
    keep = counts > 0
    if not keep.all():  # a beam no point went to (votes only): not in the card
        remap = np.cumsum(keep) - 1
        el, z0, el0, counts, R = el[keep], z0[keep], el0[keep], counts[keep], remap[R]
        n = len(el)
    el = _parted(np.round(el, 5))
    assigned = off <= 0.5 * _band_gaps(el)[R]  # within its beam's band
    share = float(assigned.mean())
    resid = float(np.median(off))
    if not allow_mixed:  # before the quality check: two units' rings fit no line, and this says why
        _refuse_mixed(fr, fid[ok], R, n, t, use_rings)
    if (share < MIN_ASSIGNED and not use_rings) or resid > MAX_RESIDUAL_DEG:  # rings say where points go
        _not_spinning(labels, f"{share:.0%} of the points on {n} beams, median {resid:.3f} deg off them; a "
                              f"spinning unit's: over {MIN_ASSIGNED:.0%}, under {MAX_RESIDUAL_DEG} deg")
    columns, offsets, drop = _columns(az[ok], fid[ok], R, assigned, n, len(fr), labels)
    rr = r[ok]
    split = _warn_split(el, labels)
    meta = {"source": source or "fitted by slr_ray.sensorfit.fit_card from " + ", ".join(labels),
            "height_m": [round(float(x), 5) + 0.0 for x in z0],  # + 0.0: no -0.0
            "drop_rate": [round(float(x), 5) + 0.0 for x in drop],
            "points": [int(x) for x in counts],
            "fit": {"how": how, "frames": len(fr), "points": int(ok.sum()),
                    "median_off_beam_deg": round(resid, 5), "share_assigned": round(share, 5),
                    "azimuth_seen": round(seen, 4), "split_beams": split,
                    "columns_from": "median azimuth step of a beam's points",
                    "ranges": "the ranges seen (override with min_range / max_range, --min-range / --max-range)"}}
    if not use_rings:  # its beams are elevation bands: frames without rings take their beams from them
        meta["beams_from"] = "elevation bands"
    if use_rings:
        meta["ring"] = [int(x) for x in rings_seen[keep]] if not keep.all() else [int(x) for x in rings_seen]
    return BeamPattern(tuple((el + 0.0).tolist()), columns, tuple((np.round(offsets, 5) + 0.0).tolist()),
                       min_range=round(float(rr.min()), 3), max_range=round(float(rr.max()), 3),
                       name=name or "fitted", meta=meta)


#: frames of one unit: at most this share of a frame's points lies on beams another frame hardly uses
#: (under :data:`_HARDLY` of its even share a beam); two units' frames put far more there
MAX_FOREIGN_SHARE = 0.1
_HARDLY = 0.02
#: ... and each beam's median elevation in two frames within this (degrees, median over the beams)
MAX_RING_SHIFT_DEG = 0.1


def _foreign_shares(fid, R, n, n_frames) -> np.ndarray:
    """``[i, j]``: the share of frame ``i``'s points on beams frame ``j`` hardly uses."""
    counts = np.bincount(np.asarray(fid, np.int64) * n + R, minlength=n_frames * n).reshape(n_frames, n).astype(float)
    total = counts.sum(axis=1, keepdims=True)
    hardly = counts < _HARDLY * np.maximum(total, 1) / n  # [j, beam]
    return (counts @ hardly.T.astype(float)) / np.maximum(total, 1)


def _refuse_mixed(fr, fid, R, n, t, use_rings) -> None:
    """Refuse frames of two units (one line naming two that disagree): a frame with over
    :data:`MAX_FOREIGN_SHARE` of its points on beams (rings, or beams voted from the points) another frame
    hardly uses (a 128-ring unit's frame beside a 64-ring one's), or rings whose elevations in two frames
    differ by over :data:`MAX_RING_SHIFT_DEG` (median over the rings both use: two units of one ring count)."""
    if len(fr) < 2:
        return
    shares = _foreign_shares(fid, R, n, len(fr))
    i, j = np.unravel_index(int(np.argmax(shares)), shares.shape)
    if shares[i, j] > MAX_FOREIGN_SHARE:
        raise InputValueError(f"{fr[i][2]} and {fr[j][2]}: {shares[i, j]:.0%} of the first's points lie on beams the "
                              f"second hardly returns from ({n} beams fitted from both): frames of two units, not "
                              "fitted as one card (--allow-mixed-frames to fit them anyway)")
    if not use_rings:  # voted beams: each point went to the nearest beam, so their elevations agree by construction
        return
    key = np.asarray(fid, np.int64) * n + R  # each frame's beam: its points' median elevation, one sort
    order = np.argsort(key, kind="stable")
    groups, starts = np.unique(key[order], return_index=True)
    el = np.degrees(np.arctan(t))[order]
    med = np.full(len(fr) * n, np.nan)
    med[groups] = [np.median(part) for part in np.split(el, starts[1:])]
    med = med.reshape(len(fr), n)
    for a in range(len(fr)):
        for b in range(a + 1, len(fr)):
            both = np.isfinite(med[a]) & np.isfinite(med[b])
            shift = float(np.median(np.abs(med[a, both] - med[b, both]))) if both.any() else 0.0
            if shift > MAX_RING_SHIFT_DEG:
                raise InputValueError(f"{fr[a][2]} and {fr[b][2]}: their beams' elevations differ by {shift:.3g} deg "
                                      f"(median over {int(both.sum())} beams): frames of two units, not fitted as one "
                                      "card (--allow-mixed-frames to fit them anyway)")


def _rings(fr, ring) -> tuple[list, bool]:
    """The frames, KITTI ``.bin`` frames given their scan order's rings where none records a ring
    field (and ``ring`` allows rings), and whether the fit takes rings."""
    if ring is not False and all(f[1] is None for f in fr):
        orders = [scan_order_beams(f[0], 64) if str(f[2]).lower().endswith(".bin") else None for f in fr]
        if all(o is not None for o in orders):
            fr = [(f[0], o, f[2], "scan order") for f, o in zip(fr, orders)]
    has = [f[1] is not None for f in fr]
    if ring is True and not all(has):
        raise InputValueError(f"ring=True: {[f[2] for f in fr if f[1] is None][:3]} record no ring "
                              f"({', '.join(RING_FIELDS)}) and are not KITTI frames in scan order")
    return fr, ring is not False and all(has)


def _spinning(P, labels):
    """The points a spinning unit's fit takes (``ok``), their ranges, azimuths and the share of the
    turn of azimuth seen; refused (:func:`_not_spinning`) where they are not a spinning unit's."""
    rho = np.hypot(P[:, 0], P[:, 1])
    ok = np.isfinite(P).all(axis=1) & (rho > _MIN_RHO)
    if ok.sum() < 100:
        _not_spinning(labels, f"{int(ok.sum())} points beyond {_MIN_RHO} m of the spin axis")
    r = np.linalg.norm(P, axis=1)
    if np.median(r[ok]) > 1000:
        _not_spinning(labels, f"median range {np.median(r[ok]):.0f} m: georeferenced coordinates, not the "
                              "sensor's own axes")
    az = np.arctan2(P[:, 1], P[:, 0])
    seen = len(np.unique(np.floor(np.degrees(az[ok])).astype(int))) / 360
    if seen < 0.5:
        _not_spinning(labels, f"{seen:.0%} of the turn of azimuth seen; a spinning unit sees most of it "
                              "(a solid-state or forward-looking unit?)")
    return ok, r, az, seen


def _first_beams(fr, ok, u, t, use_rings, labels):
    """Each point's beam and the beams' first elevations and heights: from the rings, or voted from
    the points' elevations. Returns (beams, elevations, heights, how, the ring numbers or None)."""
    if use_rings:
        R_all = np.concatenate([f[1] for f in fr])
        rings_seen, R = np.unique(R_all[ok], return_inverse=True)
        if len(rings_seen) > MAX_BEAMS:
            _not_spinning(labels, f"{len(rings_seen)} ring values")
        el0 = np.array([np.median(np.degrees(np.arctan(t[R == b]))) for b in range(len(rings_seen))])
        return R, el0, np.zeros(len(el0)), f"beams from the frames' {fr[0][3]} field", rings_seen
    el0, z00 = _vote_beams(u, t)
    if len(el0) < 2 or len(el0) > MAX_BEAMS:
        _not_spinning(labels, f"{len(el0)} beams found in the points' elevations")
    R, _ = _assign(el0, z00, u, t)
    return R, el0, z00, "beams from the points' elevations (no ring field)", None


def _beam_lines(Pk, R, el0, z00, u, t, use_rings):
    """The beams' lines: ``slr_ray.sequence.rays``' fit (points beyond 2 m), else the starting
    estimate, whichever fits a beam's points best; without rings the points are assigned again.
    Returns (elevations, heights, beams)."""
    n = len(el0)
    app = np.degrees(np.arctan(t))
    el, z0 = el0.copy(), z00.copy()
    for _ in range(1 if use_rings else 2):
        z1, e1, _ = beam_lines(Pk, R, n)
        e1 = np.degrees(e1)
        for b in range(n):  # the line, or the median elevation at the height so far: the one that fits best
            mine = R == b
            if not mine.any():
                continue
            cands = [(el[b], z0[b]), (float(np.median(np.degrees(np.arctan(t[mine] - z0[b] * u[mine])))), z0[b])]
            if np.isfinite(e1[b]):
                cands.append((e1[b], z1[b]))
            el[b], z0[b] = min(cands, key=lambda c: np.median(np.abs(_apparent(c[0], c[1], 1.0 / u[mine]) -
                                                                       app[mine])))
        if not use_rings:
            R, _ = _assign(el, z0, u, t)
    return el, z0, R


def _parted(el):
    """Two beams at one elevation parted by 1e-5 degree."""
    n = len(el)
    while len(np.unique(el)) != n:
        _, first = np.unique(el, return_index=True)
        el[np.setdiff1d(np.arange(n), first)] += 1e-5
    return el


def _band_gaps(el):
    """Each beam's gap to its nearest neighbour in elevation (inf for a lone beam)."""
    n = len(el)
    gap = np.full(n, np.inf)
    if n > 1:
        srt = np.sort(el)
        pos = np.searchsorted(srt, el)
        left = np.where(pos > 0, el - srt[np.maximum(pos - 1, 0)], np.inf)
        right = np.where(pos < n - 1, srt[np.minimum(pos + 1, n - 1)] - el, np.inf)
        gap = np.minimum(left, right)
    return gap


def _columns(A, F, R, assigned, n, n_frames, labels):
    """The columns (the median azimuth step between a beam's neighbouring points, frame by frame),
    each beam's azimuth offset (deg: where within a column it fires; a column's centre is offset +
    (h + 1/2) step) and drop rate. ``A``, ``F``: the points' azimuths and frames."""
    steps = []
    for i in range(n_frames):
        for b in range(n):
            a = np.sort(A[(F == i) & (R == b) & assigned])
            d = np.diff(a)
            d = d[d > 1e-7]
            if len(d) >= 10:
                steps.append(np.median(d))
    if not steps:
        _not_spinning(labels, "no beam has ten points in a row")
    columns = int(round(2 * math.pi / np.median(steps)))
    step = 2 * math.pi / columns
    ph = np.exp(1j * (2 * math.pi / step) * (A - 0.5 * step))
    offsets = np.array([np.angle(ph[(R == b) & assigned].mean()) if np.any((R == b) & assigned) else 0.0
                        for b in range(n)]) * step / (2 * math.pi)
    offsets = np.degrees(offsets)
    col = np.floor(((A - np.radians(offsets)[R]) % (2 * math.pi)) / step).astype(np.int64)
    occupied = np.array([len(np.unique(F[R == b] * columns + col[R == b])) for b in range(n)])
    return columns, offsets, 1.0 - occupied / (n_frames * columns)
