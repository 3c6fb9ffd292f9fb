"""Point Cloud Library files (``.pcd``), ascii, binary and binary_compressed: :func:`read` and :func:`write`.

binary_compressed (read only): two little-endian uint32 (compressed and
uncompressed sizes), then LZF-compressed data holding each field's values for
all points in turn (column by column). A sensor's ring field (``ring``,
``laser_number``, ``channel``...) is kept as the integer attribute it is.

:mod:`slr_ray.io` reads and writes ``.pcd`` with these. They take and give
plain arrays and any object with ``points``, ``attributes`` and ``origin``,
so this module does not import :mod:`slr_ray.io`. The reader believes no
count: POINTS against WIDTH x HEIGHT and against the data, in both directions.
"""

from __future__ import annotations

import io
import warnings

import numba
import numpy as np

from ..errors import FormatError
from .cloud import PointCloud
from .format import Format, spellable_ascii

__all__ = ["read", "write", "FORMATS"]

_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
              ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}


def read(path) -> tuple:
    """A PCD file as ``(points, attributes, origin)``: every field kept; VIEWPOINT's translation as the origin."""
    with open(path, "rb") as f:
        header = {}
        while True:
            line = f.readline()
            if not line:
                raise FormatError(f"{path}: PCD header ends before DATA")
            words = line.decode("ascii", "replace").strip().split()
            if not words or words[0].startswith("#"):
                continue
            header[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                break
        body = f.read()
    try:
        fields = header["FIELDS"]
        sizes = [int(x) for x in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(x) for x in header.get("COUNT", ["1"] * len(fields))]
        n = int(header["POINTS"][0])
        if n < 0 or any(c < 1 for c in counts) or any(sz < 1 for sz in sizes):
            raise ValueError(f"POINTS {n}, SIZE {sizes}, COUNT {counts}: counts must be >= 0 and sizes >= 1")
        if not len(fields) == len(sizes) == len(types) == len(counts):
            raise ValueError(f"{len(fields)} FIELDS, {len(sizes)} SIZE, {len(types)} TYPE, {len(counts)} COUNT")
        if "WIDTH" in header and "HEIGHT" in header and int(header["WIDTH"][0]) * int(header["HEIGHT"][0]) != n:
            raise ValueError(f"WIDTH x HEIGHT = {header['WIDTH'][0]} x {header['HEIGHT'][0]} is not POINTS {n}")
        dtype = np.dtype([(name if c == 1 else name, _PCD_TYPES[(t, sz)], () if c == 1 else (c,))
                          for name, sz, t, c in zip(fields, sizes, types, counts)])
    except (KeyError, ValueError, IndexError) as exc:
        raise FormatError(f"{path}: bad PCD header ({exc})") from None
    kind = header["DATA"][0].lower()
    if kind == "ascii":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # numpy's "input contained no data"
            flat = np.loadtxt(io.BytesIO(body), ndmin=2, dtype=str)  # text: a uint64 past 2**53 stays exact
        if flat.size == 0:
            flat = np.empty((0, sum(counts)), str)
        if len(flat) != n:
            raise FormatError(f"{path}: {len(flat)} rows for POINTS {n}")
        data = np.empty(n, dtype)
        col = 0
        try:
            for name, c in zip(fields, counts):
                data[name] = _parsed(flat[:, col] if c == 1 else flat[:, col:col + c], dtype[name].base)
                col += c
        except ValueError as exc:
            raise FormatError(f"{path}: ascii data field {name!r}: {exc}") from None
    elif kind == "binary":
        if len(body) < n * dtype.itemsize:
            raise FormatError(f"{path}: truncated ({len(body)} bytes of data for POINTS {n} of "
                              f"{dtype.itemsize} bytes)")
        extra = body[n * dtype.itemsize:]
        if len(extra) >= dtype.itemsize and extra.strip(b"\0"):  # zero padding (PCL's writers pad) is no data
            raise FormatError(f"{path}: POINTS {n} declared, the data holds {len(body) // dtype.itemsize} points "
                              "(a header that lies, or a corrupt file)")
        data = np.frombuffer(body[: n * dtype.itemsize], dtype)
    elif kind == "binary_compressed":
        data = _decompressed(path, body, n, dtype)
    else:
        raise FormatError(f"{path}: PCD DATA {kind} is not supported (ascii, binary and binary_compressed are)")
    if not {"x", "y", "z"} <= set(fields):
        raise FormatError(f"{path}: no x, y, z fields")
    pts = np.column_stack([data["x"], data["y"], data["z"]])  # as stored: read_cloud warns of coarse float32
    attrs = {name: np.array(data[name]) for name in fields if name not in ("x", "y", "z") and name != "_"}
    vp = header.get("VIEWPOINT")
    origin = np.array([float(v) for v in vp[:3]]) if vp and len(vp) >= 3 else None
    return pts, attrs, origin


def _parsed(text: np.ndarray, dt: np.dtype) -> np.ndarray:
    """An ascii PCD column's words as ``dt``: integers parsed as integers (exact to 64 bits); an
    integer field a writer wrote as ``5.0`` through float."""
    if dt.kind in "iu":
        try:
            return text.astype(dt)
        except ValueError:
            return text.astype(np.float64).astype(dt)
    return text.astype(np.float64).astype(dt)


def _ascii_words(a: np.ndarray) -> np.ndarray:
    """A column's values as text that reads back to the same value: integers exact, float32 to 9
    significant digits, float64 to 17 (``%.10g`` lost a float64 timestamp's fractions of a second)."""
    if a.dtype.kind in "iu":
        return a.astype(str)
    return np.char.mod("%.9g" if a.dtype.itemsize <= 4 else "%.17g", a)


@numba.njit(cache=True)
def _lzf_decode(src, dst):  # pragma: no cover (compiled)
    """LZF (liblzf's format): returns the bytes written to ``dst``, -1 for a corrupt stream."""
    ip, op, n_in, n_out = 0, 0, len(src), len(dst)
    while ip < n_in:
        ctrl = np.int64(src[ip])
        ip += 1
        if ctrl < 32:  # a literal run of ctrl + 1 bytes
            ctrl += 1
            if op + ctrl > n_out or ip + ctrl > n_in:
                return -1
            for _ in range(ctrl):
                dst[op] = src[ip]
                op += 1
                ip += 1
        else:  # a back reference: length (ctrl >> 5) + 2, distance from the low 5 bits and the next byte
            length = ctrl >> 5
            if length == 7:
                if ip >= n_in:
                    return -1
                length += np.int64(src[ip])
                ip += 1
            if ip >= n_in:
                return -1
            ref = op - ((ctrl & 0x1F) << 8) - 1 - np.int64(src[ip])
            ip += 1
            length += 2
            if ref < 0 or op + length > n_out:
                return -1
            for _ in range(length):  # byte by byte: the reference may overlap what it writes
                dst[op] = dst[ref]
                op += 1
                ref += 1
    return op


def _decompressed(path, body: bytes, n: int, dtype: np.dtype) -> np.ndarray:
    """The points of a binary_compressed body (module docstring), as a structured array."""
    if len(body) < 8:
        raise FormatError(f"{path}: binary_compressed data shorter than its two sizes")
    packed, unpacked = (int(v) for v in np.frombuffer(body[:8], "<u4"))
    if packed > len(body) - 8:
        raise FormatError(f"{path}: truncated (binary_compressed: {len(body) - 8} bytes of {packed} compressed)")
    if unpacked != n * dtype.itemsize:
        raise FormatError(f"{path}: binary_compressed holds {unpacked} bytes uncompressed, POINTS {n} of "
                          f"{dtype.itemsize} bytes need {n * dtype.itemsize}")
    raw = np.empty(unpacked, np.uint8)
    got = _lzf_decode(np.frombuffer(body, np.uint8, packed, 8), raw) if unpacked else 0
    if got != unpacked:
        raise FormatError(f"{path}: corrupt binary_compressed data (LZF gave {got} of {unpacked} bytes)")
    data = np.empty(n, dtype)
    at = 0
    for name in dtype.names:  # column by column: all points' values of one field, then the next
        sub = dtype.fields[name][0]
        size = n * sub.itemsize
        data[name] = np.frombuffer(raw[at:at + size].tobytes(), sub.base, n * max(1, int(np.prod(sub.shape)))
                                   ).reshape((n,) + sub.shape)
        at += size
    return data


def write(path, cloud, binary: bool = True) -> None:
    """``cloud`` (``points``, ``attributes``, ``origin``) as PCD v0.7, binary or ascii."""
    names, arrays = ["x", "y", "z"], [cloud.points[:, 0], cloud.points[:, 1], cloud.points[:, 2]]
    for k, v in cloud.attributes.items():
        v = np.asarray(v)
        if v.ndim not in (1, 2) or v.dtype.kind not in "iufb" or v.ndim == 2 and v.shape[1] < 1:
            raise FormatError(f"PCD cannot store attribute {k!r} of dtype {v.dtype} and shape {v.shape}")
        names.append(k)  # (n, c): one field of COUNT c, as PCL's descriptors
        arrays.append(v.astype(np.uint8) if v.dtype == bool else v)
    dtype = np.dtype([(nm, a.dtype, a.shape[1:]) for nm, a in zip(names, arrays)])
    data = np.empty(len(cloud), dtype)
    for nm, a in zip(names, arrays):
        data[nm] = a
    kind = {"f": "F", "i": "I", "u": "U"}
    o = cloud.origin if cloud.origin is not None else np.zeros(3)
    header = "\n".join([
        "# .PCD v0.7 - Point Cloud Data file format (slr_ray)", "VERSION 0.7",
        "FIELDS " + " ".join(names), "SIZE " + " ".join(str(a.dtype.itemsize) for a in arrays),
        "TYPE " + " ".join(kind[a.dtype.kind] for a in arrays), "COUNT " + " ".join(str(a.shape[1]) if a.ndim == 2 else "1" for a in arrays),
        f"WIDTH {len(cloud)}", "HEIGHT 1", "VIEWPOINT " + " ".join(repr(float(x)) for x in o) + " 1 0 0 0",
        f"POINTS {len(cloud)}", "DATA " + ("binary" if binary else "ascii")]) + "\n"
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        if binary:
            f.write(data.astype(data.dtype.newbyteorder("<")).tobytes())
        else:
            columns = [_ascii_words(col) for a in arrays for col in (a.T if a.ndim == 2 else [a])]
            if len(cloud):
                rows = columns[0]
                for words in columns[1:]:
                    rows = np.char.add(np.char.add(rows, " "), words)
                f.write(("\n".join(rows.tolist()) + "\n").encode("ascii"))


def _read_pcd(path):
    return PointCloud(*read(path))


FORMATS = (Format(".pcd", _read_pcd, write, reserved=frozenset({"x", "y", "z"}), booleans=False,
                  spellable=spellable_ascii, spelling="ASCII without blanks"),)
