"""The scanner protocol every backend implements, and typed backend options.

A backend turns a point cloud into a :class:`Scanner` once (``prepare``: the
expensive part, e.g. neighbours, normals and a BVH) and the scanner answers
:meth:`Scanner.scan` for any number of positions. Options are frozen
dataclasses: the same names and checks serve the library, TOML configs and the
command line, and an unknown option is an error that lists the known ones.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from ..errors import InputValueError
from ..options import Options
from ..pattern import pulse_rays
from ..scan import Scan
from .names import Backend

__all__ = ["Backend", "Scanner", "BackendOptions", "require_streamable", "streams"]


@dataclasses.dataclass(frozen=True)
class BackendOptions(Options):
    """Base of every backend's options (frozen; unknown keys rejected; :class:`~slr_ray.options.Options`'
    ``from_dict`` and ``describe``, whose Attributes generate the command line's flags)."""

    @classmethod
    def choices(cls) -> dict:
        """``{field: allowed values}`` of the fields that take one of a few names."""
        return {}

    def check_points(self, n: int) -> None:
        """Refuse options that do not fit a cloud of ``n`` points (an array of another
        length); :func:`slr_ray.prepare` calls it before any work. None here."""

    def to_dict(self) -> dict:
        """Plain-JSON description (arrays summarised by shape)."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                v = f"array{list(v.shape)}"
            elif isinstance(v, tuple):
                v = list(v)
            out[f.name] = v
        return out


class Scanner(ABC):
    """A cloud prepared for scanning from many positions.

    Attributes
    ----------
    points : (n, 3) float
        The cloud (held by reference, not copied).
    backend : Backend
    options : BackendOptions
    prepare_seconds : float
        Time spent preparing (neighbours, BVH...).
    release_mapped : bool
        A file-mapped cloud (``np.load(..., mmap_mode='r')``): drop the pages
        each scan has read from this process's memory as it goes
        (:func:`~slr_ray.arrays.release_pages`). Off by default: the next
        scan would fault them all in again (a loop over positions, as in
        ``augment``, runs slower by that); the paper-size validation turns
        it on for its spilled primary, whose pages would otherwise count
        beside its discs.
    """

    backend: Backend
    release_mapped: bool = False

    # --- capabilities: what callers read instead of a backend's name (as patterns have
    # ``streamable`` and ``has_beams``); readable on the class, before anything is prepared

    #: :meth:`cast` answers rays of any direction (beam divergence, motion: effects that need rays)
    casts_rays: ClassVar[bool] = False
    #: :meth:`scan` can be made chunk by chunk of a file (a streamed LAS scan, augment's ``chunk_size``)
    streamable: ClassVar[bool] = False
    #: preparing builds something worth timing and doing once (a result reports ``prepare_seconds``;
    #: a validation runs it every ``embree_every`` positions)
    costly_prepare: ClassVar[bool] = False
    #: per-point unit normals the scanner holds, (n, 3), or None (effects then estimate them)
    normals = None

    @classmethod
    def primary_options(cls, origin, primary, fast: bool = False) -> dict:
        """Options telling this backend where and how its cloud was scanned (the
        primary: ``origin``, and ``primary`` a resolution in degrees or a pattern);
        ``fast``: also the cheapest such options. None here: ``{}``."""
        return {}

    def cast(self, origin, directions, max_range: float = math.inf):
        """First point met by each ray from ``origin`` along unit ``directions``:
        ``(indices, distances)``, -1 and ``inf`` on a miss. Only where
        :attr:`casts_rays`; here an :class:`~slr_ray.errors.InputValueError`."""
        raise InputValueError(f"backend {self.backend!s} casts no rays (casts_rays is False)")

    def scan_and_rays(self, origin, pattern):
        """:meth:`scan`, and where each pulse's centre ray met the cloud first: ``(scan,
        (pulses (k, 2), indices (k,), distances (k,)))`` for the ``k`` rays that hit. Only
        where :attr:`casts_rays`: here the pulse centres cast by :meth:`cast` (a backend may
        give both from one cast)."""
        scan = self.scan(origin, pattern)
        directions, rows, columns = pulse_rays(pattern)
        idx, t = self.cast(origin, directions, max_range=pattern.range_limits[1])
        hit = idx >= 0
        return scan, (np.column_stack([rows[hit], columns[hit]]).astype(np.int64), idx[hit].astype(np.intp), t[hit])

    def __init__(self, points: np.ndarray, options: BackendOptions, prepare_seconds: float = 0.0):
        self.points = points
        self.options = options
        self.prepare_seconds = prepare_seconds

    def __len__(self) -> int:
        return len(self.points)

    @abstractmethod
    def scan(self, origin, pattern) -> Scan:
        """The scan an ideal scanner at ``origin`` with ``pattern`` records.

        Parameters
        ----------
        origin : (3,) float
        pattern : ScanPattern, str or float

        Returns
        -------
        Scan
            Indices into :attr:`points` (ascending), ranges and pulses.
        """

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.backend} n={len(self)} {self.options}>"


def streams(scanner, pattern) -> bool:
    """The one rule of streamed scans: a scanner (or scanner class) that scans chunk
    by chunk and a pattern that reduces so (a uniform grid, not a beam table)."""
    return bool(scanner.streamable and pattern.streamable)


def require_streamable(scanner, pattern, what: str) -> None:
    """:func:`streams`, or an error naming ``what`` and why not."""
    if not streams(scanner, pattern):
        raise InputValueError(f"{what} streams the cloud in chunks: it needs a streamable backend (binning) and a "
                              f"uniform pattern, got backend {scanner.backend!s} and "
                              f"{'a uniform' if pattern.streamable else 'a beam-table'} pattern")
