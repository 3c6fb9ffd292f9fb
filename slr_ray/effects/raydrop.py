"""Ray drop: pulses a real unit does not return, as a logistic model fitted from a real frame.

A spinning sensor's frame is a grid of pulses (beam by column); some pulses
that met a surface return nothing (dark, wet or glancing surfaces, far
ranges). The model gives the probability that a pulse is dropped::

    logit p = w . [1, rho, rho^2, gamma, gamma^2, iota]

with ``rho = range / 50 m``, ``gamma = incidence / 90 deg`` (the angle
between the ray and the surface normal) and ``iota = intensity /
intensity_scale`` (left out when the frame has no intensity).

Fitting from a frame (:func:`frame_pulses`, :func:`fit_ray_drop`): the
frame's rings come from its scan order (:func:`rings_from_scan_order`: a
KITTI ``.bin`` stores each laser's sweep in turn, azimuth increasing, so a
ring ends where the azimuth falls back) or a ring field; within a ring,
consecutive returns ``k`` column steps apart enclose ``k - 1`` dropped
pulses. Gaps longer than ``max_gap`` pulses are not counted (sky, or nothing
within range: not a drop the model can learn). A returned pulse's features
are its own (range, incidence from the local PCA normal, intensity); a
dropped pulse's are interpolated along the ring between the two returns
that enclose it (the neighbours' range, incidence and intensity).

Applying (:meth:`RayDropModel.sample`): one uniform draw per pulse from a
seeded generator; the same seed and the same pulses give the same drops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..arrays import as_origin
from ..backends.embree import estimate_normals
from ..errors import InputValueError

__all__ = ["RayDropModel", "fit_ray_drop", "frame_pulses", "rings_from_scan_order", "incidence_deg",
           "drop_rates", "RANGE_SCALE", "MAX_RINGS", "COLUMN_STEP_RANGE_DEG", "MAX_RING_SPREAD_DEG", "NORMAL_K_RANGE",
           "MAX_COEF", "MAX_FEATURE", "INTENSITY_SCALE_RANGE"]

#: Range unit of the model's features, metres.
RANGE_SCALE = 50.0
#: A frame's rings (beams) at most: spinning units have up to 128 (a shuffled KITTI frame read in
#: scan order gives 35,000 "rings", a random cloud thousands).
MAX_RINGS = 256
#: The azimuth step between firings a spinning unit has (degrees; KITTI's HDL-64E: 0.18; a shuffled
#: frame's "step" is 68).
COLUMN_STEP_RANGE_DEG = (0.01, 2.0)
#: The median spread of a ring's elevations at most (degrees, median absolute deviation; KITTI: 0.24).
MAX_RING_SPREAD_DEG = 1.0
#: Neighbours of a PCA normal: at least a plane's 3, at most a local patch's 100.
NORMAL_K_RANGE = (3, 100)
#: The largest feature a fit takes, in absolute value: (range / 50 m)^2 up to it is 50 km, intensity up
#: to it times the intensity scale (a point 1e150 m away overflowed the fit's logit).
MAX_FEATURE = 1e6
#: The intensity scale of a model: the intensity of reflectivity 1 (1 KITTI's, 255 8-bit, 65535 16-bit).
INTENSITY_SCALE_RANGE = (1e-6, 1e6)
#: The largest weight of a model, in absolute value: a logit of 1e6 is a certainty already (a fit to
#: separable pulses stays far below; 1e308 overflowed the probability).
MAX_COEF = 1e6
_NAMES_GEOMETRY = ("intercept", "range", "range^2", "incidence", "incidence^2")


def _design(ranges, incidence, intensity, intensity_scale):
    with np.errstate(over="ignore", invalid="ignore"):  # absurd features become inf: refused by the fit
        rho = np.asarray(ranges, np.float64) / RANGE_SCALE
        gam = np.asarray(incidence, np.float64) / 90.0
        cols = [np.ones_like(rho), rho, rho * rho, gam, gam * gam]
        if intensity is not None:
            cols.append(np.asarray(intensity, np.float64) / intensity_scale)
    return np.column_stack(cols)


def _sigmoid(z):
    return 0.5 * (1.0 + np.tanh(0.5 * z))  # stable for any z


@dataclass(frozen=True)
class RayDropModel:
    """Logistic drop probability of a pulse (module docstring).

    Attributes
    ----------
    coef : tuple of float
        Weights of ``[1, rho, rho^2, gamma, gamma^2]`` and, with
        ``uses_intensity``, ``iota``.
    uses_intensity : bool
    intensity_scale : float
        The intensity value mapped to ``iota = 1``.
    stderr : tuple of float, optional
        Standard errors of the fit (inverse Fisher information).
    info : dict
        How it was fitted (pulses, drop rate, source).
    """

    coef: tuple
    uses_intensity: bool = False
    intensity_scale: float = 1.0
    stderr: tuple | None = None
    info: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        if not isinstance(self.uses_intensity, bool):
            raise InputValueError(f"uses_intensity must be true or false, got {self.uses_intensity!r}")
        want = len(_NAMES_GEOMETRY) + (1 if self.uses_intensity else 0)
        try:
            c = tuple(float(x) for x in self.coef if not isinstance(x, (str, bool)))
        except (TypeError, ValueError):
            c = ()
        if len(c) != want or len(c) != len(self.coef) or not all(math.isfinite(x) for x in c):
            raise InputValueError(f"coef must be {want} finite numbers (uses_intensity={self.uses_intensity}), "
                                  f"got {self.coef!r}")
        if max(abs(x) for x in c) > MAX_COEF:
            raise InputValueError(f"coef must lie within +-{MAX_COEF:g} (a logit beyond is a certainty), got "
                                  f"{max(c, key=abs):g}")
        object.__setattr__(self, "coef", c)
        lo, hi = INTENSITY_SCALE_RANGE
        if not (isinstance(self.intensity_scale, (int, float)) and not isinstance(self.intensity_scale, bool)
                and lo <= self.intensity_scale <= hi):
            raise InputValueError(f"intensity_scale must lie in [{lo:g}, {hi:g}] (the intensity of reflectivity 1), "
                                  f"got {self.intensity_scale!r}")

    @property
    def names(self) -> tuple:
        return _NAMES_GEOMETRY + (("intensity",) if self.uses_intensity else ())

    def probability(self, ranges, incidence, intensity=None) -> np.ndarray:
        """``(m,)`` drop probability of pulses with these ranges (m), incidence
        angles (degrees) and, if the model uses it, intensities.

        Raises
        ------
        InputValueError
            a model that uses intensity given none.
        """
        if self.uses_intensity and intensity is None:
            raise InputValueError("this ray-drop model uses intensity; the scanned cloud has none "
                                  "(fit one without intensity: fit_ray_drop(..., intensity=None))")
        with np.errstate(over="ignore", invalid="ignore"):  # huge features: a logit of +-inf, p of 0 or 1
            x = _design(ranges, incidence, intensity if self.uses_intensity else None, self.intensity_scale)
            return _sigmoid(x @ np.asarray(self.coef))

    def sample(self, ranges, incidence, intensity=None, rng=None) -> np.ndarray:
        """``(m,) bool``: True where a pulse is dropped (one uniform draw each, from ``rng``:
        a seed or a ``numpy.random.Generator``)."""
        p = self.probability(ranges, incidence, intensity)
        return np.random.default_rng(rng).random(len(p)) < p

    def to_dict(self) -> dict:
        return {"coef": list(self.coef), "uses_intensity": self.uses_intensity,
                "intensity_scale": self.intensity_scale,
                "stderr": None if self.stderr is None else list(self.stderr), "info": self.info,
                "names": list(self.names)}

    @classmethod
    def from_dict(cls, d: dict) -> "RayDropModel":
        keys = ("coef", "uses_intensity", "intensity_scale", "stderr", "info")
        unknown = sorted(set(d) - set(keys) - {"names"})
        if unknown:
            raise InputValueError(f"unknown ray-drop model key(s) {unknown}; known: {list(keys)}")
        if "coef" not in d:
            raise InputValueError("a ray-drop model needs 'coef'")
        for k in ("coef", "stderr"):
            if d.get(k) is not None and not isinstance(d[k], (list, tuple)):
                raise InputValueError(f"a ray-drop model's {k!r} is a list of numbers, got {d[k]!r}")
        model = cls(**{k: (tuple(d[k]) if k in ("coef", "stderr") and d[k] is not None else d[k])
                       for k in keys if k in d})
        if d.get("names") is not None and list(d["names"]) != list(model.names):
            raise InputValueError(f"a ray-drop model's 'names' {d['names']!r} are not its weights' "
                                  f"{list(model.names)} (uses_intensity={model.uses_intensity})")
        if model.stderr is not None and (len(model.stderr) != len(model.coef) or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in model.stderr)):
            raise InputValueError(f"a ray-drop model's 'stderr' must be {len(model.coef)} numbers, "
                                  f"got {list(model.stderr)!r}")
        return model


def fit_ray_drop(ranges, incidence, dropped, intensity=None, intensity_scale: float = 1.0,
                 ridge: float = 1e-6, max_iter: int = 50, info: dict | None = None) -> RayDropModel:
    """Fit a :class:`RayDropModel` by maximum likelihood (Newton / IRLS).

    Parameters
    ----------
    ranges, incidence : (m,) float
        Metres, degrees.
    dropped : (m,) bool
        True where the pulse returned nothing.
    intensity : (m,) float, optional
        Without, the model has no intensity term.
    ridge : float
        A small L2 penalty (keeps separable data finite).

    Raises
    ------
    InputValueError
        mismatched lengths, non-finite features, or a class (dropped / returned) absent.
    """
    y = np.asarray(dropped, bool).ravel()
    lo, hi = INTENSITY_SCALE_RANGE
    if not (isinstance(intensity_scale, (int, float)) and lo <= intensity_scale <= hi):
        raise InputValueError(f"intensity_scale must lie in [{lo:g}, {hi:g}] (the intensity of reflectivity 1), "
                              f"got {intensity_scale!r}")
    x = _design(ranges, incidence, intensity, intensity_scale)
    if x.shape[0] != len(y):
        raise InputValueError(f"ranges, incidence, intensity and dropped must have one length, got "
                              f"{x.shape[0]} and {len(y)}")
    if not np.all(np.isfinite(x)):
        raise InputValueError(f"{int(np.count_nonzero(~np.isfinite(x).all(axis=1)))} pulses have non-finite features")
    big = int(np.count_nonzero((np.abs(x) > MAX_FEATURE).any(axis=1)))
    if big:
        raise InputValueError(f"{big} pulses have features beyond a sensor's (ranges over "
                              f"{RANGE_SCALE * math.sqrt(MAX_FEATURE):,.0f} m, or intensities over {MAX_FEATURE:g} "
                              "times intensity_scale)")
    if y.all() or not y.any():
        raise InputValueError("fit_ray_drop needs dropped and returned pulses both")
    w = np.zeros(x.shape[1])
    w[0] = math.log(y.mean() / (1 - y.mean()))
    lam = ridge * len(y)

    def loglik(w):
        z = x @ w  # log p(y) = y z - log(1 + e^z), stably
        return float(np.sum(y * z - np.logaddexp(0.0, z)) - 0.5 * lam * w @ w)

    ll = loglik(w)
    for _ in range(max_iter):
        p = _sigmoid(x @ w)
        g = x.T @ (y - p) - lam * w
        h = (x * (p * (1 - p))[:, None]).T @ x + lam * np.eye(len(w))
        step = np.linalg.solve(h, g)
        t = 1.0  # damped Newton: halve the step until the likelihood does not fall
        while t > 1e-6:
            new = loglik(w + t * step)
            if new >= ll - 1e-12 * abs(ll):
                break
            t *= 0.5
        w, ll = w + t * step, new
        if np.max(np.abs(t * step)) < 1e-9:
            break
    p = _sigmoid(x @ w)
    h = (x * (p * (1 - p))[:, None]).T @ x + lam * np.eye(len(w))
    se = np.sqrt(np.diag(np.linalg.inv(h)))
    meta = {"pulses": int(len(y)), "dropped": int(y.sum()), "drop_rate": float(y.mean()), **(info or {})}
    return RayDropModel(tuple(w.tolist()), intensity is not None, float(intensity_scale), tuple(se.tolist()), meta)


def rings_from_scan_order(points, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``(n,) int64`` ring of every point of a frame stored ring after ring.

    A KITTI ``.bin`` (an HDL-64E frame as its driver wrote it) holds each
    laser's sweep in turn, azimuth increasing from the frame's start: a new
    ring begins where the azimuth (0-360 deg from the start) falls back by
    more than 90 deg. Ring 0 is the first stored (KITTI: the top beam).
    """
    d = np.asarray(points, np.float64) - as_origin(origin)
    if len(d) == 0:
        return np.zeros(0, np.int64)
    phi = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    phi = (phi - phi[0]) % 360.0
    start = np.zeros(len(d), np.int64)
    start[1:] = np.diff(phi) < -90.0
    return np.cumsum(start)


