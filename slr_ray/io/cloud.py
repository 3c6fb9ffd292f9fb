"""The point cloud every reader returns and every writer takes: :class:`PointCloud`
(float64 coordinates and per-point attributes), and a LAS file's records beside it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["PointCloud", "LasRecords", "gather"]


@dataclass
class PointCloud:
    """Coordinates and per-point attributes.

    Attributes
    ----------
    points : (n, 3) float64
    attributes : dict of str -> (n, ...) array
    origin : (3,) float64 or None
        Scanner position, where the file records one.
    """

    points: np.ndarray
    attributes: dict = field(default_factory=dict)
    origin: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, indices) -> "PointCloud":
        """The cloud restricted to ``indices``, every attribute (and a LAS file's raw records) following."""
        return PointCloud(
            gather(self.points, indices),
            {k: gather(v, indices) for k, v in self.attributes.items()},
            self.origin,
            {k: (v.subset(indices) if isinstance(v, LasRecords) else v) for k, v in self.meta.items()},
        )


def gather(values, indices):
    """``values[indices]`` along the first axis: rows of an ``(n, k)`` array by
    ``np.take``, three times as fast as fancy indexing for the (n, 3)
    coordinates of a scan (same values; a boolean mask or a slice indexes as usual)."""
    idx = np.asarray(indices) if not isinstance(indices, slice) else None
    if idx is None or idx.dtype.kind not in "iu" or idx.ndim != 1 or not isinstance(values, np.ndarray):
        return values[indices]
    return np.take(values, idx, axis=0)


@dataclass
class LasRecords:
    """What a LAS/LAZ file holds beyond coordinates and attributes, kept so that
    writing a subset of it to LAS/LAZ loses nothing: the header (version, point
    format, scales and offsets, global encoding: GPS time type, WKT flag; every
    VLR, CRS included), the EVLRs, and the raw point records (coordinates as
    stored integers, every standard field and extra byte with its own type).

    ``read_cloud`` puts one in ``PointCloud.meta["las"]``;
    :meth:`PointCloud.subset` subsets its records with the points.
    """

    header: object
    evlrs: list
    array: np.ndarray

    def subset(self, indices) -> "LasRecords":
        return LasRecords(self.header, self.evlrs, gather(self.array, indices))
