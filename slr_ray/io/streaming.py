"""Scanning LAS/LAZ files larger than memory: one pass over the file in chunks.

Each chunk's coordinates go into one
:class:`~slr_ray.accumulator.ScanAccumulator` per scanner position (the exact
binning reduction: memory is the occupied pulses, not the points); after the
chunk, the raw records of the chunk's points that are now the nearest in
their pulse are kept, and kept records that a later chunk beat are dropped
(:class:`_Candidates`). A point that is the nearest at the end was the
nearest when its chunk was read, so the records kept at the end are exactly
the scan's. The result is the same :class:`~slr_ray.io.PointCloud` a
whole-file read and :func:`~slr_ray.backends.simulate_scan` give (same
indices, same records, same header, VLRs and EVLRs), with peak memory
bounded by one chunk, the reduction's state and about twice the scan's
records, and every chunk decompressed once for all the positions of a batch.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import laspy
import numpy as np

from ..accumulator import ScanAccumulator
from ..errors import FormatError
from ..progress import bar as progress_bar
from ..threads import default_threads
from .cloud import LasRecords, PointCloud
from .las import check_las_size

__all__ = ["scan_las", "las_bounds", "scan_las_many", "las_chunks", "las_xyz", "las_bar", "STREAMED_FORMATS",
           "DEFAULT_CHUNK"]

#: Input formats :func:`scan_las` reads in chunks.
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
        A progress bar (stderr).

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
    return next(scan_las_many(path, [origin], pattern, chunk=chunk, progress=progress))


def las_bounds(path) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest coordinates of a LAS/LAZ file, as its header records them (no point
    read); None when it declares no point."""
    try:
        with laspy.open(str(path)) as reader:
            h = reader.header
            return (np.asarray(h.mins, np.float64), np.asarray(h.maxs, np.float64)) if h.point_count else None
    except (laspy.errors.LaspyException, ValueError, RuntimeError) as exc:  # OSError (no such file) as it is
        raise FormatError(f"cannot read {path}: {type(exc).__name__}: {exc}") from exc


def las_xyz(pts) -> np.ndarray:
    return np.column_stack([np.asarray(pts.x), np.asarray(pts.y), np.asarray(pts.z)])


def scan_las_many(path, origins, pattern, *, chunk: int = DEFAULT_CHUNK, n_threads: int | None = None,
                  progress: bool = False):
    """Binning scans of a LAS/LAZ file from several origins, in one pass over
    the file: each chunk is read once and reduced for every origin, and the
    raw records each scan may keep are kept as the chunks go by.

    Yields ``(cloud, scan)`` per origin, in order, as :func:`scan_las` returns
    them (the same clouds, records and indices). Memory: one chunk, one
    reduction state per origin (a 0.144 deg pattern: 50 MB a thread) and up
    to about twice the kept records of each scan. ``n_threads`` (default all
    cores) are shared out: the reductions run side by side, one thread each,
    or a single origin's reduction on all of them.
    """
    path = Path(path)
    threads = n_threads or default_threads()
    per = max(1, threads // max(1, len(origins)))
    accs = [ScanAccumulator(o, pattern, n_threads=per) for o in origins]
    kept = [_Candidates() for _ in accs]
    start, header, evlrs = 0, None, []

    def step(acc, cand, xyz, records, start):
        acc.add(xyz)
        cand.update(acc.indices(), start, records)

    bar = las_bar(path, f"{len(accs)} scan{'s' if len(accs) > 1 else ''}", progress)
    with ThreadPoolExecutor(max(1, min(len(accs), threads))) as pool:
        for header, evlrs, pts in las_chunks(path, chunk):
            xyz, records = las_xyz(pts), pts.array
            if len(accs) == 1:
                step(accs[0], kept[0], xyz, records, start)
            else:
                list(pool.map(lambda ac: step(*ac, xyz, records, start), zip(accs, kept)))  # noqa: B023
            start += len(pts)
            if bar is not None:
                bar.update(len(pts))
    if bar is not None:
        bar.close()
    if header is None:
        raise FormatError(f"{path}: no points")
    for i, (acc, cand) in enumerate(zip(accs, kept)):
        scan = acc.result()
        accs[i] = kept[i] = None  # each reduction's state and candidates freed once its scan is out
        yield _cloud(header, evlrs, cand.records(scan.indices, header.point_format.dtype())), scan


class _Candidates:
    """The raw records a streamed scan may still keep: those of points that
    were the nearest in their pulse when their chunk was reduced, minus those
    a later chunk has beaten (pruned once they are half of what is held, so
    the work is linear in the records kept)."""

    def __init__(self):
        self.parts = []  # (indices, records) per chunk, indices ascending
        self.held = 0

    def update(self, winners, start, records) -> None:
        """After the chunk of ``records`` (file indices from ``start``) was reduced:
        ``winners`` are the indices of the current nearest points, ascending."""
        lo, hi = np.searchsorted(winners, [start, start + len(records)])
        if hi > lo:
            new = winners[lo:hi].copy()  # not a view: it would hold all of this chunk's winners
            self.parts.append((new, records[new - start]))
            self.held += hi - lo
        if self.held > 2 * len(winners):
            self.parts = [self._pruned(idx, rec, winners) for idx, rec in self.parts]
            self.held = sum(len(idx) for idx, _ in self.parts)

    @staticmethod
    def _pruned(idx, rec, winners):
        at = np.searchsorted(winners, idx).clip(max=len(winners) - 1)
        keep = winners[at] == idx
        return idx[keep], rec[keep]

    def records(self, indices, dtype) -> np.ndarray:
        """The records of the scan's ``indices`` (ascending), in that order."""
        parts = [self._pruned(idx, rec, indices)[1] for idx, rec in self.parts] if len(indices) else []
        self.parts = []
        out = np.concatenate(parts) if parts else np.zeros(0, dtype)
        if len(out) != len(indices):  # pragma: no cover - a winner whose chunk did not keep it
            raise RuntimeError(f"streamed scan kept {len(out)} records for {len(indices)} points")
        return out


def _cloud(header, evlrs, array) -> PointCloud:
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
