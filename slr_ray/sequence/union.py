"""The accumulated primary: the frames of a window as one cloud in the world frame.

Each point keeps its source frame (an index into the union's ``frames``) and
so that frame's scanner origin; attributes (intensity, SemanticKITTI
``semantic`` and ``instance``) are carried where every frame of the window has
them. With labels, SemanticKITTI's *moving* classes (252-259: moving car,
bicyclist, person, motorcyclist, on-rails, truck, other vehicle, bus... as the
SemanticKITTI API's ``semantic-kitti.yaml`` numbers them) are left out by
default: a moving object is in another place in every frame, and a union keeps
all of its places.

A window (``half`` frames either side of the target, or the frames whose
origin lies within ``radius`` metres of the target's) bounds what is held in
memory: a sequence of thousands of frames never needs its whole map.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from ..effects.motion import rotate, to_frame  # noqa: F401  (the one to_frame: re-exported)
from ..errors import InputValueError
from .estimators import PulseReturns, merge_nearest, nearest_returns
from .frames import Frame, Sequence
from .sources import (SeeThrough, SourceView, base_pattern, cast_sources, seen_through_votes, source_discs,
                      source_view)

__all__ = ["Union", "rotate", "MOVING_CLASSES", "window", "accumulate", "nearest_of_frames", "discs_of_frames",
           "FrameCache", "Keep", "to_frame"]

#: SemanticKITTI's moving classes (semantic-kitti.yaml: 252 moving-car ... 259 moving-other-vehicle)
MOVING_CLASSES = tuple(range(252, 260))


@dataclass
class Union:
    """Points of several frames in the world frame.

    Attributes
    ----------
    points : (n, 3) float64, world frame
    source : (n,) int32, position in ``frames`` of each point's frame
    frames : (k,) int, the sequence indices of the frames held
    origins : (k, 3) float64, each frame's scanner origin (world)
    attributes : dict of (n,) arrays carried (those every frame has)
    removed : dict, points left out and why (``moving``: labelled moving)
    """

    points: np.ndarray
    source: np.ndarray
    frames: np.ndarray
    origins: np.ndarray
    attributes: dict = field(default_factory=dict)
    removed: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def frame_of_point(self) -> np.ndarray:
        """The sequence index of each point's source frame."""
        return self.frames[self.source]

    @property
    def origin_of_point(self) -> np.ndarray:
        """``(n, 3)``: each point's source scanner origin (world)."""
        return self.origins[self.source]

    def select(self, keep: np.ndarray) -> "Union":
        return Union(self.points[keep], self.source[keep], self.frames, self.origins,
                     {k: v[keep] for k, v in self.attributes.items()}, dict(self.removed))


def window(seq: Sequence, target: int, half: int | None = 2, radius: float | None = None,
           include_target: bool = False) -> list[int]:
    """The frames of ``target``'s window: ``half`` either side, or within ``radius`` m of its origin
    (both given: both hold), the target itself only with ``include_target``."""
    n = len(seq)
    if not 0 <= target < n:
        raise InputValueError(f"frame {target} is not in a sequence of {n} frames")
    cand = np.arange(n)
    if half is not None:
        if half < 0:
            raise InputValueError(f"the window's half width must be >= 0, got {half}")
        cand = cand[np.abs(cand - target) <= half]
    if radius is not None:
        if not radius > 0:
            raise InputValueError(f"the window's radius must be > 0, got {radius}")
        o = seq.poses[:, :3, 3]
        cand = cand[np.linalg.norm(o[cand] - o[target], axis=1) <= radius]
    return [int(i) for i in cand if include_target or i != target]


