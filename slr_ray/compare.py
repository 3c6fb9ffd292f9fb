"""Cross-checking the two backends on the same cloud and positions.

The binning backend returns, per pulse, the closest point anywhere in the
pulse's pyramid; the embree backend returns the point whose disc the pulse's
centre ray meets first. Where a surface is sampled sparsely, binning can return
a point far *behind* that surface, because no point of the surface fell in the
pulse: a "see-through" point, the binning artefact the embree backend exists
to expose. :func:`compare_backends` counts them per position and range band.
"""

from __future__ import annotations

import math

import numpy as np

from .arrays import as_origin, as_points
from .errors import InputValueError
from .backends import Backend, Scanner, prepare
from .pattern import as_pattern
from .progress import bar, phase

__all__ = ["compare_backends", "DEFAULT_BANDS"]

#: range bands (metres) of the per-band figures
DEFAULT_BANDS = (0.0, 5.0, 10.0, 20.0, 40.0, 80.0, math.inf)


def _band_stats(b_idx, e_idx, b_rng, e_rng, see, bands):
    rows = []
    for lo, hi in zip(bands[:-1], bands[1:]):
        bi = set(b_idx[(b_rng >= lo) & (b_rng < hi)].tolist())
        ei = set(e_idx[(e_rng >= lo) & (e_rng < hi)].tolist())
        union = len(bi | ei)
        rows.append({
            "band_m": [lo, None if math.isinf(hi) else hi],
            "binning": len(bi), "embree": len(ei),
            "jaccard": (len(bi & ei) / union) if union else None,
            "only_binning": len(bi - ei), "only_embree": len(ei - bi),
            "see_through": int(np.count_nonzero(see & (b_rng >= lo) & (b_rng < hi))),
        })
    return rows


def _jaccard(a, b):
    """|a & b| / |a | b|; None where both are empty (as in the bands: nothing to agree on)."""
    union = len(np.union1d(a, b))
    return len(np.intersect1d(a, b)) / union if union else None


def compare_backends(points, origins, pattern, *, tolerance: float = 0.10, bands=DEFAULT_BANDS,
                     embree_options: dict | None = None, scene: Scanner | None = None,
                     binning: Scanner | None = None, progress: bool = False) -> dict:
    """Run both backends from each origin and compare them.

    Parameters
    ----------
    points : (n, 3) float
    origins : (k, 3) or (3,) float
        Scanner positions.
    pattern : ScanPattern, str or float
    tolerance : float
        A binning return is "see-through" when it lies more than this (metres)
        behind the disc the embree ray of the same pulse hits first.
    bands : sequence of float
        Range band edges (metres) for the per-band figures; ranges are from
        each position.
    embree_options : dict
        Options of the embree backend (:class:`slr_ray.backends.EmbreeOptions`).
    scene : Scanner, optional
        These points already prepared with ``backend='embree'``, reused.
    binning : Scanner, optional
        These points already prepared with ``backend='binning'``, reused.
    progress : bool
        Progress on stderr: preparing the discs, then a bar over the positions.

    Returns
    -------
    dict
        ``positions``: per position the totals and ``bands`` (per range band:
        points from each backend, Jaccard index of the two index sets (None where both are empty), points
        only one backend returns, see-through points), timings, and the
        options used. Plain JSON.
    """
    pts = as_points(points).astype(np.float64, copy=False)
    pattern = as_pattern(pattern)
    origins = np.atleast_2d(np.asarray(origins, dtype=np.float64))
    if origins.ndim != 2 or origins.shape[1] != 3:
        raise InputValueError(f"origins must be (k, 3), got {origins.shape}")
    if tolerance <= 0:
        raise InputValueError(f"tolerance must be > 0, got {tolerance}")
    bands = tuple(float(b) for b in bands)
    if len(bands) < 2 or any(hi <= lo for lo, hi in zip(bands[:-1], bands[1:])):
        raise InputValueError(f"bands must be at least two increasing edges, got {bands}")
    if scene is None:
        with phase(f"embree: preparing {len(pts):,} points", progress=progress):
            scene = prepare(pts, Backend.EMBREE, embree_options)
    if binning is None:
        binning = prepare(pts, Backend.BINNING)
    out = []
    nh = pattern.n_azimuth
    for origin in bar(origins, "compare", "position", progress=progress):
        origin = as_origin(origin)
        b = binning.scan(origin, pattern)
        e, (ray_pulses, _, ray_t) = scene.scan_and_rays(origin, pattern)
        # per pulse, the distance to the first disc along its centre ray
        first_t = dict(zip((ray_pulses[:, 0] * nh + ray_pulses[:, 1]).tolist(), ray_t.tolist()))
        t_same = np.array([first_t.get(k, np.inf) for k in b.pulse_ids.tolist()])
        see = b.ranges > t_same + tolerance
        out.append({
            "origin": origin.tolist(), "binning": len(b), "embree": len(e),
            "jaccard": _jaccard(b.indices, e.indices),
            "see_through": int(see.sum()), "see_through_fraction": float(see.mean()) if len(see) else 0.0,
            "binning_seconds": b.seconds, "embree_seconds": e.seconds,
            "embree_cast_seconds": e.info["cast_seconds"],
            "bands": _band_stats(b.indices, e.indices, b.ranges, e.ranges, see, bands),
        })
    return {"pattern": pattern.to_dict(), "tolerance": tolerance, "n_points": len(pts),
            "embree_options": scene.options.to_dict(), "embree_prepare_seconds": scene.prepare_seconds,
            "positions": out}
