"""Checking and normalising the arrays users pass in.

Every public entry point goes through these, so a wrong shape, dtype or a
non-finite row is reported the same way everywhere: which argument, what was
expected, what was given and, for non-finite rows, how many.
"""

from __future__ import annotations

import math
import mmap

import numpy as np
from numba import njit, prange

from .errors import InputTypeError, InputValueError

__all__ = ["json_safe", "refuse_nonfinite_rows", "as_points", "as_origin", "as_rigid_pose", "count_nonfinite_rows", "bounds", "file_mapping", "release_pages",
           "POSE_TOLERANCE", "MAX_POSE_TRANSLATION"]

#: How far a pose's rotation may be from orthonormal (largest entry of |R^T R - I|) and its
#: determinant from +1: a matrix written as text with 6 to 7 significant digits (KITTI's poses) passes.
POSE_TOLERANCE = 1e-5
#: The largest translation of a pose, metres: beyond any coordinate on Earth (UTM northings reach 1e7 m).
MAX_POSE_TRANSLATION = 1e8


def _check_real_dtype(name: str, arr: np.ndarray) -> None:
    kind = arr.dtype.kind
    if kind in "fiu":
        return
    if kind == "b":
        raise InputTypeError(f"{name} must hold real numbers, got a boolean array")
    raise InputTypeError(
        f"{name} must hold real numbers (float or int), got dtype {arr.dtype}"
    )


def as_points(points, name: str = "points", check_finite: bool = True) -> np.ndarray:
    """Return ``points`` as a C-contiguous ``(n, 3)`` float array.

    float32 and float64 are kept as they are (kernels widen to float64 before
    any arithmetic); integers are converted to float64. No copy is made when
    the input is already a contiguous float array.

    Raises
    ------
    InputTypeError
        complex, object, boolean or string data.
    InputValueError
        a shape other than ``(n, 3)``, or (with ``check_finite``) rows holding
        NaN or inf; the message gives how many.
    """
    try:
        arr = np.asarray(points)
    except (TypeError, ValueError) as exc:  # ragged lists and the like
        raise InputValueError(f"{name} must be an (n, 3) array: {exc}") from None
    _check_real_dtype(name, arr)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputValueError(f"{name} must have shape (n, 3), got {arr.shape}")
    if arr.dtype.kind in "iu":
        arr = arr.astype(np.float64)
    elif arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float64)
    arr = np.ascontiguousarray(arr)
    if check_finite:
        refuse_nonfinite_rows(count_nonfinite_rows(arr), len(arr), name)
    return arr


def refuse_nonfinite_rows(bad: int, n: int, name: str = "points",
                          then: str = "remove them first (nothing is dropped silently)") -> None:
    """The one refusal of rows holding NaN or inf: ``bad`` of ``n`` rows of ``name``
    (none: nothing happens), and what to do or what was left undone (``then``)."""
    if bad:
        raise InputValueError(f"{name} has {bad} row(s) with NaN or inf out of {n}; {then}")


def count_nonfinite_rows(points: np.ndarray) -> int:
    """Number of rows of an ``(n, 3)`` array holding a NaN or an inf."""
    if points.size == 0:
        return 0
    return int(len(points) - np.count_nonzero(np.isfinite(points).all(axis=1)))


def as_origin(origin, name: str = "origin") -> np.ndarray:
    """Return ``origin`` as a float64 array of shape ``(3,)``, finite."""
    try:
        arr = np.asarray(origin)
    except (TypeError, ValueError) as exc:
        raise InputValueError(f"{name} must be 3 numbers (x, y, z): {exc}") from None
    _check_real_dtype(name, arr)
    if arr.shape != (3,):
        raise InputValueError(f"{name} must have shape (3,), got {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise InputValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def as_rigid_pose(pose, name: str = "pose", tol: float = POSE_TOLERANCE,
                  max_translation: float = MAX_POSE_TRANSLATION) -> np.ndarray:
    """Return ``pose`` as a ``(4, 4)`` float64 rigid transform ``[[R, t], [0 0 0 1]]``, checked.

    ``R`` must be a rotation: orthonormal (every entry of ``R^T R - I``
    within ``tol``) with determinant +1 (within ``tol``; -1 is a reflection);
    the last row exactly ``0 0 0 1``; every value finite; ``|t|`` at most
    ``max_translation`` metres. A ``(3, 4)`` matrix (KITTI's poses rows) gets
    the last row added. Nothing is corrected: a matrix that fails is refused.

    Raises
    ------
    InputTypeError
        complex, object, boolean or string data.
    InputValueError
        any other failure; the message says which check and by how much.
    """
    try:
        arr = np.asarray(pose)
    except (TypeError, ValueError) as exc:
        raise InputValueError(f"{name} must be a 4 x 4 matrix: {exc}") from None
    _check_real_dtype(name, arr)
    if arr.shape == (3, 4):
        arr = np.vstack([arr, [0, 0, 0, 1]])
    if arr.shape != (4, 4):
        raise InputValueError(f"{name}: must be a 4 x 4 (or 3 x 4) matrix, got shape {arr.shape}")
    T = arr.astype(np.float64)
    if not np.isfinite(T).all():
        raise InputValueError(f"{name}: {int(np.count_nonzero(~np.isfinite(T)))} NaN or inf value(s)")
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputValueError(f"{name}: the last row must be 0 0 0 1 (a rigid pose), got "
                              f"{' '.join(repr(float(v)) for v in T[3])}")
    R, t = T[:3, :3], T[:3, 3]
    with np.errstate(all="ignore"):  # 1e300 entries: R^T R overflows to inf, which fails below
        off = float(np.abs(R.T @ R - np.eye(3)).max())
        s = np.linalg.svd(R / max(np.abs(R).max(), 1e-300), compute_uv=False) * np.abs(R).max()
    if not off <= tol:
        raise InputValueError(f"{name}: its 3 x 3 part is not a rotation (R^T R differs from I by {off:.3g} > "
                              f"{tol:g}; singular values {', '.join(f'{v:.4g}' for v in s)}: a scale, shear "
                              "or zero matrix)")
    det = float(np.linalg.det(R))
    if not abs(det - 1.0) <= tol:
        raise InputValueError(f"{name}: its 3 x 3 part has determinant {det:.4g}: a reflection, not a rotation "
                              "(a rigid pose has +1)")
    big = float(np.abs(t).max())
    norm = big * float(np.linalg.norm(t / big)) if big > 0 else 0.0  # no overflow for 1e300
    if not norm <= max_translation:
        raise InputValueError(f"{name}: its translation is {norm:.3g} m, beyond {max_translation:g} m (no place "
                              "on Earth is that far; a matrix in other units or a wrong column?)")
    return T