@dataclass(frozen=True)
class Keep:
    """Which points of each frame a union keeps, one object passed whole (to
    :func:`accumulate`, :class:`FrameCache`'s ``selection``, ``kept`` and ``discs``, the methods'
    :class:`~slr_ray.sequence.methods.HeldOut` and ``TargetFrame``): all but the labelled moving
    classes (``drop_moving``) and, with ``see_through``, but those other frames saw through; the
    frames of ``exclude`` (a held-out target) never vote."""

    drop_moving: bool = True
    see_through: SeeThrough | None = None
    exclude: tuple = ()

    @classmethod
    def of(cls, keep=True, see_through: SeeThrough | None = None, exclude=()) -> Keep:
        """``keep`` itself where it is a :class:`Keep`; else the old loose arguments (``keep`` the
        ``drop_moving`` bool) made one."""
        if isinstance(keep, Keep):
            return keep
        return cls(bool(keep), see_through, tuple(sorted(int(e) for e in exclude)))

    def key(self, i: int) -> tuple:
        """What frame ``i``'s selection depends on: the excluded frames only where they would vote
        (``see_through``; its own index never excludes it), so that held-out targets share a frame's
        selection, points and discs where nothing sees through."""
        if self.see_through is None:
            return bool(self.drop_moving), None, ()
        return (bool(self.drop_moving), self.see_through.key,
                tuple(sorted(int(e) for e in self.exclude if e != i)))


