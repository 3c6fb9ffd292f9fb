"""Reading LAS/LAZ files larger than memory: chunks of points, the header's bounds, a progress bar.

:func:`las_chunks` yields the file's points a chunk at a time (with its
header and EVLRs), :func:`las_xyz` a chunk's coordinates, and
:func:`records_cloud` the :class:`~slr_ray.io.PointCloud` of some of its raw
records (header, VLRs and EVLRs kept, written back exactly). The streamed
scans and positions built on them (:func:`slr_ray.streaming.scan_las`,
``scan_las_many``, ``las_positions``) live in :mod:`slr_ray.streaming`: a
file module knows nothing of scanning.
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import lazy
from ..errors import FormatError, SlrWarning
from ..progress import bar as progress_bar
from .cloud import LasRecords, PointCloud
from .las import check_las_size

#: laspy, loaded on first use (slr_ray.lazy: the command line starts without it, and without requests)
laspy = lazy.module("laspy")

__all__ = ["las_bounds", "checked_bounds", "las_chunks", "las_xyz", "las_bar", "records_cloud", "STREAMED_FORMATS", "DEFAULT_CHUNK"]

#: Input formats read in chunks (:func:`slr_ray.streaming.scan_las`).
STREAMED_FORMATS = (".las", ".laz")
#: Points a chunk (about 100 MB of coordinates and raw records).
DEFAULT_CHUNK = 2_000_000


def las_chunks(path, chunk):
    try:
        with laspy.open(str(path)) as reader:
            header = reader.header
            check_las_size(path, header)  # fewer points declared than the file holds: refused before any work
            evlrs = list(getattr(reader, "evlrs", None) or [])
            seen = 0
            for points in reader.chunk_iterator(chunk):
                seen += len(points)
                yield header, evlrs, points
            if seen != header.point_count:  # laspy stops quietly where a lying header's points run out
                raise FormatError(f"{path}: the header declares {header.point_count:,} points, the file holds "
                                  f"{seen:,} (truncated or corrupt)")
    except (laspy.errors.LaspyException, ValueError, OSError, RuntimeError) as exc:  # lazrs: RuntimeError
        if isinstance(exc, FormatError):
            raise
        raise FormatError(f"cannot read {path}: {type(exc).__name__}: {exc}") from exc


def las_bounds(path) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest coordinates of a LAS/LAZ file, as its header records them (no point
    read); None when it declares no point."""
    try:
        with laspy.open(str(path)) as reader:
            h = reader.header
            return (np.asarray(h.mins, np.float64), np.asarray(h.maxs, np.float64)) if h.point_count else None
    except (laspy.errors.LaspyException, ValueError, RuntimeError) as exc:  # OSError (no such file) as it is
        raise FormatError(f"cannot read {path}: {type(exc).__name__}: {exc}") from exc


def checked_bounds(path, header_bounds, points_bounds, scales):
    """The bounds to use: the header's (``header_bounds``, :func:`las_bounds`) when they agree with
    ``points_bounds``, the lowest and highest coordinates of the points actually read, to half a
    scale step; else the points', with a warning on stderr saying so (a header that lies about its
    bounds must not move ``--origin-relative centre`` nor fool the origin's range check)."""
    lo, hi = (np.asarray(b, np.float64) for b in points_bounds)
    if header_bounds is None:
        return lo, hi
    hlo, hhi = (np.asarray(b, np.float64) for b in header_bounds)
    tol = 0.5 * np.abs(np.asarray(scales, np.float64)) + 1e-9 * np.maximum(np.abs(lo), np.abs(hi))
    if np.all(np.abs(hlo - lo) <= tol) and np.all(np.abs(hhi - hi) <= tol):
        return hlo, hhi
    fmt = lambda a, b: ", ".join(f"{n} {a[i]:,.3f} to {b[i]:,.3f}" for i, n in enumerate("xyz"))  # noqa: E731
    warnings.warn(f"{path}: the LAS header's bounds ({fmt(hlo, hhi)}) disagree with its points' ({fmt(lo, hi)}): "
                  "the points' are used", SlrWarning, stacklevel=2)
    return lo, hi


def las_xyz(pts) -> np.ndarray:
    return np.column_stack([np.asarray(pts.x), np.asarray(pts.y), np.asarray(pts.z)])


def records_cloud(header, evlrs, array) -> PointCloud:
    """The cloud of some raw LAS ``array`` records of a file of ``header`` and ``evlrs``."""
    rec = laspy.ScaleAwarePointRecord(array, header.point_format, header.scales, header.offsets)
    pts = np.column_stack([np.asarray(rec.x), np.asarray(rec.y), np.asarray(rec.z)]) if len(array) else \
        np.empty((0, 3))
    attrs = {name: np.asarray(rec[name]) for name in header.point_format.dimension_names
             if name not in ("X", "Y", "Z")}
    meta = {"las_point_format": int(header.point_format.id), "las_scales": header.scales.tolist(),
            "las_offsets": header.offsets.tolist(), "las": LasRecords(header, evlrs, array)}
    return PointCloud(np.ascontiguousarray(pts, np.float64), attrs, None, meta)


def las_bar(path, what, progress):
    if not progress:
        return None
    with laspy.open(str(path)) as r:
        total = r.header.point_count
    if not total:  # no points: refused after the (empty) read, with no bar drawn before the error
        return None
    return progress_bar(total=total, desc=what, unit="pt", unit_scale=True)
