"""Subsampling backends behind one protocol: prepare a cloud once, scan it many times.

>>> import numpy as np, slr_ray
>>> pts = np.array([[1.0, 0, 0], [2.0, 0, 0], [0, 1.0, 0]])
>>> scanner = slr_ray.prepare(pts, backend="binning")
>>> scanner.scan([0, 0, 0], 0.144).indices.tolist()
[0, 2]

Backends (:class:`Backend`):

``binning`` (:class:`~slr_ray.backends.binning.BinningScanner`)
    the paper's nearest-in-pulse rule, exact and the fastest; nothing to prepare.
``embree`` (:class:`~slr_ray.backends.embree.DiscScanner`)
    points as discs in an Embree BVH, one ray per pulse centre; neighbours,
    normals and the BVH are prepared once.

Each backend has typed options (:class:`~slr_ray.backends.binning.BinningOptions`,
:class:`~slr_ray.backends.embree.EmbreeOptions`) that reject unknown keys;
:func:`options_for` builds them from a mapping (config files, CLI flags).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from typing import NamedTuple

from ..arrays import as_origin, as_points
from ..errors import InputValueError, SlrNote, SlrWarning
from ..pattern import as_pattern
from ..raycast import embree_available
from ..scan import Scan
from .base import Backend, BackendOptions, Scanner, require_streamable, streams
from .binning import BinningOptions, BinningScanner
from .embree import DiscScanner, EmbreeOptions
from .embree.fit import fit_primary_pattern
from .embree.scanner import ENCLOSED_SHARE

__all__ = ["Backend", "BACKENDS", "BackendEntry", "Scanner", "BackendOptions", "prepare", "simulate_scan",
           "options_for", "scanner_class", "backends_with", "require_rays", "require_streamable", "streams",
           "available_backends", "BinningOptions", "EmbreeOptions", "primary_from_cloud", "enclosed_note"]


class BackendEntry(NamedTuple):
    """A backend's scanner class and options class."""

    scanner: type
    options: type


#: The one registry of backends: what ``prepare``, ``options_for`` and the command line's flags read.
#: Keyed by name (a :class:`Backend` is its name); a new backend is one file and one line here.
BACKENDS: dict[str, BackendEntry] = {
    Backend.BINNING: BackendEntry(BinningScanner, BinningOptions),
    Backend.EMBREE: BackendEntry(DiscScanner, EmbreeOptions),
}


def _backend(name) -> str:
    if isinstance(name, str) and name in BACKENDS:
        return Backend(name) if name in {b.value for b in Backend} else name
    raise InputValueError(f"unknown backend {name!r}; choose one of {[str(b) for b in BACKENDS]}")


def scanner_class(backend) -> type:
    """The :class:`Scanner` class of ``backend`` (a name): its capabilities
    (``casts_rays``, ``streamable``...) before anything is prepared."""
    return BACKENDS[_backend(backend)].scanner


def backends_with(capability: str) -> list[str]:
    """Names of the registered backends whose scanner class has ``capability`` (a
    :class:`Scanner` capability, as ``'casts_rays'``), in the registry's order:
    what a message names instead of one backend."""
    return [str(b) for b, entry in BACKENDS.items() if getattr(entry.scanner, capability, False)]


def require_rays(scanner, what: str) -> None:
    """The one rule of effects that need rays: refuse ``what`` (e.g. 'beam divergence
    (divergence_mrad)') on a scanner or scanner class that casts none, naming the
    backends that do (:func:`backends_with`)."""
    if not scanner.casts_rays:
        them = backends_with("casts_rays")
        which = f"casts_rays: {', '.join(them)}; --backend {them[0]}" if them else "none is registered"
        raise InputValueError(f"{what} needs a backend that casts rays ({which}): {scanner.backend!s} keeps one "
                              "point per pulse and has no footprint beyond it (docs/effects.md)")


def options_for(backend, options: dict | BackendOptions | None = None, **more) -> BackendOptions:
    """Typed options of ``backend`` from a mapping and keywords (unknown keys are an error)."""
    cls = BACKENDS[_backend(backend)].options
    if isinstance(options, BackendOptions):
        if not isinstance(options, cls):
            raise InputValueError(f"{type(options).__name__} given for backend {str(backend)!r}")
        return replace(options, **more) if more else options
    return cls.from_dict(options, **more)


def prepare(points, backend: str | Backend = Backend.BINNING, options=None, **more) -> Scanner:
    """Prepare ``points`` for scanning from many positions.

    Parameters
    ----------
    points : (n, 3) float
        The cloud, float64 or float32 (widened to float64 before any origin is
        subtracted). Held by reference: do not modify it while scanning.
    backend : {'binning', 'embree'}
    options : dict or BackendOptions, optional
        Backend options; keywords are merged in (``prepare(p, "embree",
        radius=0.02)``).

    Returns
    -------
    Scanner
        ``.scan(origin, pattern) -> Scan`` for any number of positions.

    Raises
    ------
    InputValueError
        bad shape, non-finite rows (with their count), unknown or bad options.
    InputTypeError
        complex, object or boolean data.
    """
    b = _backend(backend)
    opts = options_for(b, options, **more)
    pts = as_points(points, check_finite=False)
    opts.check_points(len(pts))
    return BACKENDS[b].scanner(pts, opts)