class FrameCache:
    """The last ``size`` frames read, in the world frame (a sliding window reads each frame once);
    ``local=False`` keeps the world coordinates only (not the frame's own). What is derived from a
    frame (its kept points, its own view, its discs) is held with it and goes with it; what a
    method builds once for the sequence (:meth:`method_state`) is held for the cache's life.
    ``keep`` (a :class:`Keep`) says which points of a frame a union keeps; the old loose arguments
    (``drop_moving``, ``see_through``, ``exclude``) still work in its place."""

    def __init__(self, seq: Sequence, size: int = 64, local: bool = True):
        self.seq, self.size, self.local = seq, max(1, int(size)), local
        self._held: OrderedDict = OrderedDict()
        self._kept: dict = {}
        self._views: dict = {}
        self._discs: dict = {}
        self._states: dict = {}  # a method's per-sequence state (method_state)
        self._state: dict = {}  # per frame: what methods derive from it (state)

    def method_state(self, method, options):
        """``method.sequence_state(seq, cache, options)`` built once for this cache (one sequence's
        run: every held-out frame of ``sequence evaluate``, every frame a ``sequence convert``
        worker converts), then returned as it is; keyed by the method's name and options."""
        key = (method.name, options)
        if key not in self._states:
            self._states[key] = method.sequence_state(self.seq, self, options)
        return self._states[key]

    def get(self, i: int) -> tuple[Frame, np.ndarray]:
        if i in self._held:
            self._held.move_to_end(i)
            return self._held[i]
        f = self.seq.read(i)
        item = (f, f.world())
        if not self.local:  # the world coordinates only: half the memory of a window
            f.points = np.zeros((0, 3))
        self._held[i] = item
        while len(self._held) > self.size:
            gone, _ = self._held.popitem(last=False)
            for d in (self._kept, self._views, self._discs, self._state):
                d.pop(gone, None)
        return item

    def state(self, i: int, key, make):
        """What a method derives from frame ``i`` (``make()``, its meshes, its own fit: a method's
        per-frame state), made once while the frame is held and gone with it; ``key`` names it
        (the method and its settings)."""
        self.get(i)
        held = self._state.setdefault(i, {})
        if key not in held:
            held[key] = make()
        return held[key]

    def own_points(self, i: int) -> np.ndarray:
        """Frame ``i``'s points in its own axes (float64; from the world ones where not kept)."""
        f, w = self.get(i)
        return f.points if len(f.points) == len(w) else to_frame(w, f.pose)

    def view(self, i: int, base) -> SourceView:
        """Frame ``i``'s own sensor (``base`` fitted to it), its range image at its origin."""
        f, _ = self.get(i)
        held = self._views.setdefault(i, {})
        key = (base.name, base.shape, tuple(base.elevation_deg))  # one view a table
        if key not in held:
            held[key] = source_view(self.own_points(i), f.attributes, base,
                                       f"frame {f.name} ({self.seq.paths[i]})")
        return held[key]

    def selection(self, i: int, keep: Keep | bool = True, see_through: SeeThrough | None = None,
                  exclude=()) -> tuple[np.ndarray | None, dict]:
        """Which points of frame ``i`` the union keeps (None: all) and how many each rule removed:
        ``moving`` (labelled moving classes, with ``drop_moving``), ``seen_through`` (other frames
        of ``see_through``'s neighbourhood, less ``exclude``, saw through them)."""
        rule = Keep.of(keep, see_through, exclude)
        see_through, exclude = rule.see_through, rule.key(i)[2]
        f, w = self.get(i)
        key = ("sel", *rule.key(i))
        held = self._kept.setdefault(i, {})
        if key not in held:
            keep = _kept(f, rule.drop_moving)
            removed = {"moving": 0 if keep is None else int(len(keep) - keep.sum())}
            if see_through is not None:
                base = base_pattern(see_through.sensor)
                others = [j for j in window(self.seq, i, see_through.half) if j not in exclude]
                views = [(self.get(j)[0].pose, self.view(j, base)) for j in others]
                votes = seen_through_votes(len(w), lambda pose: to_frame(w, pose), views, see_through.margin)
                through = votes >= see_through.votes
                removed["seen_through"] = int((through if keep is None else through & keep).sum())
                keep = ~through if keep is None else keep & ~through
            if keep is not None and keep.all():
                keep = None
            held[key] = (keep, removed)
        return held[key]

    def kept(self, i: int, keep: Keep | bool = True, see_through: SeeThrough | None = None,
             exclude=()) -> tuple[np.ndarray, dict]:
        """Frame ``i``'s world points and 1-d attributes less its labelled moving points (with
        ``drop_moving``) and those other frames saw through (with ``see_through``), selected once
        while the frame is held: a window of 61 frames slid over a drive selects each frame once,
        not 61 times."""
        rule = Keep.of(keep, see_through, exclude)
        f, w = self.get(i)
        keep, _ = self.selection(i, rule)
        held = self._kept.setdefault(i, {})
        key = ("pts", *rule.key(i))
        if key not in held:
            a = {n: np.asarray(v) for n, v in f.attributes.items() if np.ndim(v) == 1}
            if keep is not None:
                w = w[keep]
                a = {n: v[keep] for n, v in a.items()}
            held[key] = (w, a)
        return held[key]

    def discs(self, i: int, base, keep: Keep | bool = True, see_through: SeeThrough | None = None, exclude=()):
        """An embree scanner of frame ``i``'s kept points, discs from its own pulse grid
        (:func:`~slr_ray.sequence.sources.source_discs`), built once while the frame is held."""
        rule = Keep.of(keep, see_through, exclude)
        f, w = self.get(i)
        keep, _ = self.selection(i, rule)
        key = rule.key(i) + (base.name, base.shape, tuple(base.elevation_deg))
        held = self._discs.setdefault(i, {})
        if key not in held:
            held[key] = source_discs(w, self.own_points(i), self.view(i, base), f.pose, keep)
        return held[key]


def _kept(f: Frame, drop_moving: bool):
    sem = f.attributes.get("semantic")
    if drop_moving and sem is not None:
        return ~np.isin(np.asarray(sem), MOVING_CLASSES)
    return None