def _check_scan(d, r, rings, step, source):
    """Refuse rings that are not a spinning unit's: too many, an azimuth step no unit has, or
    rings whose points lie at many elevations (a shuffled frame, a random cloud, a ring field
    of random values)."""
    ids, counts = np.unique(rings, return_counts=True)
    where = f"rings from {source}"
    if len(ids) > MAX_RINGS:
        raise InputValueError(f"{where}: {len(ids):,} rings, more than a spinning unit's {MAX_RINGS} (a median "
                              f"of {int(np.median(counts))} points a ring): the frame is not a scan in its order")
    lo, hi = COLUMN_STEP_RANGE_DEG
    if not lo <= step <= hi:
        raise InputValueError(f"{where}: a median azimuth step of {step:.3g} deg between a ring's consecutive "
                              f"points, outside a spinning unit's [{lo:g}, {hi:g}]: the frame is not a scan in "
                              "its order")
    el = np.degrees(np.arcsin(np.divide(d[:, 2], r, out=np.zeros_like(r), where=r > 0)))
    order = np.argsort(rings, kind="stable")
    parts = np.split(el[order], np.cumsum(counts)[:-1])
    spread = float(np.median([np.median(np.abs(e - np.median(e))) for e in parts]))
    if spread > MAX_RING_SPREAD_DEG:
        raise InputValueError(f"{where}: a ring's points spread over {spread:.2f} deg of elevation (median "
                              f"absolute deviation; a beam's: under {MAX_RING_SPREAD_DEG:g}): not a scan's rings")


