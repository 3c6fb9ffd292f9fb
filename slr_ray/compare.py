"""Cross-checking two backends on the same cloud and positions: one that keeps
a point per pulse bin and one that casts rays (by default the first of each
in the registry, :data:`~slr_ray.backends.BACKENDS`: binning and embree).

The binning backend returns, per pulse, the closest point anywhere in the
pulse's pyramid; the embree backend returns the point whose disc the pulse's
centre ray meets first. Where a surface is sampled sparsely, binning can return
a point far *behind* that surface, because no point of the surface fell in the
pulse: a "see-through" point, the binning artefact the embree backend exists
to expose. :func:`compare_backends` counts them per position and range band;
its figures are keyed by the two backends' names (``binning``, ``embree``,
``only_binning``, ``embree_options``...).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .arrays import as_origin, as_points
from .backends import BACKENDS, Scanner, backends_with, prepare, scanner_class
from .errors import InputValueError
from .options import Options
from .pattern import as_pattern
from .progress import bar, phase

__all__ = ["compare_backends", "CompareOptions", "compared_backends", "DEFAULT_BANDS"]

#: range bands (metres) of the per-band figures
DEFAULT_BANDS = (0.0, 5.0, 10.0, 20.0, 40.0, 80.0, math.inf)


def compared_backends() -> tuple[str, str]:
    """The default pair, from the registry's capabilities: the first backend that casts
    no rays (one point a pulse bin) and the first that casts rays."""
    bins = [str(b) for b in BACKENDS if not scanner_class(b).casts_rays]
    rays = backends_with("casts_rays")
    if not bins or not rays:
        raise InputValueError("comparing backends needs one that casts rays and one that does not; registered: "
                              f"{[str(b) for b in BACKENDS]}")
    return bins[0], rays[0]


@dataclass(frozen=True)
class CompareOptions(Options):
    """What :func:`compare_backends` compares, and how.

    Attributes
    ----------
    tolerance : float
        A return of the first backend is "see-through" when it lies more than
        this (metres) behind what the centre ray of the same pulse meets first.
    bands : sequence of float
        Range band edges (metres) for the per-band figures; ranges are from
        each position.
    backends : (2,) str or None
        The pair: one that casts no rays, then one that does (default
        :func:`compared_backends`).
    ray_options : dict or None
        Options of the backend that casts rays (e.g.
        :class:`~slr_ray.backends.EmbreeOptions`; the old keyword
        ``embree_options``).
    """

    tolerance: float = 0.10
    bands: tuple = DEFAULT_BANDS
    backends: tuple | None = None
    ray_options: dict | None = None


def _band_stats(b_idx, e_idx, b_rng, e_rng, see, bands, names):
    first, second = names
    rows = []
    for lo, hi in zip(bands[:-1], bands[1:]):
        bi = set(b_idx[(b_rng >= lo) & (b_rng < hi)].tolist())
        ei = set(e_idx[(e_rng >= lo) & (e_rng < hi)].tolist())
        union = len(bi | ei)
        rows.append({
            "band_m": [lo, None if math.isinf(hi) else hi],
            first: len(bi), second: len(ei),
            "jaccard": (len(bi & ei) / union) if union else None,
            f"only_{first}": len(bi - ei), f"only_{second}": len(ei - bi),
            "see_through": int(np.count_nonzero(see & (b_rng >= lo) & (b_rng < hi))),
        })
    return rows


def _jaccard(a, b):
    """|a & b| / |a | b|; None where both are empty (as in the bands: nothing to agree on)."""
    union = len(np.union1d(a, b))
    return len(np.intersect1d(a, b)) / union if union else None


def compare_backends(points, origins, pattern, options: CompareOptions | None = None, *,
                     scanners: tuple | None = None, progress: bool = False, **keywords) -> dict:
    """Run both backends from each origin and compare them.

    Parameters
    ----------
    points : (n, 3) float
    origins : (k, 3) or (3,) float
        Scanner positions.
    pattern : ScanPattern, str or float
    options : CompareOptions or dict, optional
        ``tolerance``, ``bands``, the pair of ``backends`` and the options of
        the one that casts rays (:class:`CompareOptions`); each field may also
        be given as a keyword (``tolerance=0.1``). ``embree_options=`` is kept
        as another name of ``ray_options``.
    scanners : (Scanner, Scanner), optional
        These points already prepared by the two backends, reused (the old
        keywords ``binning=`` and ``scene=``: either of them).
    progress : bool
        Progress on stderr: preparing the discs, then a bar over the positions.

    Returns
    -------
    dict
        ``positions``: per position the totals and ``bands`` (per range band:
        points from each backend, Jaccard index of the two index sets (None where both are empty), points
        only one backend returns, see-through points), timings, and the
        options used. Plain JSON, keyed by the backends' names.
    """
    old = {k: keywords.pop(k) for k in ("scene", "binning") if k in keywords}
    if "embree_options" in keywords:
        keywords["ray_options"] = keywords.pop("embree_options")
    opts = CompareOptions.of(options, **keywords)
    tolerance = opts.tolerance
    pts = as_points(points).astype(np.float64, copy=False)
    pattern = as_pattern(pattern)
    origins = np.atleast_2d(np.asarray(origins, dtype=np.float64))
    if origins.ndim != 2 or origins.shape[1] != 3:
        raise InputValueError(f"origins must be (k, 3), got {origins.shape}")
    if tolerance <= 0:
        raise InputValueError(f"tolerance must be > 0, got {tolerance}")
    bands = tuple(float(b) for b in opts.bands)
    if len(bands) < 2 or any(hi <= lo for lo, hi in zip(bands[:-1], bands[1:])):
        raise InputValueError(f"bands must be at least two increasing edges, got {bands}")
    first, second = (str(b) for b in (opts.backends or compared_backends()))
    if scanner_class(first).casts_rays or not scanner_class(second).casts_rays:
        raise InputValueError(f"backends: one that casts no rays, then one that does (casts_rays: "
                              f"{', '.join(backends_with('casts_rays'))}), got {first!r}, {second!r}")
    binning, scene = scanners if scanners is not None else (old.get("binning"), old.get("scene"))
    if scene is None:
        with phase(f"{second}: preparing {len(pts):,} points", progress=progress):
            scene = prepare(pts, second, opts.ray_options)
    if binning is None:
        binning = prepare(pts, first)
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
            "origin": origin.tolist(), first: len(b), second: len(e),
            "jaccard": _jaccard(b.indices, e.indices),
            "see_through": int(see.sum()), "see_through_fraction": float(see.mean()) if len(see) else 0.0,
            f"{first}_seconds": b.seconds, f"{second}_seconds": e.seconds,
            f"{second}_cast_seconds": e.info.get("cast_seconds"),
            "bands": _band_stats(b.indices, e.indices, b.ranges, e.ranges, see, bands, (first, second)),
        })
    return {"pattern": pattern.to_dict(), "tolerance": tolerance, "n_points": len(pts),
            f"{second}_options": scene.options.to_dict(), f"{second}_prepare_seconds": scene.prepare_seconds,
            "positions": out}