def nearest_of_frames(seq: Sequence, frames, pose, pattern, keep: Keep | bool = True,
                      cache: FrameCache | None = None,
                      see_through: SeeThrough | None = None) -> tuple[PulseReturns, dict]:
    """The nearest rule over the union of ``frames`` seen from ``pose``, a frame at a time: each
    frame reduced on its own, the winners merged (:func:`~slr_ray.sequence.estimators.merge_nearest`).
    The same returns as ``estimate(to_frame(accumulate(...).points, pose), pattern)``, without the
    union in memory. Returns them and the attributes carried (every frame's), by return.
    ``see_through``: points other frames saw through are left out too (:class:`FrameCache.selection`)."""
    cache = cache or FrameCache(seq, len(frames))
    keep = Keep.of(keep, see_through)
    posed = getattr(pattern, "reduce_posed", None)  # a beam table's (slr_ray.sensors.BeamPattern)
    parts, attrs, offset = [], [], 0
    for i in frames:
        w, a = cache.kept(int(i), keep)
        if posed is not None:  # each point moved in the kernel: no moved copy of the frame
            keys, ranges, idx = posed(w, pose)
            order = np.argsort(keys, kind="stable")
            keys, ranges, idx = keys[order], ranges[order], idx[order]
            ret = PulseReturns(keys, ranges, to_frame(w[idx], pose), idx)
        else:
            ret = nearest_returns(to_frame(w, pose), pattern)
        parts.append(PulseReturns(ret.keys, ret.ranges, ret.points, ret.index + offset))
        attrs.append({n: v[ret.index] for n, v in a.items()})
        offset += len(w)
    merged, pos = merge_nearest(parts)
    common = set(attrs[0]).intersection(*attrs[1:]) if attrs else set()
    carried = {n: np.concatenate([a[n] for a in attrs])[pos] for n in sorted(common)}
    return merged, carried


def accumulate(seq: Sequence, frames, keep: Keep | bool = True, cache: FrameCache | None = None,
               see_through: SeeThrough | None = None, exclude=(), *, drop_moving: bool | None = None) -> Union:
    """The union of ``frames`` of ``seq`` in the world frame (module docstring), each frame's points
    that ``keep`` keeps (a :class:`Keep`; or the old loose arguments: ``keep`` or ``drop_moving=``
    the labelled moving classes left out, with ``see_through`` the points other frames saw through
    too, the frames of ``exclude``, a held-out target, not among those that vote)."""
    keep = Keep.of(keep if drop_moving is None else drop_moving, see_through, exclude)
    frames = [int(i) for i in frames]
    if not frames:
        raise InputValueError("no frame to accumulate: the window holds none but the target")
    see_through = keep.see_through
    cache = cache or FrameCache(seq, len(frames) + (2 * see_through.half if see_through else 0))
    pts, src, attrs, origins = [], [], [], []
    removed = {"moving": 0} | ({"seen_through": 0} if see_through else {})
    for k, i in enumerate(frames):
        f, _ = cache.get(i)
        w, a = cache.kept(i, keep)
        for name, count in cache.selection(i, keep)[1].items():
            removed[name] += count
        pts.append(w)
        src.append(np.full(len(w), k, np.int32))
        attrs.append(a)
        origins.append(f.origin)
    common = set(attrs[0]).intersection(*attrs[1:]) if attrs else set()
    carried = {n: np.concatenate([a[n] for a in attrs]) for n in sorted(common)}
    return Union(np.concatenate(pts), np.concatenate(src), np.asarray(frames), np.asarray(origins),
                 carried, removed)


def discs_of_frames(cache: FrameCache, frames, pose, pattern, base, keep: Keep | bool = True,
                    see_through: SeeThrough | None = None, exclude=()) -> tuple[PulseReturns, dict]:
    """The ``embree-sources`` estimator over ``frames`` seen from ``pose``: each frame's discs from its
    own pulse grid (``base`` fitted to it), one scene a frame held by ``cache`` and reused by every
    target whose window holds the frame (:func:`~slr_ray.sequence.sources.cast_sources`). Returns
    the returns and the attributes carried (every frame's), by return (``cache``: the sequence's
    frames, ``FrameCache(seq)``)."""
    keep = Keep.of(keep, see_through, exclude)
    scanners, attrs, offset = [], [], 0
    for i in frames:
        w, a = cache.kept(int(i), keep)
        scanners.append((cache.discs(int(i), base, keep), offset))
        attrs.append(a)
        offset += len(w)
    ret = cast_sources(scanners, pose, pattern)
    common = set(attrs[0]).intersection(*attrs[1:]) if attrs else set()
    carried = {n: np.concatenate([a[n] for a in attrs])[ret.index] for n in sorted(common)}
    return ret, carried