def incidence_deg(points, normals, origin) -> np.ndarray:
    """``(n,)`` angle between each point's line of sight from ``origin`` and its normal, degrees (0-90)."""
    d = np.asarray(points, np.float64) - as_origin(origin)
    r = np.linalg.norm(d, axis=1)
    n = np.asarray(normals, np.float64)
    c = np.abs(np.einsum("ij,ij->i", d, n)) / np.maximum(r * np.linalg.norm(n, axis=1), 1e-300)
    return np.degrees(np.arccos(np.clip(c, 0.0, 1.0)))


def frame_pulses(points, origin=(0.0, 0.0, 0.0), rings=None, intensity=None, column_step_deg=None,
                 max_gap: int = 16, normals=None, k: int = 10) -> dict:
    """Every pulse of a frame's own grid that can be classified: returned or dropped.

    Parameters
    ----------
    points : (n, 3) float
        The frame, in scan order within each ring (as drivers write it).
    origin : (3,) float
    rings : (n,) int, optional
        Each point's ring; default :func:`rings_from_scan_order`.
    intensity : (n,) float, optional
    column_step_deg : float, optional
        Azimuth step between firings; default the median step between
        consecutive points of a ring. Either must lie in
        :data:`COLUMN_STEP_RANGE_DEG`.
    max_gap : int
        Longer runs of missing pulses are not counted (module docstring).
    normals : (n, 3) float, optional
        Default: PCA of the ``k`` nearest neighbours (``k`` in
        :data:`NORMAL_K_RANGE`).

    Raises
    ------
    InputValueError
        rings that are not a spinning unit's: more than :data:`MAX_RINGS`,
        a median step outside :data:`COLUMN_STEP_RANGE_DEG`, or a median
        spread of a ring's elevations over :data:`MAX_RING_SPREAD_DEG`
        (a shuffled frame, a random cloud, a ring field of random values).

    Returns
    -------
    dict
        ``range``, ``incidence`` (degrees), ``intensity`` (or None), ``dropped``
        (bool), ``ring``: one entry per classified pulse; ``column_step_deg``.
    """
    pts = np.asarray(points, np.float64)
    o = as_origin(origin)
    n = len(pts)
    lo_k, hi_k = NORMAL_K_RANGE
    if normals is None and not (isinstance(k, (int, np.integer)) and lo_k <= k <= min(hi_k, max(n - 1, lo_k))):
        raise InputValueError(f"k must be an integer in [{lo_k}, {hi_k}] and below the frame's {n} points (the "
                              f"neighbours of a PCA normal), got {k!r}")
    rings, source = _rings_of(pts, o, rings)
    _check_steps(max_gap, column_step_deg)
    d = pts - o
    r = np.linalg.norm(d, axis=1)
    phi = np.degrees(np.unwrap(np.arctan2(d[:, 1], d[:, 0])))
    same = rings[1:] == rings[:-1]
    dphi = np.diff(phi)
    steps = np.abs(dphi[same])
    measured = float(np.median(steps[steps > 0])) if np.any(steps > 0) else math.nan
    _check_scan(d, r, rings, measured, source)
    if column_step_deg is None:
        column_step_deg = measured
    nrm = estimate_normals(pts, k=k, primary_origin=o) if normals is None else np.asarray(normals, np.float64)
    inc = incidence_deg(pts, nrm, o)
    gap = np.rint(np.abs(dphi) / column_step_deg).astype(np.int64) - 1  # missing pulses between i and i+1
    ok = same & (gap >= 1) & (gap <= max_gap)
    a = np.flatnonzero(ok)
    m = gap[a]
    # one row per missing pulse: interpolated between the enclosing returns a and a + 1
    left = np.repeat(a, m)
    j = np.arange(m.sum()) - np.repeat(np.cumsum(m) - m, m) + 1
    frac = j / np.repeat(m + 1, m)

    def lerp(v):
        return (1 - frac) * v[left] + frac * v[left + 1]

    out = {"range": np.concatenate([r, lerp(r)]), "incidence": np.concatenate([inc, lerp(inc)]),
           "intensity": None if intensity is None else np.concatenate([np.asarray(intensity, np.float64),
                                                                       lerp(np.asarray(intensity, np.float64))]),
           "dropped": np.concatenate([np.zeros(n, bool), np.ones(len(left), bool)]),
           "ring": np.concatenate([rings, rings[left]]), "column_step_deg": column_step_deg}
    return out


