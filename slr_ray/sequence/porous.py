"""Porous surfaces for ``embree-rays``: a first hit that the other frames' pulses went through.

A frame's ring mesh is the surface its own pulses stopped on. Foliage, a fence, a railing stop some
pulses and let others through (an HDL-64E's beam, ~2 mrad wide, partly covers a thin structure): a
first-surface cast returns the structure for every pulse that meets its mesh, and the real frame's
returns from behind it are far from every simulated one (on the KITTI frames most of the Chamfer
distance's coverage side: docs/sequences.md).

The evidence that a surface is porous is free space: the window's other frames' own range images
(their pulses from their origins). A frame whose pulse toward a hit returned more than ``margin``
beyond it went *through* it; one whose pulse returned within ``margin`` of it *stopped* on it; one
that returned nearer, or nothing, does not vote (:meth:`Porosity.votes`). Two rules
(:meth:`Porosity.porous`):

* ``window`` 0: each frame's pulse through the hit votes; the hit is passed where more frames went
  through it than stopped on it;
* ``window`` ``w`` >= 1: each frame's pulses ``w`` rows and ``2 w`` columns either side vote too (the
  region's transmittance ``T``, through over through and stop), and the ray passes where ``T`` exceeds
  its own threshold in [0, 1) (:func:`dither`: a low-discrepancy sequence over the rays), so a region
  passes about ``T`` of its rays, the same ones every run: the mix of near and far returns a porous
  structure gives.

Hits nearer than :data:`BEYOND` are kept. A ray passed goes on from just beyond the hit in every frame whose hit made its first surface
(:func:`pass_porous`), up to :data:`LAYERS` times (a bush is many); with nothing behind in any frame it
keeps the hit. Deterministic: the same frames give the same returns.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Porosity", "pass_porous", "dither", "MARGIN", "LAYERS", "BEYOND"]

#: a frame went through a hit where its pulse toward it returned this far (m) beyond it; stopped within it
MARGIN = 0.5
#: hits nearer than this (m, along the ray) are never passed: near, the frames' pulses are dense on a
#: structure and the passes there were a silhouette's pixels (KITTI frames: from 0 m, 0.0015 m more RMSE
#: for the same Chamfer distance; from 20 m every figure as good or better)
BEYOND = 20.0
#: porous layers a ray goes through at most
LAYERS = 3
#: a ray goes on this far (m) beyond a porous hit (past its own triangle)
STEP = 0.05


class Porosity:
    """The frames' range images as votes on a hit (module docstring): ``views`` ``(pose, SourceView)``
    of the window's frames (never the target), ``margin`` metres, ``window`` the rule; hits nearer than
    ``beyond`` metres are not passed."""

    def __init__(self, views, margin: float = MARGIN, window: int = 0, beyond: float = BEYOND):
        self._views, self.margin, self.window, self.beyond = views, float(margin), int(window), float(beyond)

    @property
    def views(self) -> list:
        """The views (``views`` given as a callable: made on the first vote, none where no hit lies beyond
        ``beyond``)."""
        if callable(self._views):
            self._views = self._views()
        return list(self._views)

    def votes(self, world) -> tuple[np.ndarray, np.ndarray]:
        """Per point of ``world``: how many pulses (of the frames, ``window`` around each frame's pulse
        through it) went through it and how many stopped on it."""
        w = np.asarray(world, np.float64)
        through, stop = np.zeros(len(w), np.int64), np.zeros(len(w), np.int64)
        for pose, view in self.views:
            T = np.asarray(pose, np.float64)
            keys, r = view.pattern.pulse_ids((w - T[:3, 3]) @ T[:3, :3], np.zeros(3))  # the frame's axes
            ok = keys >= 0
            rows, cols = view.pattern.shape
            v, h = keys[ok] // cols, keys[ok] % cols
            for dv in range(-self.window, self.window + 1):
                for dh in range(-2 * self.window, 2 * self.window + 1):
                    val = np.full(len(w), np.nan)
                    val[ok] = view.image[np.clip(v + dv, 0, rows - 1), (h + dh) % cols]
                    with np.errstate(invalid="ignore"):
                        through += val > r + self.margin
                        stop += np.abs(val - r) <= self.margin
        return through, stop

    def porous(self, world, rays) -> np.ndarray:
        """Whether each point of ``world`` (the first surface of rays ``rays``, their indices) is passed
        (module docstring)."""
        through, stop = self.votes(world)
        share = dither(rays) if self.window else 0.5
        return (through > 0) & (through > share * (through + stop))


def dither(rays) -> np.ndarray:
    """Each ray's pass threshold in [0, 1): its index times the golden ratio, mod 1 (a low-discrepancy
    sequence: neighbouring rays spread over [0, 1), so a region of transmittance ``T`` passes about
    ``T`` of its rays, the same rays every run)."""
    return np.mod(np.asarray(rays, np.float64) * 0.6180339887498949, 1.0)


def pass_porous(porosity: Porosity, live, rays, hits, gap: float, first_peak, debias=None):
    """Rays (``rays``: their world origins and directions) whose first surface (``first_peak(t, gap)``:
    the nearest of the frames' hits ``t``, ``hits`` ``(t, prims)`` rays by frames of ``live``) is porous
    cast on from :data:`STEP` beyond it in each frame whose hit lies within ``gap`` of the nearest; up to
    :data:`LAYERS` times. A ray with nothing behind a porous hit in any frame
    keeps it (the pulse returns from the structure or from beyond every frame's reach: the structure is
    the better guess). ``debias(t, prims, k)``: frame ``k``'s new hits debiased in place as its first ones
    were. In place (``t``, ``prims``)."""
    ow, dw = rays
    t, prims = hits
    todo = np.arange(len(t))
    for _ in range(LAYERS):
        if not len(todo):
            return
        tt, _ = first_peak(t[todo], gap)
        fin = np.isfinite(tt) & (tt > porosity.beyond)
        todo, tt = todo[fin], tt[fin]
        todo = todo[porosity.porous(ow[todo] + tt[:, None] * dw[todo], todo)]
        if not len(todo):
            return
        sub = t[todo]
        near = sub <= (sub.min(axis=1) + gap)[:, None]
        nt, npr = sub.copy(), prims[todo].copy()
        for k, (scene, _, _, _, _) in enumerate(live):
            m = np.flatnonzero(near[:, k])
            if not len(m):
                continue
            start = sub[m, k] + STEP
            rows = todo[m]
            h = scene.intersect_each(ow[rows] + start[:, None] * dw[rows], dw[rows])
            tk, pk = start + h.distances, h.primitives.copy()  # inf where nothing behind
            if debias is not None:
                debias(tk, pk, k)
            nt[m, k], npr[m, k] = tk, pk
        go = np.isfinite(nt).any(axis=1)  # something behind in some frame
        t[todo[go]], prims[todo[go]] = nt[go], npr[go]
        todo = todo[go]
