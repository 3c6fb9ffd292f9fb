"""A simulated scan with sensor effects: :func:`simulate` and its result :class:`EffectScan`.

The effects are resolved once (:meth:`~slr_ray.effects.Effects.resolve`), and
every one is a stage of :data:`~slr_ray.effects.stages.STAGES`, run in this
order where it is on:

1. what is cast (:meth:`~slr_ray.effects.stages.Stage.rays`): beam divergence's
   sub-rays of each pulse's cone (:mod:`.returns`), motion's pose for each
   sector of columns (:mod:`.motion`);
2. the geometry this module makes: the ideal scan (``scanner.scan``) where
   nothing is asked, or the rays cast (by a scanner that casts rays; motion on
   one that does not scans each sector from its pose);
3. the returns (:meth:`~slr_ray.effects.stages.Stage.apply`): ray drop (one draw
   per pulse, from its first return's range, incidence and intensity; a
   dropped pulse loses all its returns), blind zone and the maximum range of
   each return's reflectivity, range noise along each return's ray, intensity
   carried or corrected;
4. where they land (:meth:`~slr_ray.effects.stages.Stage.place`): with motion,
   the sensor's frame at the sweep's end, or each column's firing pose
   (``motion_frame='firing'``, a raw frame).

With every effect off the result is the ideal scan: the same points, the
same indices (``EffectScan.ideal`` holds it).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..arrays import as_origin
from ..backends import BackendOptions, Scanner, backends_with, prepare
from ..backends.embree import refuse_cast
from ..errors import InputValueError
from ..io import PointCloud
from ..pattern import as_pattern, pulse_rays
from ..progress import step
from ..scan import Scan
from . import stages as registry  # its STAGES read at each call: a stage registered there runs
from .motion import as_poses
from .returns import group_returns, select_returns, subray_directions
from .settings import EffectsBase
from .stages import Context, Effects, Rays, Returns, Stage

__all__ = ["ray_count", "EffectScan", "simulate", "simulate_given", "effect_cloud"]

#: rays cast per call (bounds memory: about 100 bytes a ray)
RAYS_PER_BATCH = 1 << 21


@dataclass(frozen=True, eq=False)
class EffectScan:
    """A simulated scan with sensor effects: one row per return.

    Attributes
    ----------
    points : (m, 3) float64
        Where each return lands: the cloud's coordinates, or with motion the
        sensor frame at the end of the sweep (``frame``).
    indices : (m,) intp
        The point of the scanned cloud behind each return (its attributes
        and labels follow: ``labels[es.indices]``).
    ranges : (m,) float64
        Measured range (with noise, if on).
    pulses : (m, 2) int64
        ``(v, h)`` of each return's pulse.
    return_number, number_of_returns : (m,) int64
        1-based position of the return along its pulse, and how many the pulse
        has (1 and 1 without divergence).
    share : (m,) float64
        Share of the pulse's footprint behind the return (1 without divergence).
    intensity : (m,) float64 or None
        None when the cloud has none or ``intensity`` is off.
    frame : {'world', 'sensor-end', 'firing'}
    ideal : Scan or None
        The ideal scan the effects start from (None when rays were cast here).
    info : dict
        ``seconds`` per stage, returns removed by each effect, the effects.
    """

    points: np.ndarray
    indices: np.ndarray
    ranges: np.ndarray
    pulses: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    share: np.ndarray
    intensity: np.ndarray | None
    origin: np.ndarray
    pattern: object
    frame: str = "world"
    ideal: Scan | None = None
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.indices)

    def to_cloud(self, attributes: dict | None = None) -> PointCloud:
        """The returns as a :class:`~slr_ray.io.PointCloud`: ``return_number``,
        ``number_of_returns`` (LAS's standard fields), ``intensity`` where
        known, and each of ``attributes`` (per point of the scanned cloud)
        taken at :attr:`indices`."""
        att = {k: np.asarray(v)[self.indices] for k, v in (attributes or {}).items()}
        att["return_number"] = self.return_number.astype(np.uint8)
        att["number_of_returns"] = self.number_of_returns.astype(np.uint8)
        if self.intensity is not None:
            att["intensity"] = self.intensity
        return PointCloud(self.points, att, None if self.frame != "world" else self.origin)


def effect_cloud(es: EffectScan, cloud: PointCloud) -> PointCloud:
    """The returns of ``es`` as a subset of the scanned ``cloud`` (what the
    command line writes): every attribute, and a LAS file's records, follow
    :attr:`EffectScan.indices`; the points are where the returns land;
    ``return_number`` and ``number_of_returns`` are set where a pulse can have
    several returns (beam divergence), and ``intensity`` where the effects made
    one (rounded to the input's type when that is an integer, as LAS's)."""
    sub = cloud.subset(es.indices)
    sub.points = np.ascontiguousarray(es.points)
    sub.origin = es.origin if es.frame == "world" else None
    if (es.info.get("effects") or {}).get("divergence_mrad"):
        sub.attributes["return_number"] = es.return_number.astype(np.uint8)
        sub.attributes["number_of_returns"] = es.number_of_returns.astype(np.uint8)
    if es.intensity is not None:
        old = cloud.attributes.get("intensity")
        kind = np.asarray(old).dtype if old is not None else np.dtype(np.float64)
        if kind.kind in "iu":
            info = np.iinfo(kind)
            sub.attributes["intensity"] = np.clip(np.round(es.intensity), info.min, info.max).astype(kind)
        else:
            sub.attributes["intensity"] = es.intensity.astype(kind if kind.kind == "f" else np.float64)
    return sub


def ray_count(pattern, effects: Effects | None = None) -> int:
    """The rays a scan of ``pattern`` with ``effects`` casts on a scanner that casts rays: one a pulse,
    or each pulse's sub-rays with beam divergence (``1 + 3 beam_rings (beam_rings - 1)``)."""
    n = int(as_pattern(pattern).n_pulses)
    if effects is not None and effects.divergence_mrad and effects.divergence_mrad != "sensor":
        n *= 1 + 3 * effects.beam_rings * (effects.beam_rings - 1)
    return n


def _cast_returns(scanner, origin, pattern, plan: Rays, intensity):
    """Rays cast here (a scanner that casts rays): the plan's sub-rays of every pulse, from its
    sector's pose."""
    nv, nh = pattern.shape
    s = len(plan.weights)
    refuse_cast(nv * nh * s, f"the rays {scanner.backend!s} casts{' with their sub-rays' if plan.subrays else ''} "
                f"(a backend with casts_rays: {', '.join(backends_with('casts_rays'))})",
                "choose a coarser pattern (--resolution) or fewer sub-rays (beam_rings)")
    rmin, rmax = pattern.range_limits
    if plan.sectors is None:
        starts, stops, rots, origins = [0], [nh], np.eye(3)[None], origin[None]
    else:
        starts, stops, rots, origins = plan.sectors
    dirs_all, vv, hh = pulse_rays(pattern)
    dirs_all = dirs_all.reshape(nv, nh, 3)
    parts = []
    for a, b, rot, o in zip(starts, stops, rots, origins):
        rows_per = max(1, RAYS_PER_BATCH // ((b - a) * s))
        for r0 in range(0, nv, rows_per):
            step(f"casting {nv * nh * s:,} rays", (len(parts) * rows_per) / (len(starts) * nv))  # once named
            r1 = min(nv, r0 + rows_per)
            d = dirs_all[r0:r1, a:b].reshape(-1, 3) @ rot.T
            idx, t = scanner.cast(o, subray_directions(d, plan.offsets) if plan.subrays else d, max_range=rmax)
            g = group_returns(idx.reshape(-1, s), t.reshape(-1, s), plan.weights, plan.separation, plan.min_share,
                              intensity)
            v = r0 + g["pulse"] // (b - a)
            h = a + g["pulse"] % (b - a)
            g.update(v=v, h=h, dir=d[g["pulse"]], fire=np.broadcast_to(o, (len(v), 3)))
            parts.append(g)
    keys = ("v", "h", "range", "share", "index", "strength", "return_number", "number_of_returns", "dir", "fire")
    out = {k: np.concatenate([p[k] for p in parts]) for k in keys}
    if "all" not in plan.returns:
        keep = select_returns({**out, "pulse": out["v"] * nh + out["h"]}, plan.returns)
        out = {k: v[keep] for k, v in out.items()}
    inside = (out["range"] >= rmin) & (out["range"] <= rmax)
    return {k: v[inside] for k, v in out.items()}


def _sector_scans(scanner, pattern, plan: Rays):
    """Motion on a scanner that casts no rays (binning): the cloud seen from each sector's pose, one scan
    per sector by the scanner's own backend and options."""
    parts = []
    for a, b, rot, o in zip(*plan.sectors):
        local = (scanner.points - o) @ rot  # the sensor frame of this sector's pose
        sc = prepare(local, scanner.backend, scanner.options).scan(np.zeros(3), pattern)
        mine = (sc.pulses[:, 1] >= a) & (sc.pulses[:, 1] < b)
        idx = sc.indices[mine]
        r = sc.ranges[mine]
        d = (local[idx] / r[:, None]) @ rot.T
        parts.append({"v": sc.pulses[mine, 0], "h": sc.pulses[mine, 1], "range": r, "index": idx, "dir": d,
                      "fire": np.broadcast_to(o, (len(idx), 3))})
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    m = len(out["v"])
    out.update(share=np.ones(m), return_number=np.ones(m, np.int64), number_of_returns=np.ones(m, np.int64))
    return out


def _geometry(scanner, origin, pattern, plan: Rays, intensity):
    """The returns the plan asks for, in pulse order unless sectors fire from their own poses;
    and the ideal scan where the plan asks for nothing beyond it (else None)."""
    ideal = None
    if plan.ideal:
        ideal = scanner.scan(origin, pattern)
        idx = ideal.indices
        d = scanner.points[idx] - origin
        m = len(idx)
        g = {"v": ideal.pulses[:, 0], "h": ideal.pulses[:, 1], "range": ideal.ranges.copy(), "index": idx,
             "dir": d / np.maximum(ideal.ranges, 1e-300)[:, None], "fire": np.broadcast_to(origin, (m, 3)),
             "share": np.ones(m), "return_number": np.ones(m, np.int64), "number_of_returns": np.ones(m, np.int64)}
    elif scanner.casts_rays:
        g = _cast_returns(scanner, origin, pattern, plan, intensity)
    else:
        g = _sector_scans(scanner, pattern, plan)
    if plan.sectors is None:
        order = np.lexsort((g["return_number"], g["h"], g["v"]))
        g = {k: v[order] for k, v in g.items()}
    return Returns.from_columns(g), ideal


def _check_per_point(name, a, n, width=None):
    if a is None:
        return None
    a = np.asarray(a, np.float64)
    want = (n,) if width is None else (n, width)
    if a.shape != want:
        raise InputValueError(f"{name} must have shape {want} (one per point of the scanned cloud), got {a.shape}")
    return a


def simulate(scanner, origin, pattern, effects=None, *, intensity=None, normals=None, poses=None,
             primary_origin=None) -> EffectScan:
    """Scan a prepared cloud with sensor effects.

    Parameters
    ----------
    scanner : Scanner
        ``slr_ray.prepare(points, backend)``; divergence and per-column motion
        need a scanner that casts rays (``scanner.casts_rays``: embree); motion
        on one that does not scans each sector of columns from its own pose.
    origin : (3,) float or None
        Scanner position (with ``poses``: None; the result's ``origin`` is then
        the end pose's).
    pattern : ScanPattern, BeamPattern, str or float
    effects : Effects or dict, optional
        Default none: the ideal scan. Resolved here (:meth:`Effects.resolve`)
        unless they already are.
    intensity : (n,) float, optional
        The cloud's intensity (strongest return, maximum range by
        reflectivity, the drop model's intensity term, carried intensity).
    normals : (n, 3) float, optional
        For incidence angles (ray drop, corrected intensity); default the
        embree scanner's disc normals, or PCA normals of the cloud.
    poses : (k, 4, 4) float, optional
        Sensor-to-world poses over the sweep (:mod:`slr_ray.effects.motion`).
    primary_origin : (3,) float, optional
        Where the cloud was scanned from (``intensity='correct'``).

    Returns
    -------
    EffectScan
    """
    pattern = as_pattern(pattern)
    eff = (effects if isinstance(effects, EffectsBase) else Effects.from_dict(effects)).resolve(pattern)  # once
    n = len(scanner.points)
    intensity = _check_per_point("intensity", intensity, n)
    normals = _check_per_point("normals", normals, n, 3)
    if eff.motion and poses is None:
        raise InputValueError("these effects include motion: give poses (start and end of the sweep, or a trajectory)")
    if poses is not None:
        poses = as_poses(poses)
        origin = poses[-1][:3, 3].copy()  # the sensor at the end of the sweep
    else:
        origin = as_origin(origin)
    drop_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(eff.seed).spawn(2))
    info = {"returns_geometry": 0}
    ctx = Context(effects=eff, scanner=scanner, pattern=pattern, origin=origin, intensity=intensity,
                  normals=normals, primary_origin=primary_origin, rng={"drop": drop_rng, "noise": noise_rng},
                  info=info, poses=poses)
    stages = [stage for stage in registry.STAGES if stage.on(ctx)]
    t0 = time.perf_counter()
    plan = Rays()
    for stage in stages:  # what to cast, before any work
        plan = stage.rays(plan, ctx)
    ctx.rays = plan
    r, ideal = _geometry(scanner, origin, pattern, plan, intensity)
    ranges = r.range.copy() if ideal is not None else None  # a stage that changes them moves the points
    secs = {"geometry": time.perf_counter() - t0}
    info["returns_geometry"] = int(len(r))
    for stage in stages:
        if type(stage).apply is Stage.apply:  # acts before the geometry or on the points only (their time: geometry)
            continue
        t0 = time.perf_counter()
        r = stage.apply(r, ctx)
        secs[stage.name] = time.perf_counter() - t0
    pts = r.fire + r.dir * r.range[:, None]
    for stage in stages:
        pts = stage.place(pts, r, ctx)
    if (ideal is not None and len(r) == len(ideal.indices) and np.array_equal(r.range, ranges)
            and all(type(stage).place is Stage.place for stage in stages)):
        pts = scanner.points[r.index]  # exactly the ideal scan's points (no rounding through the range)
    info.update(seconds={k: round(v, 6) for k, v in secs.items()}, effects=eff.to_dict(), backend=scanner.backend)
    return EffectScan(points=np.ascontiguousarray(pts), indices=r.index.astype(np.intp), ranges=r.range,
                      pulses=np.column_stack([r.v, r.h]).astype(np.int64),
                      return_number=r.return_number.astype(np.int64),
                      number_of_returns=r.number_of_returns.astype(np.int64), share=r.share,
                      intensity=r.intensity, origin=origin, pattern=pattern, frame=ctx.frame, ideal=ideal, info=info)


class _GivenScan(Scanner):
    """A scan made elsewhere, as the scanner :func:`simulate` starts from (no
    capabilities: it casts no rays, holds no normals)."""

    backend = "given"

    def __init__(self, points, scan: Scan):
        super().__init__(points, BackendOptions())
        self._scan = scan

    def scan(self, origin, pattern) -> Scan:
        return self._scan


def simulate_given(scan: Scan, points, effects=None, *, intensity=None, normals=None,
                   primary_origin=None) -> EffectScan:
    """The effects that follow the geometry (ray drop, blind zone and
    reflectivity range, range noise, intensity) on a scan made elsewhere,
    e.g. the hits of a mesh scan (:func:`slr_ray.meshscan.scan_mesh`).

    Parameters
    ----------
    scan : Scan
        Its ``indices`` index ``points``; its ``origin`` and ``pattern`` are the scan's.
    points : (n, 3) float
    effects : Effects or dict, optional
    intensity, normals : (n,) float, (n, 3) float, optional
        Per point of ``points`` (default normals: PCA of the points' neighbours).
    primary_origin : (3,) float, optional

    Raises
    ------
    InputValueError
        effects that need rays cast here: beam divergence, motion.
    """
    eff = (effects if isinstance(effects, EffectsBase) else Effects.from_dict(effects)).resolve(scan.pattern)
    if eff.divergence_mrad or eff.motion:
        raise InputValueError("beam divergence and motion cast their own rays: they apply to a prepared cloud "
                              "(simulate), not to a scan made elsewhere")
    pts = np.asarray(points, np.float64)
    return simulate(_GivenScan(pts, scan), scan.origin, scan.pattern, eff, intensity=intensity, normals=normals,
                    primary_origin=primary_origin)
