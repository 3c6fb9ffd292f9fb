"""Positions on a LAS/LAZ file larger than memory: :func:`las_positions`, the
grid method on the ground points and occupied cells gathered in two passes of
chunks (read by :mod:`slr_ray.io.streaming`).

The streamed scans themselves live in :mod:`slr_ray.io.streaming`; their
names (:func:`scan_las`, :func:`scan_las_many`, :func:`las_bounds`,
:data:`STREAMED_FORMATS`, :data:`DEFAULT_CHUNK`) are kept here too, the
module's path before the input/output package.
"""

from __future__ import annotations

import warnings

import numpy as np

from .errors import InputValueError
from .io.streaming import DEFAULT_CHUNK, STREAMED_FORMATS, las_bar, las_bounds, las_chunks, las_xyz, scan_las, \
    scan_las_many
from .paper import CELL_SIZE, MIN_GROUND_POINTS
from .positions import select_positions

__all__ = ["las_positions", "MAX_GROUND_POINTS", "scan_las", "las_bounds", "scan_las_many", "STREAMED_FORMATS",
           "DEFAULT_CHUNK"]


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
    lo, lowest, total, n_ground = np.full(2, np.inf), np.zeros(2, np.int64), 0, 0
    bar = las_bar(path, "positions: pass 1", progress)
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
        options["min_ground_points"] = -(-int(options.get("min_ground_points", MIN_GROUND_POINTS)) // stride)
        warnings.warn(f"{path}: {n_ground:,} ground points; positions from every {stride}th "
                      f"(min_ground_points {options['min_ground_points']:,}): close to, not exactly, "
                      "those of a whole read", stacklevel=2)
    seen, parts, labels, start, rank = set(), [], [], 0, 0
    bar = las_bar(path, "positions: pass 2", progress)
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
    if bar is not None:
        bar.close()
    pts = np.concatenate(parts) if parts else np.empty((0, 3))
    g = np.concatenate(labels) if labels else np.empty(0, bool)
    if not g.any():
        raise InputValueError(f"{path}: no point is labelled ground")
    positions, cells = select_positions(pts, g, n, seed=seed, return_cells=True, progress=progress, **options)
    return positions, cells, total
