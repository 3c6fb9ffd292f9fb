"""Scans and positions on LAS/LAZ files larger than memory, read in chunks
(by :mod:`slr_ray.io.streaming`).

Scans (:func:`scan_las`, :func:`scan_las_many`): one pass over the file.
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

Positions (:func:`las_positions`): the grid method on the ground points and
occupied cells gathered in two passes of chunks.
"""

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .accumulator import ScanAccumulator
from .errors import FormatError, InputValueError
from .io.streaming import DEFAULT_CHUNK, STREAMED_FORMATS, las_bar, las_bounds, las_chunks, las_xyz, records_cloud
from .paper import CELL_SIZE, MIN_GROUND_POINTS
from .positions import select_positions
from .threads import default_threads

__all__ = ["las_positions", "MAX_GROUND_POINTS", "scan_las", "las_bounds", "scan_las_many", "STREAMED_FORMATS",
           "DEFAULT_CHUNK"]


# --- scans ----------------------------------------------------------------------------------------------------

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
    or a single origin's reduction on all of them. Each cloud's
    ``meta["points_bounds"]`` holds the lowest and highest coordinates of all
    the file's points, as read (:func:`slr_ray.io.streaming.checked_bounds`
    compares them with the header's).
    """
    path = Path(path)
    threads = n_threads or default_threads()
    per = max(1, threads // max(1, len(origins)))
    accs = [ScanAccumulator(o, pattern, n_threads=per) for o in origins]
    kept = [_Candidates() for _ in accs]
    start, header, evlrs = 0, None, []
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)  # the points' own bounds: the header's may lie

    def step(acc, cand, xyz, records, start):
        acc.add(xyz)
        cand.update(acc.indices(), start, records)

    bar = las_bar(path, f"{len(accs)} scan{'s' if len(accs) > 1 else ''}", progress)
    with ThreadPoolExecutor(max(1, min(len(accs), threads))) as pool:
        for header, evlrs, pts in las_chunks(path, chunk):
            xyz, records = las_xyz(pts), pts.array
            if len(xyz):
                lo, hi = np.minimum(lo, xyz.min(axis=0)), np.maximum(hi, xyz.max(axis=0))
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
        cloud = records_cloud(header, evlrs, cand.records(scan.indices, header.point_format.dtype()))
        cloud.meta["points_bounds"] = (lo.copy(), hi.copy())
        yield cloud, scan


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


# --- positions ------------------------------------------------------------------------------------------------

def _chunk_ground(pts, names) -> np.ndarray:
    """A chunk's ground labels: ``is_ground`` if the file has it, else LAS class 2
    (what :func:`~slr_ray.positions.ground_labels` reads from a whole cloud)."""
    if "is_ground" in names:
        return np.asarray(pts["is_ground"]).astype(bool)
    if "classification" in names:
        return np.asarray(pts["classification"]) == 2
    raise _unlabelled("the input has no ground labels (is_ground, classification)")


def _unlabelled(what: str) -> InputValueError:
    """The error of a streamed input without ground labels: CSF, which finds them, needs the whole cloud."""
    return InputValueError(f"{what}, and a streamed read cannot find them (CSF needs the whole cloud): read it "
                           "whole (no chunk_size), or pass labels",
                           flags={"read it whole (no chunk_size), or pass labels":
                                  "drop --chunk-size, or name them with --ground-attribute"})


#: Ground points :func:`las_positions` keeps at most (0.24 GB, and their k-d tree).
MAX_GROUND_POINTS = 10_000_000


def las_positions(path, n: int, *, seed=0, ground=None, chunk: int = DEFAULT_CHUNK, progress: bool = False,
                  max_ground_points: int = MAX_GROUND_POINTS, **options):
    """:func:`~slr_ray.positions.select_positions` on a LAS/LAZ file read in chunks.

    The grid method needs only the ground points and which cells hold any
    point. Pass 1 finds the cloud's lowest x and y and counts the ground
    points; pass 2 keeps the ground points (in file order) and the first
    point of every occupied cell (cells laid out exactly as
    :func:`~slr_ray.positions.candidate_cells` lays them from that corner).

    Up to ``max_ground_points`` ground points, the grid method on those
    points gives exactly the positions it gives on the whole cloud (same
    cells, same ground points in the same order, same draws; tested). Beyond
    it, every k-th ground point is kept (``k = ceil(ground / max)``) and
    ``min_ground_points`` is divided by k: the positions are then those of an
    evenly thinned ground, close to but not the whole cloud's (a warning says
    so), and memory stays bounded (the 10^8-point benchmark LAZ: 70 M ground
    points). The azimuth test (``profile``) scans the whole cloud per cell
    and is not offered here.

    Parameters
    ----------
    ground : (n,) bool, optional
        Labels for the whole file (default: ``is_ground``, else LAS class 2).
    **options
        :func:`~slr_ray.positions.select_positions` parameters
        (``min_ground_points``, ``cell_size``, ``allow_fewer``, ...).

    Returns
    -------
    positions : (m, 3) float64
    cells : CandidateCells
    n_points : int
        Points in the file.
    """
    if options.get("profile") is not None:
        raise InputValueError("the azimuth test (profile) scans the whole cloud per cell: not streamed")
    cell = float(options.get("cell_size", CELL_SIZE))

    def labelled(header, pts, start):
        if ground is None:
            return _chunk_ground(pts, set(header.point_format.dimension_names))
        return np.asarray(ground[start:start + len(pts)], bool)

    # pass 1: the lowest x and y (and which points hold them); the ground count
    bar = las_bar(path, "positions: pass 1", progress)
    lo, lowest, total, n_ground = _lowest_and_ground(path, chunk, labelled, bar)
    if ground is not None and len(ground) != total:
        raise InputValueError(f"ground has {len(ground)} labels for {total} points")
    if ground is None and total and not n_ground:  # a TLS scan's LAS: classification 0 throughout
        raise _unlabelled(f"{path}: its ground labels (is_ground, classification 2) mark no point as ground")
    # pass 2: ground points, the first point of each occupied cell and the lowest
    # points (so that candidate_cells finds the same corner), in file order
    if bar is not None:
        bar.close()
    corner = np.floor(lo / cell) * cell
    stride = max(1, -(-n_ground // int(max_ground_points)))
    if stride > 1:
        if options.get("min_ground_points") != "auto":  # 'auto' follows the density of what is kept
            options["min_ground_points"] = -(-int(options.get("min_ground_points", MIN_GROUND_POINTS)) // stride)
        least = options["min_ground_points"]
        warnings.warn(f"{path}: {n_ground:,} ground points; positions from every {stride}th "
                      f"(min_ground_points {least:{',' if least != 'auto' else ''}}): close to, not exactly, "
                      "those of a whole read", stacklevel=2)
    bar = las_bar(path, "positions: pass 2", progress)
    parts, labels = _ground_and_cells(path, chunk, labelled, lowest, corner, cell, stride, bar)
    if bar is not None:
        bar.close()
    pts = np.concatenate(parts) if parts else np.empty((0, 3))
    g = np.concatenate(labels) if labels else np.empty(0, bool)
    if not g.any():
        raise InputValueError(f"{path}: no point is labelled ground")
    positions, cells = select_positions(pts, g, n, seed=seed, return_cells=True, progress=progress, **options)
    return positions, cells, total


def _lowest_and_ground(path, chunk, labelled, bar) -> tuple:
    """:func:`las_positions`' pass 1: ``(lo, lowest, total, n_ground)``, the lowest x and y and which
    points hold them, the points and the ground points."""
    lo, lowest, total, n_ground = np.full(2, np.inf), np.zeros(2, np.int64), 0, 0
    for header, _, pts in las_chunks(path, chunk):
        if bar is not None:
            bar.update(len(pts))
        n_ground += int(np.count_nonzero(labelled(header, pts, total)))
        if len(pts):
            xy = las_xyz(pts)[:, :2]
            at = xy.argmin(axis=0)
            better = xy[at, [0, 1]] < lo
            lo = np.where(better, xy[at, [0, 1]], lo)
            lowest = np.where(better, at + total, lowest)
        total += len(pts)
    return lo, lowest, total, n_ground


def _ground_and_cells(path, chunk, labelled, lowest, corner, cell, stride, bar) -> tuple:
    """:func:`las_positions`' pass 2: ``(parts, labels)``, per chunk the ground points (every
    ``stride``-th), the first point of each occupied cell and the lowest points, in file order, and
    their ground labels."""
    seen, parts, labels, start, rank = set(), [], [], 0, 0
    for header, _, pts in las_chunks(path, chunk):
        if bar is not None:
            bar.update(len(pts))
        xyz = las_xyz(pts)
        g = labelled(header, pts, start)
        if stride > 1:  # every stride-th ground point of the file, by rank
            at = np.flatnonzero(g)
            g = np.zeros_like(g)
            g[at[(rank + np.arange(len(at))) % stride == 0]] = True
            rank += len(at)
        keep = g.copy()
        keep[lowest[(lowest >= start) & (lowest < start + len(pts))] - start] = True
        if len(xyz):
            ij = np.floor((xyz[:, :2] - corner) / cell).astype(np.int64)  # candidate_cells' cells
            uniq, first = np.unique(ij[:, 0] * (1 << 32) + ij[:, 1], return_index=True)
            new = np.fromiter((u not in seen for u in uniq.tolist()), bool, len(uniq))
            seen.update(uniq[new].tolist())
            keep[first[new]] = True
        parts.append(xyz[keep])
        labels.append(g[keep])
        start += len(pts)
    return parts, labels