def _rings_of(pts, o, rings) -> tuple:
    """``(rings, source)`` of :func:`frame_pulses`: the rings given, checked, or from the scan order."""
    n = len(pts)
    if rings is None:
        rings, source = rings_from_scan_order(pts, o), "the scan order"
    else:
        given = np.asarray(rings)
        if given.shape != (n,):
            raise InputValueError(f"rings must have one entry per point ({n}), got {given.shape}")
        if given.dtype.kind not in "iu" and (given.dtype.kind != "f" or not np.all(np.isfinite(given))
                                             or np.any(given != np.round(given))):
            raise InputValueError(f"rings must be integers (ring ids), got dtype {given.dtype} with fractions")
        rings, source = given.astype(np.int64), "the rings given"
    return rings, source


def _check_steps(max_gap, column_step_deg) -> None:
    """:func:`frame_pulses`' ``max_gap`` and ``column_step_deg`` refused out of range."""
    if not (isinstance(max_gap, (int, np.integer)) and max_gap >= 1):
        raise InputValueError(f"max_gap must be an integer >= 1, got {max_gap!r}")
    lo, hi = COLUMN_STEP_RANGE_DEG
    if column_step_deg is not None and not (isinstance(column_step_deg, (int, float)) and
                                            lo <= column_step_deg <= hi):
        raise InputValueError(f"column_step_deg must be degrees in [{lo:g}, {hi:g}] (a spinning unit's step "
                              f"between firings), got {column_step_deg!r}")


def drop_rates(values, dropped, edges) -> dict:
    """Drop rate per bin of ``values``: ``{'edges', 'pulses', 'rate'}`` (NaN where a bin is empty)."""
    values = np.asarray(values, np.float64)
    dropped = np.asarray(dropped, np.float64)
    edges = np.asarray(edges, np.float64)
    b = np.digitize(values, edges) - 1
    inside = (b >= 0) & (b < len(edges) - 1)
    cnt = np.bincount(b[inside], minlength=len(edges) - 1).astype(np.float64)
    drp = np.bincount(b[inside], weights=dropped[inside], minlength=len(edges) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = drp / cnt
    return {"edges": edges.tolist(), "pulses": cnt.astype(int).tolist(), "rate": rate.tolist()}
