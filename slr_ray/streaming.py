"""Scanning LAS/LAZ files larger than memory: two passes over the file in chunks.

Pass 1 reads coordinates chunk by chunk into a
:class:`~slr_ray.accumulator.ScanAccumulator` (the exact binning reduction:
memory is the occupied pulses, not the points); pass 2 reads the file again
and keeps the raw records of the points the scan selected. The result is the
same :class:`~slr_ray.io.PointCloud` a whole-file read and
:func:`~slr_ray.backends.simulate_scan` give (same indices, same records,
same header, VLRs and EVLRs), with peak memory bounded by one chunk, the
reduction's state and the scan itself.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .accumulator import ScanAccumulator
from .errors import FormatError
from .io import LasRecords, PointCloud

__all__ = ["scan_las", "STREAMED_FORMATS", "DEFAULT_CHUNK"]

#: Input formats :func:`scan_las` reads in chunks.
STREAMED_FORMATS = (".las", ".laz")
#: Points a chunk (about 100 MB of coordinates and raw records).
DEFAULT_CHUNK = 2_000_000


def _chunks(path, chunk):
    import laspy

    try:
        with laspy.open(str(path)) as reader:
            header = reader.header
            evlrs = list(getattr(reader, "evlrs", None) or [])
            for points in reader.chunk_iterator(chunk):
                yield header, evlrs, points
    except (laspy.errors.LaspyException, ValueError, OSError) as exc:
        raise FormatError(f"cannot read {path}: {exc}") from exc


def scan_las(path, origin, pattern, chunk: int = DEFAULT_CHUNK, progress: bool = False):
    """The binning scan of a LAS/LAZ file from ``origin``, read in chunks.

    Parameters
    ----------
    path : path
        ``.las`` or ``.laz``.
    origin : (3,) float
        Scanner position, in the file's coordinates.
    pattern : ScanPattern, str or float
    chunk : int
        Points read at a time.
    progress : bool
        A progress bar per pass (stderr).

    Returns
    -------
    cloud : PointCloud
        The points kept, every attribute, with ``meta["las"]`` holding the
        input's header, VLRs, EVLRs and the kept raw records (written back
        to LAS/LAZ exactly by :func:`~slr_ray.io.write_cloud`).
    scan : Scan
        Indices (into the whole file, in file order), ranges and pulses.
    """
    path = Path(path)
    if path.suffix.lower() not in STREAMED_FORMATS:
        raise FormatError(f"{path}: streamed scans read {STREAMED_FORMATS}, not {path.suffix!r}")
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    acc = ScanAccumulator(origin, pattern)
    bar = _bar(path, "pass 1: scan", progress)
    for _, _, pts in _chunks(path, chunk):
        acc.add(np.column_stack([np.asarray(pts.x), np.asarray(pts.y), np.asarray(pts.z)]))
        if bar is not None:
            bar.update(len(pts))
    if bar is not None:
        bar.close()
    scan = acc.result()
    keep = scan.indices  # ascending
    parts, start, header, evlrs = [], 0, None, []
    bar = _bar(path, "pass 2: records", progress)
    for header, evlrs, pts in _chunks(path, chunk):
        lo, hi = np.searchsorted(keep, [start, start + len(pts)])
        if hi > lo:
            parts.append(pts.array[keep[lo:hi] - start])
        start += len(pts)
        if bar is not None:
            bar.update(len(pts))
    if bar is not None:
        bar.close()
    if header is None:
        raise FormatError(f"{path}: no points")
    array = np.concatenate(parts) if parts else np.zeros(0, header.point_format.dtype())
    return _cloud(header, evlrs, array), scan


def _cloud(header, evlrs, array) -> PointCloud:
    import laspy

    rec = laspy.ScaleAwarePointRecord(array, header.point_format, header.scales, header.offsets)
    pts = np.column_stack([np.asarray(rec.x), np.asarray(rec.y), np.asarray(rec.z)]) if len(array) else \
        np.empty((0, 3))
    attrs = {name: np.asarray(rec[name]) for name in header.point_format.dimension_names
             if name not in ("X", "Y", "Z")}
    meta = {"las_point_format": int(header.point_format.id), "las_scales": header.scales.tolist(),
            "las_offsets": header.offsets.tolist(), "las": LasRecords(header, evlrs, array)}
    return PointCloud(np.ascontiguousarray(pts, np.float64), attrs, None, meta)


def _bar(path, what, progress):
    if not progress:
        return None
    import laspy
    from tqdm import tqdm

    with laspy.open(str(path)) as r:
        total = r.header.point_count
    return tqdm(total=total, unit="pt", unit_scale=True, desc=what, leave=False)
