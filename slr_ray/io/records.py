"""Files of little-endian float32 records, a fixed number of floats a point (KITTI's ``.bin``,
nuScenes' ``.pcd.bin``): read whole, a size that no whole number of records fills refused naming
the layout, and the other layout where the size would fit it."""

from __future__ import annotations

import os

import numpy as np

from ..errors import FormatError

__all__ = ["float_records"]


def float_records(path, fields: tuple, what: str, other: tuple = ()) -> np.ndarray:
    """``(n, len(fields))`` float32 records of the file at ``path`` (``fields``: their names, for the
    message; ``what``: the layout, "a KITTI .bin"). ``other``: ``(floats a point, hint)`` of another
    layout, whose hint the refusal adds where the size is a multiple of its record."""
    width = len(fields)
    size = os.path.getsize(path)
    if size % (4 * width):
        hint = other[1] if other and size % (4 * other[0]) == 0 else ""
        raise FormatError(f"{path}: {size} bytes, not a multiple of {4 * width} (float32 {', '.join(fields)} a "
                          f"point): truncated, or not {what}" + hint)
    return np.fromfile(path, dtype="<f4").reshape(-1, width)
