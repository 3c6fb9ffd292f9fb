"""PLY, ascii or binary, via plyfile: every vertex property is kept; coordinates as float64."""

from __future__ import annotations

import os

import numpy as np
from plyfile import PlyData, PlyElement

from ..errors import FormatError
from .cloud import PointCloud
from .format import Format, spellable_ascii

__all__ = ["FORMATS"]


def _read_ply(path):
    with open(path, "rb") as f:
        ply = PlyData.read(f)
        if not ply.text:  # binary: the declared elements end where the file does
            extra = os.fstat(f.fileno()).st_size - f.tell()
    if ply.text:
        extra = _ply_text_rows(path) - sum(e.count for e in ply.elements)
    if "vertex" not in ply:
        raise FormatError(f"{path}: no vertex element")
    if extra > 0 and (ply.text or all(not hasattr(p, "len_dtype") for e in ply.elements for p in e.properties)):
        size = ply["vertex"].data.dtype.itemsize
        if ply.text or extra >= size:  # a partial record of padding is tolerated, whole ones are not
            raise FormatError(f"{path}: the header declares {ply['vertex'].count:,} vertices, the file holds "
                              f"{'%d more rows' % extra if ply.text else '%d more bytes' % extra} after its "
                              "declared elements (a header that lies, or a corrupt file)")
    v = ply["vertex"].data
    names = v.dtype.names
    if not {"x", "y", "z"} <= set(names):
        raise FormatError(f"{path}: vertex element lacks x, y, z")
    pts = np.column_stack([v["x"], v["y"], v["z"]])  # as stored: read_cloud warns of coarse float32
    return PointCloud(pts, {n: np.asarray(v[n]) for n in names if n not in ("x", "y", "z")})


def _ply_text_rows(path) -> int:
    """Non-blank lines after an ASCII PLY's ``end_header``."""
    with open(path, "rb") as f:
        for line in f:
            if line.strip() == b"end_header":
                break
        return sum(1 for line in f if line.strip())


def _write_ply(path, cloud, binary):
    fields = [("x", "f8"), ("y", "f8"), ("z", "f8")]
    for k, v in cloud.attributes.items():
        v = np.asarray(v)
        if v.ndim != 1:
            raise FormatError(f"PLY attributes must be one value per point; {k!r} has shape {v.shape}")
        dt = v.dtype
        if dt == np.bool_:
            dt = np.dtype(np.uint8)
        if dt == np.int64:
            dt = np.dtype(np.int32) if (len(v) == 0 or np.abs(v).max() < 2**31) else dt
        if dt.kind not in "iuf" or dt.itemsize > 8 or dt == np.int64 or dt == np.uint64:
            raise FormatError(f"PLY cannot store attribute {k!r} of dtype {v.dtype}")
        fields.append((k, dt.str))
    data = np.empty(len(cloud), dtype=fields)
    data["x"], data["y"], data["z"] = cloud.points.T
    for k, v in cloud.attributes.items():
        data[k] = v
    PlyData([PlyElement.describe(data, "vertex")], text=not binary).write(str(path))


FORMATS = (Format(".ply", _read_ply, _write_ply, reserved=frozenset({"x", "y", "z"}), booleans=False,
                  spellable=spellable_ascii, spelling="ASCII without blanks"),)
