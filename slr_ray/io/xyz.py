"""Plain text, whitespace-separated (``.xyz``, ``.txt``): x y z, then intensity,
r, g, b (Semantic3D) or further columns as ``column_3``..."""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import FormatError
from .cloud import PointCloud
from .format import Format

__all__ = ["FORMATS"]


_SEMANTIC3D = ("intensity", "red", "green", "blue")


def _read_xyz(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # numpy's "input contained no data"
        a = np.loadtxt(path, dtype=np.float64, ndmin=2)
    if a.size == 0:
        return PointCloud(np.empty((0, 3)))
    if a.shape[1] < 3:
        raise FormatError(f"{path}: {a.shape[1]} columns, need at least x y z")
    extra = a.shape[1] - 3
    names = list(_SEMANTIC3D) if extra == 4 else ["intensity"] if extra == 1 else \
        [f"column_{j}" for j in range(3, a.shape[1])]
    return PointCloud(a[:, :3], {n: a[:, 3 + j] for j, n in enumerate(names)})


def _write_xyz(path, cloud, binary):
    """Text columns: coordinates to 1 micrometre, integer attributes exactly, float
    attributes to the digits of their dtype. Column names are not stored: a warning
    says which names a reader will not get back (it names columns by their count)."""
    n, cols, fmts, names = len(cloud), [np.asarray(cloud.points, np.float64)], ["%.6f"] * 3, []
    for k, v in cloud.attributes.items():
        v = np.asarray(v)
        v = v.reshape(n, int(np.prod(v.shape[1:], dtype=np.int64)))
        if v.dtype.kind not in "biuf":
            raise FormatError(f"{path}: .xyz holds numbers; attribute {k!r} is {v.dtype}")
        integer = v.dtype.kind in "biu"
        cols.append(v.astype(np.int64 if integer and v.dtype != np.uint64 else v.dtype if integer else np.float64))
        fmts += ["%d" if integer else "%.9g" if v.dtype.itemsize <= 4 else "%.17g"] * v.shape[1]
        names += [k] if v.shape[1] == 1 else [f"{k}[{j}]" for j in range(v.shape[1])]
        if integer and len(v) and np.abs(v.astype(np.float64)).max() > 2**53:
            warnings.warn(f"{path}: {k!r} holds integers beyond 2**53, written exactly but read back as float64 "
                          "(digits lost): write .npz or .npy to keep them", stacklevel=3)
    back = list(_SEMANTIC3D) if len(names) == 4 else ["intensity"] if len(names) == 1 else \
        [f"column_{j}" for j in range(3, 3 + len(names))]
    if names != back:
        warnings.warn(f"{path}: .xyz stores columns, not names: {names} will read back as {back}", stacklevel=3)
    data = np.empty((n, len(fmts)), object) if len(cols) > 1 else cols[0]
    if len(cols) > 1:
        j = 0
        for c in cols:
            c = c.reshape(n, int(np.prod(c.shape[1:], dtype=np.int64)))
            data[:, j:j + c.shape[1]] = c
            j += c.shape[1]
    np.savetxt(path, data, fmt=fmts)


FORMATS = (Format(".xyz", _read_xyz, _write_xyz), Format(".txt", _read_xyz, _write_xyz))