def simulate_scan(points, origin, pattern, backend: str | Backend = Backend.BINNING, **options) -> Scan:
    """Simulate the scan an ideal static scanner at ``origin`` would record.

    Prepare-then-scan in one call; to scan one cloud from many positions,
    :func:`prepare` it once instead.

    Parameters
    ----------
    points : (n, 3) float
        The cloud, float64 or float32 (float32 input gives exactly what its
        float64 copy gives).
    origin : (3,) float
        Scanner position, in the same coordinates as ``points``.
    pattern : ScanPattern, str or float
        The scan pattern, a preset name (``"slr"``, ``"syns"``...) or a
        resolution in degrees.
    backend : {'binning', 'embree'}
        ``'binning'`` (default) keeps, per pulse bin, the point with the
        smallest range (ties to the lowest index): the paper's rule, exact,
        and the fastest. ``'embree'`` splats the points as discs and returns
        the point whose disc the ray through each pulse centre meets first
        (:mod:`slr_ray.backends.embree`); a point hit by several rays appears
        once.
    **options
        Backend options (:class:`BinningOptions`, :class:`EmbreeOptions`).

    Returns
    -------
    Scan
        Indices into ``points`` (ascending), ranges and pulse bins.

    Examples
    --------
    >>> import numpy as np, slr_ray
    >>> pts = np.array([[1.0, 0, 0], [2.0, 0, 0], [0, 1.0, 0]])
    >>> scan = slr_ray.simulate_scan(pts, [0, 0, 0], 0.144)
    >>> scan.indices.tolist()     # the point at 2 m hides behind the one at 1 m
    [0, 2]
    """
    pattern = as_pattern(pattern)
    origin = as_origin(origin)
    t0 = time.perf_counter()
    scanner = prepare(points, backend, **options)
    scan = scanner.scan(origin, pattern)
    info = dict(scan.info)
    if scanner.prepare_seconds and scanner.costly_prepare:
        info["prepare_seconds"] = round(scanner.prepare_seconds, 6)
    return replace(scan, seconds=time.perf_counter() - t0, info=info)


def available_backends() -> list[str]:
    """Backends whose dependencies load on this machine."""
    return [str(b) for b in BACKENDS if b != Backend.EMBREE or embree_available()]


def enclosed_note(scan, name) -> str | None:
    """What to say of a scan that stands among points (``Scan.info['enclosed_share']`` over
    :data:`~.embree.scanner.ENCLOSED_SHARE`: a disc backend's rays stop on the discs around it), or None."""
    share = (getattr(scan, "info", None) or {}).get("enclosed_share", 0.0)
    if not share > ENCLOSED_SHARE:
        return None
    return (f"{name}: its scanner stands among points (over {ENCLOSED_SHARE:.0%} of its rays stop on discs "
            "within two of their radii of it): the embree backend's discs are surfaces and hide what lies beyond "
            "them, where binning sees between the points, so it keeps far fewer points than binning would "
            "(docs/augment.md)")


def primary_from_cloud(cloud, backend, options: dict, name) -> dict:
    """``options`` (a mapping of ``backend``'s options) with the primary taken from ``cloud``, as
    ``slr-ray scan`` takes it: where the cloud records its scanner's origin (a KITTI .bin, an .npz
    origin, a PCD viewpoint, an E57 pose) and ``options`` choose no primary, a backend told of its
    primary (embree) gets that origin and ``primary_pattern='fit'`` (the same pattern wherever it is
    prepared), said in a :class:`~slr_ray.errors.SlrNote`; a cloud no fit holds keeps ``options``,
    with a warning saying why. ``options`` unchanged for a cloud of None (a streamed input). ``name``:
    the cloud's, for the messages."""
    takes = scanner_class(backend).primary_options
    if (cloud is None or cloud.origin is None or not takes((0.0, 0.0, 0.0), 1.0)
            or any(k in options for k in ("primary_origin", "primary_pattern", "primary_resolution"))):
        return options
    origin = [float(v) for v in cloud.origin]
    try:
        _, how, _ = fit_primary_pattern(cloud.points, origin)
    except InputValueError as e:  # no grid, or not a scan's: the discs go without the primary (kNN), and say why
        warnings.warn(f"{name}: its pattern is not fitted, the discs take kNN neighbours: {e}", SlrWarning,
                      stacklevel=3)
        return options
    warnings.warn(f"{name} records where its scanner was ({', '.join(f'{v:g}' for v in origin)}): the {backend} "
                  f"backend takes its pattern fitted to the points ({how}); give primary_origin and "
                  "primary_pattern or primary_resolution to choose them", SlrNote, stacklevel=3)
    return {**options, **takes(origin, "fit")}