@njit(cache=True, nogil=True)
def _unravel_into(ids, n_columns, out):
    for j in range(ids.shape[0]):
        v = ids[j] // n_columns
        out[j, 0] = v
        out[j, 1] = ids[j] - v * n_columns


def unravel_ids(ids, n_columns: int) -> np.ndarray:
    """``(m, 2) int64`` rows ``(id // n_columns, id % n_columns)`` of non-negative
    flat ids: one integer division per id (numpy's divmod takes two)."""
    ids = np.ascontiguousarray(ids, dtype=np.int64).ravel()
    out = np.empty((len(ids), 2), dtype=np.int64)
    _unravel_into(ids, np.int64(n_columns), out)
    return out


def bounds(points) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)``, float64, of the first three columns of ``(n, >=3)`` finite
    rows, in one parallel pass (numpy's ``min(axis=0)`` on an ``(n, 3)`` array
    is ~20x slower: 2.4 s on 58 M points). Empty input: ``(+inf, -inf)``."""
    a = np.asarray(points)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    if len(a):
        chunks = max(1, min(64, len(a) // 65536))
        los = np.empty((chunks, 3))
        his = np.empty((chunks, 3))
        if len(a) < SERIAL_ROWS:  # one thread: the same pass (waking the others costs more)
            _serial_bounds(a, chunks, los, his)
        else:
            _chunk_bounds(a, chunks, los, his)
        lo, hi = los.min(axis=0), his.max(axis=0)
    return lo, hi


#: below this many rows a pass runs on one thread: a parallel region's waking and spinning threads cost
#: ~5-8 CPU ms on a loaded 2-core machine, more than the pass (0.25 ms on 125 k rows; embree-rays' meshes)
SERIAL_ROWS = 1 << 20


@njit(cache=True)
def _bounds_of_chunk(a, c, chunks, los, his):
    """Chunk ``c`` of ``chunks`` (rows ``c * n // chunks`` on) of ``a``: its per-column min and max."""
    n = a.shape[0]
    s = c * n // chunks
    e = (c + 1) * n // chunks
    for j in range(3):
        lo = np.float64(a[s, j])
        hi = lo
        for i in range(s + 1, e):
            x = np.float64(a[i, j])
            if x < lo:
                lo = x
            elif x > hi:
                hi = x
        los[c, j] = lo
        his[c, j] = hi


@njit(cache=True, parallel=True)
def _chunk_bounds(a, chunks, los, his):
    for c in prange(chunks):
        _bounds_of_chunk(a, c, chunks, los, his)


@njit(cache=True)
def _serial_bounds(a, chunks, los, his):
    """:func:`_chunk_bounds` on one thread (the same chunks, the same answer)."""
    for c in range(chunks):
        _bounds_of_chunk(a, c, chunks, los, his)


def file_mapping(a):
    """The ``mmap`` of a file that ``a`` (or the array it is a view of) lives
    in, when that mapping is shared with the file (``np.load(...,
    mmap_mode='r')``, ``np.memmap`` in mode ``'r'``, ``'r+'`` or ``'w+'``);
    else None (an in-memory array, or a copy-on-write ``'c'`` mapping, whose
    changed pages exist nowhere else)."""
    owner = a
    while isinstance(owner, np.ndarray):
        if isinstance(owner, np.memmap) and getattr(owner, "mode", "c") != "c":
            mm = getattr(owner, "_mmap", None)
            if isinstance(mm, mmap.mmap):
                return mm
        owner = owner.base
    return None


def release_pages(a) -> int:
    """Drop the resident pages of a file-mapped array from this process's
    memory (``madvise(MADV_DONTNEED)``); returns the bytes of the range
    released, 0 where ``a`` is not file-mapped (:func:`file_mapping`).

    The data does not change: the pages stay in the kernel's file cache
    while memory allows and come back on the next touch (a minor fault), or
    from the file. A mapped primary is read whole by a preparation's passes
    and by every binning scan; released afterwards it no longer counts in
    the process's resident memory while Embree builds or while the next
    stage allocates.
    """
    mm = file_mapping(a)
    if mm is None or not hasattr(mmap, "MADV_DONTNEED") or a.size == 0:
        return 0
    base = np.frombuffer(mm, np.uint8).ctypes.data
    lo, hi = np.lib.array_utils.byte_bounds(a)
    page = mmap.PAGESIZE
    start = (lo - base) // page * page
    stop = min(len(mm), -(-(hi - base) // page) * page)
    if stop <= start:
        return 0
    mm.madvise(mmap.MADV_DONTNEED, start, stop - start)
    return stop - start


def json_safe(obj):
    """``obj`` ready for strict JSON: nan and inf as None, numpy scalars as numbers,
    tuples as lists, mapping keys as strings (the one helper for every JSON written)."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
