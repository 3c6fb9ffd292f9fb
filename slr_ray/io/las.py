"""LAS and LAZ files (laspy, lazrs): :func:`read`, :func:`write` and the count checks.

:mod:`slr_ray.io` reads and writes ``.las``/``.laz`` with these; they take
and give plain arrays and any object with ``points``, ``attributes`` and
``meta`` (and a source's records: ``header``, ``evlrs``, ``array``), so this
module does not import :mod:`slr_ray.io`. Readers believe no count
(:func:`check_las_size`); writers keep a LAS source's header, records and
field types, and never wrap a value into a field too small for it.
"""

from __future__ import annotations

import copy
import io
import os
import struct
import warnings
from pathlib import Path

import lazrs
import numpy as np

from .. import lazy
from ..errors import FormatError
from .cloud import LasRecords, PointCloud
from .format import Format

#: laspy, loaded on first use (slr_ray.lazy: the command line starts without it, and without requests)
laspy = lazy.module("laspy")
laspy_vlrs = lazy.module("laspy.vlrs.vlrlist")

__all__ = ["read", "write", "check_las_size", "FORMATS"]


def check_las_size(path, header) -> None:
    """Refuse a LAS/LAZ whose header declares another count than its point
    data holds. Uncompressed: whole records left over before the EVLRs or the
    end of the file (a header that lies), or fewer records than declared (a
    truncated file, a part of a record included: laspy read what was there,
    or failed in numpy's words).
    Point data ends at the first EVLR or at LAS 1.3's internal waveform
    packets, where a file has them. LAZ: the chunk table's point counts
    (variable-size chunks: exactly; fixed-size chunks: a count that leaves
    whole chunks unread, or one larger than the table can hold, and the last
    chunk's own count, read from a layered chunk or found by decompressing a
    pointwise one: :func:`_check_last_chunk`). A LAS 1.4
    legacy count that disagrees with the 1.4 count is read past with a warning.
    A scale of 0 or not finite (every coordinate of that axis would read as
    its offset) is refused first."""
    scales = np.asarray(header.scales, np.float64)
    offsets = np.asarray(header.offsets, np.float64)
    bad = [f"{a} scale {s!r}" for a, s in zip("xyz", scales.tolist()) if not (np.isfinite(s) and s != 0)]
    bad += [f"{a} offset {o!r}" for a, o in zip("xyz", offsets.tolist()) if not np.isfinite(o)]
    if bad:
        raise FormatError(f"{path}: the LAS header's {', '.join(bad)}: its coordinates cannot be read "
                          "(a scale of 0 reads every one as the offset; a corrupt or hand-edited header)")
    if header.are_points_compressed:
        _check_laz_chunks(path, header)
    else:
        _check_las_records(path, header)
    _check_legacy_count(path, header)  # after the refusals: a file refused is not also warned about


def _check_las_records(path, header) -> None:
    """The uncompressed half of :func:`check_las_size`."""
    end = os.path.getsize(path)
    start_evlr = int(getattr(header, "start_of_first_evlr", 0) or 0)
    if getattr(header, "number_of_evlrs", 0) and header.offset_to_point_data < start_evlr <= end:
        end = start_evlr
    waveforms = int(getattr(header, "start_of_waveform_data_packet_record", 0) or 0)  # LAS 1.3+, internal
    if header.offset_to_point_data < waveforms <= end:
        end = waveforms
    data = end - int(header.offset_to_point_data)
    room, rest = divmod(max(data, 0), header.point_format.size)
    if room > header.point_count:
        raise FormatError(f"{path}: the header declares {header.point_count:,} points, the file holds "
                          f"{room:,} (a header that lies, or a corrupt file)")
    if room < header.point_count:  # laspy: points dropped quietly, or numpy's 'buffer size must be a multiple'
        raise FormatError(f"{path}: the header declares {header.point_count:,} points, the file holds "
                          f"{room:,}{f' and {rest} bytes of another' if rest else ''} (truncated, or a header "
                          "that lies)")


def _check_legacy_count(path, header) -> None:
    """Warn when a LAS 1.4 header's legacy point count (the 32-bit field that
    readers of LAS 1.3 and older use) is neither 0 nor its 64-bit count: the
    1.4 count is read (the specification's rule, and laspy's), but another
    program may read the file as holding the legacy count's points."""
    if (header.version.major, header.version.minor) < (1, 4):
        return
    with open(path, "rb") as f:
        f.seek(_LEGACY_COUNT_AT)
        raw = f.read(4)
    legacy = int.from_bytes(raw, "little") if len(raw) == 4 else 0
    if legacy and legacy != int(header.point_count):
        warnings.warn(f"{path}: the header's legacy point count ({legacy:,}) disagrees with its LAS 1.4 "
                      f"count ({int(header.point_count):,}); reading the 1.4 count (a reader of LAS 1.3 and "
                      f"older would read {legacy:,})", UserWarning, stacklevel=3)


#: byte offset of the public header's legacy "number of point records" (LAS 1.0-1.4)
_LEGACY_COUNT_AT = 107


def _check_laz_chunks(path, header) -> None:
    """Refuse a LAZ whose chunk table holds a count other than its header declares
    (:func:`check_las_size`). Files without a readable table (an old writer's)
    are left to the readers."""
    vlr = next((v for v in header.vlrs if getattr(v, "record_id", None) == 22204
                and getattr(v, "user_id", "") == "laszip encoded"), None)
    if vlr is None:
        return
    try:
        laz = lazrs.LazVlr(vlr.record_data_bytes())
        with open(path, "rb") as f:
            f.seek(int(header.offset_to_point_data))
            table = lazrs.read_chunk_table(f, laz)
    except Exception:  # noqa: BLE001  no table (an old writer), or a corrupt one: the readers decide
        return
    if not table:
        return
    declared = int(header.point_count)
    if laz.uses_variable_size_chunks():
        held = sum(int(c[0]) for c in table)
        if held != declared:
            raise FormatError(f"{path}: the header declares {declared:,} points, its LAZ chunk table holds "
                              f"{held:,} (a header that lies, or a corrupt file)")
        return
    size = int(laz.chunk_size())
    if size and declared <= (len(table) - 1) * size:
        raise FormatError(f"{path}: the header declares {declared:,} points, its LAZ chunk table holds "
                          f"{len(table):,} chunks of {size:,}: more than {(len(table) - 1) * size:,} points "
                          "(a header that lies, or a corrupt file)")
    if size and declared > len(table) * size:  # lazrs would say 'failed to fill whole buffer'
        raise FormatError(f"{path}: the header declares {declared:,} points, its LAZ chunk table holds "
                          f"{len(table):,} chunks of {size:,}: {len(table) * size:,} points at most "
                          "(truncated, or a header that lies)")
    if size:
        _check_last_chunk(path, header, laz, vlr.record_data_bytes(), table, declared - (len(table) - 1) * size)


def _check_last_chunk(path, header, laz, record_data, table, declared_last) -> None:
    """Refuse a LAZ of fixed-size chunks whose last chunk holds another count
    than the header leaves it (a lie inside the last chunk, which laspy reads
    past: points dropped, or garbage decoded). Layered chunks (LAS 1.4 point
    formats) record their count; a pointwise chunk does not, but its
    arithmetic coder ends in step with its bytes: the declared points must need
    the chunk's last byte and no byte past it (points that take no byte, exact
    repeats of the one before at the chunk's end, cannot be counted so)."""
    start = int(header.offset_to_point_data) + 8 + sum(int(c[1]) for c in table[:-1])
    nbytes = int(table[-1][1])
    psize = int(header.point_format.size)
    with open(path, "rb") as f:
        f.seek(start)
        chunk = f.read(nbytes)
    if len(chunk) < nbytes:
        return  # cut short: the readers say so
    compressor = int.from_bytes(record_data[:2], "little")
    if compressor == 3:  # layered: the raw first point, then the chunk's count
        held = int.from_bytes(chunk[psize:psize + 4], "little") if len(chunk) >= psize + 4 else None
        if held is not None and held != declared_last:
            _refuse_last_chunk(path, header, table, held, declared_last)
        return
    if compressor != 2:
        return
    stream = _ChunkStream(chunk, laz)

    def fits(k, end):  # k points decode from the chunk's first `end` bytes
        return stream.decodes(record_data, psize, k, end)

    if fits(declared_last, nbytes) and not fits(declared_last, nbytes - 1):
        return
    cap = int(laz.chunk_size())
    lo, hi = 0, cap + 1  # the fewest points that need the chunk's last byte: its count
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if fits(mid, nbytes - 1) else (lo, mid)
    _refuse_last_chunk(path, header, table, hi if hi <= cap and fits(hi, nbytes) else None, declared_last)


def _refuse_last_chunk(path, header, table, held_last, declared_last):
    full = len(table) - 1
    before = int(header.point_count) - declared_last
    last = f"{held_last:,}" if held_last is not None else "another count of"
    where = (f"{full:,} full chunks and a last one of {last} points" if full else f"one chunk of {last} points")
    held = f"{before + held_last:,}" if held_last is not None else "another count"
    raise FormatError(f"{path}: the header declares {int(header.point_count):,} points, its LAZ chunks hold "
                      f"{held} ({where}, not {declared_last:,}): a header that lies, or a corrupt file")


class _ChunkStream(io.RawIOBase):
    """One LAZ chunk as a file lazrs decompresses: the chunk-table offset,
    the chunk, a one-entry table; reads stop at ``end`` bytes of the chunk."""

    def __init__(self, chunk, laz):
        table = io.BytesIO()
        lazrs.write_chunk_table(table, [(int(laz.chunk_size()), len(chunk))], laz)
        self.data = struct.pack("<q", 8 + len(chunk)) + chunk + table.getvalue()
        self.pos, self.limit = 0, len(self.data)
        self.chunk_end = 8 + len(chunk)

    def readable(self):
        return True

    def seekable(self):
        return True

    def tell(self):
        return self.pos

    def seek(self, offset, whence=0):
        self.pos = offset if whence == 0 else self.pos + offset if whence == 1 else len(self.data) + offset
        return self.pos

    def readinto(self, buf):
        n = max(0, min(self.limit, self.pos + len(buf)) - self.pos)
        buf[:n] = self.data[self.pos:self.pos + n]
        self.pos += n
        return n

    def decodes(self, record_data, psize, k, end, batch=1 << 20) -> bool:
        """Whether ``k`` points decode from the chunk's first ``end`` bytes."""
        self.pos, self.limit = 0, len(self.data)
        try:
            dec = lazrs.LasZipDecompressor(self, record_data)  # reads the table, then returns to the chunk
            self.limit = 8 + end
            out = bytearray(min(k, batch) * psize)
            left = k
            while left:
                step = min(left, batch)
                dec.decompress_many(memoryview(out)[:step * psize])
                left -= step
        except Exception:  # noqa: BLE001  lazrs: 'failed to fill whole buffer', or garbage it cannot decode
            return False
        return True


def read(path) -> tuple:
    """A LAS/LAZ file as ``(points, attributes, meta, (header, evlrs, records))``:
    every dimension kept (extra bytes with their types); ``meta``: point format,
    scales, offsets. Counts checked both ways (:func:`check_las_size`)."""
    with laspy.open(str(path)) as reader:
        check_las_size(path, reader.header)
    las = laspy.read(str(path))
    if len(las.points) != las.header.point_count:  # laspy stops quietly where a lying header's points run out
        raise FormatError(f"{path}: the header declares {las.header.point_count:,} points, the file holds "
                          f"{len(las.points):,} (truncated or corrupt)")
    pts = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    attrs = {name: np.asarray(las.points[name]) for name in las.point_format.dimension_names  # not las[name]:
             if name not in ("X", "Y", "Z")}  # an extra dimension 'header' is a field, not LasData's header
    meta = {"las_point_format": int(las.header.point_format.id),
            "las_scales": las.header.scales.tolist(), "las_offsets": las.header.offsets.tolist()}
    return pts, attrs, meta, (las.header, list(las.evlrs or []), las.points.array)


_LAYOUT_RECORDS = {"copc"}


def write(path, cloud, src=None, compress: bool | None = None) -> None:
    """Write ``cloud`` as LAS/LAZ (``compress``; default: by the extension). From a LAS source ``src``
    (:class:`~slr_ray.io.LasRecords`, a cloud's ``meta["las"]``): the source's header, VLRs,
    EVLRs and raw records for the points kept, so version, point format, CRS,
    GPS time type and extra-byte types are those of the input; attributes
    added since (or edited) are written through the checks below. From other
    sources: LAS 1.4, and a value a standard field cannot hold exactly is
    never wrapped: floats in [0, 1] for an unsigned field are scaled to its
    full range, anything else goes to an extra dimension ``<name>_value``;
    either is said in a warning."""
    if src is not None and len(src.array) == len(cloud):
        header = copy.deepcopy(src.header)
        layout = [v for v in header.vlrs if str(v.user_id).strip().lower() in _LAYOUT_RECORDS]
        evlrs = [e for e in src.evlrs if str(e.user_id).strip().lower() not in _LAYOUT_RECORDS]
        if layout or len(evlrs) != len(src.evlrs):
            for v in layout:
                header.vlrs.remove(v)
            warnings.warn(f"{path}: COPC records dropped (they index the whole input, not this subset); "
                          "the file is a plain LAS/LAZ", stacklevel=4)
        if getattr(header, "evlrs", None) is not None:  # laspy keeps EVLRs read with the header too
            header.evlrs = laspy_vlrs.VLRList(evlrs)
        # the records given, never header.point_count (a header that lies, or 7e8 points, would be allocated);
        # read in place, and copied only when something is written into them (the caller's stay as they were)
        las = laspy.LasData(header, laspy.ScaleAwarePointRecord(src.array, header.point_format,
                                                                header.scales, header.offsets))
        las.evlrs = laspy_vlrs.VLRList(evlrs)
        moved = not all(np.array_equal(np.asarray(las[c]), cloud.points[:, i]) for i, c in enumerate("xyz"))
        have = set(las.point_format.dimension_names)
        edited = [k for k, v in cloud.attributes.items()
                  if k in have and not np.array_equal(np.asarray(las[k]), np.asarray(v))]
        if moved:
            _fit_offsets(header, cloud.points, path, *_bounds(cloud.points))
        if moved or edited:
            las.points = laspy.ScaleAwarePointRecord(src.array.copy(), header.point_format, header.scales,
                                                     header.offsets)
        if moved:
            las.x, las.y, las.z = cloud.points[:, 0], cloud.points[:, 1], cloud.points[:, 2]
        for k, v in cloud.attributes.items():
            if k in edited:
                _set_las_field(las, k, v, path)
            elif k not in have:
                _add_las_extra(las, k, v, path)
    else:
        if src is not None and (src.header.vlrs or src.evlrs):
            warnings.warn(f"{path}: the cloud's {len(cloud):,} points are not its LAS source's {len(src.array):,} "
                          "records (a cloud built anew around another's meta): written with a new header, "
                          "without the source's VLRs and EVLRs (its CRS among them)", stacklevel=4)
        fmt, version = _las_format_for(cloud)
        header = laspy.LasHeader(point_format=fmt, version=version)
        n = len(cloud)
        lo, hi = _bounds(cloud.points)  # once, for the default offsets and their check
        if "las_scales" in cloud.meta:
            header.scales = np.array(cloud.meta["las_scales"])
            header.offsets = np.array(cloud.meta["las_offsets"])
        else:
            header.scales = np.array([0.001, 0.001, 0.001])
            header.offsets = np.floor(lo) if n else np.zeros(3)
        _fit_offsets(header, cloud.points, path, lo, hi)
        # the records allocated at their size (assigning x to an empty LasData grows it by np.append)
        las = laspy.LasData(header, laspy.ScaleAwarePointRecord.zeros(n, header=header))
        las.x, las.y, las.z = cloud.points[:, 0], cloud.points[:, 1], cloud.points[:, 2]
        standard = set(header.point_format.dimension_names)
        for k, v in cloud.attributes.items():
            if k in standard:
                _set_las_field(las, k, v, path)
            else:
                _add_las_extra(las, k, v, path)
    # laspy decides compression by a path's extension and ignores do_compress: hand it a file object
    with open(path, "w+b") as f:  # as laspy opens it
        las.write(f, do_compress=Path(path).suffix.lower() == ".laz" if compress is None else bool(compress))


def _bounds(points) -> tuple:
    """Per-axis minimum and maximum (NaN where a column holds one; zeros for no points),
    column by column: numpy's ``min(axis=0)`` of an ``(n, 3)`` array is 20x slower."""
    if not len(points):
        return np.zeros(3), np.zeros(3)
    return (np.array([points[:, i].min() for i in range(3)]), np.array([points[:, i].max() for i in range(3)]))


def _fit_offsets(header, points, path, lo, hi) -> None:
    """Keep ``header``'s offsets where every coordinate fits LAS's 32-bit
    integers at its scales; elsewhere move the offset to the middle of the
    points (whole metres where they fit, else the exact middle; a warning
    names old and new: the scales, hence the precision, stay). NaN or infinite
    coordinates are a FormatError naming them, and so is a span the scale
    cannot hold at all (laspy said "Values given do not fit" in a traceback: points moved by
    sensor effects out of a source's range, or a cloud thousands of km wide).
    ``lo``, ``hi``: the points' :func:`_bounds`."""
    if not len(points):
        return
    scales = np.asarray(header.scales, float)
    offsets = np.asarray(header.offsets, float)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):  # NaN: the span below would say 'nan m'
        rows = np.flatnonzero(~np.isfinite(points).all(axis=1))
        raise FormatError(f"{path}: {len(rows):,} of {len(points):,} points have NaN or infinite coordinates "
                          f"(rows {', '.join(map(str, rows[:5]))}{', ...' if len(rows) > 5 else ''}): "
                          "LAS cannot store them; remove them first")

    def fits(off):  # laspy's own test (past edge * scale + offset: OverflowError), and the rounded integers
        return ((lo >= -(2**31) * scales + off) & (hi <= (2**31 - 1) * scales + off)
                & (np.round((lo - off) / scales) >= -(2**31)) & (np.round((hi - off) / scales) <= 2**31 - 1))

    ok = fits(offsets)
    if ok.all():
        return
    middle = (lo + hi) / 2
    new = np.where(ok, offsets, np.floor(middle))
    new = np.where(fits(new), new, middle)  # whole metres can cost up to 1 m of a span near the limit (1e-7: 429 m)
    bad = ~fits(new)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise FormatError(f"{path}: the points span {hi[i] - lo[i]:.6g} m in {'xyz'[i]}, more than LAS's 32-bit "
                          f"integers hold at its scale {scales[i]:g} (at most {scales[i] * (2**32 - 1):.6g} m)")
    warnings.warn(f"{path}: the points do not fit the LAS offsets {offsets.tolist()} at scales "
                  f"{scales.tolist()}; offsets written as {new.tolist()} (the scales, hence the precision, "
                  "are kept)", stacklevel=5)
    header.offsets = new


def _las_format_for(cloud) -> tuple[int, str]:
    """(point format, version) for a cloud that does not come from a LAS file.

    The most widely read that holds its attributes: LAS 1.2 with format 0 to 3
    (GPS time: 1, colour: 2, both: 3), unless a value needs LAS 1.4's wider
    fields (classification above 31, more than 7 returns, 2**32 points or
    more): then format 6, 7 (colour) or 8 (colour and NIR).
    """
    a = cloud.attributes
    if "las_point_format" in cloud.meta:  # recorded by an earlier LAS read
        fmt = int(cloud.meta["las_point_format"])
        return fmt, "1.4" if fmt >= 6 else "1.3" if fmt >= 4 else "1.2"  # 4, 5: waveforms, LAS 1.3

    def above(name, limit):
        v = a.get(name)
        return v is not None and np.size(v) > 0 and np.asarray(v).max() > limit

    rgb = all(c in a for c in ("red", "green", "blue"))
    wide = (len(cloud) >= 2**32 or above("classification", 31) or above("return_number", 7)
            or above("number_of_returns", 7) or "nir" in a)
    if wide:
        return (8 if "nir" in a and rgb else 7 if rgb else 6), "1.4"
    return (2 if rgb else 0) + (1 if "gps_time" in a else 0), "1.2"


def _add_las_extra(las, name, values, path):
    """An attribute as an extra dimension with its own type (arrays of up to 3 values a point)."""
    v = np.asarray(values)
    if v.dtype == bool:
        v = v.astype(np.uint8)
    if v.dtype.kind not in "iuf" or v.ndim > 2 or (v.ndim == 2 and not 1 <= v.shape[1] <= 3):
        raise FormatError(f"LAS cannot store attribute {name!r} of dtype {v.dtype} and shape {v.shape}")
    dtype = v.dtype if v.ndim == 1 else np.dtype((v.dtype, (v.shape[1],)))
    las.add_extra_dim(laspy.ExtraBytesParams(name=name, type=dtype))
    las[name] = v


def _set_las_field(las, name, values, path):
    """A standard LAS field from ``values``, exactly, or scaled / moved aside with a warning: never wrapped."""
    v = np.asarray(values)
    field_dtype = np.asarray(las[name]).dtype
    if v.dtype == bool:
        v = v.astype(np.uint8)
    if field_dtype.kind == "f" or v.size == 0:
        las[name] = v
        return
    if field_dtype == np.bool_:
        if np.isin(v, (0, 1)).all():
            las[name] = v.astype(bool)
            return
    else:
        info = np.iinfo(field_dtype)
        finite = np.isfinite(v).all() if v.dtype.kind == "f" else True
        if finite and (v.dtype.kind != "f" or np.array_equal(v, np.round(v))) and v.min() >= info.min \
                and v.max() <= info.max:
            las[name] = v.astype(field_dtype)
            return
        if v.dtype.kind == "f" and finite and info.min == 0 and v.min() >= 0 and v.max() <= 1:
            las[name] = np.round(v * info.max).astype(field_dtype)
            warnings.warn(f"{path}: {name!r} holds values in [0, 1]; written scaled by {info.max} "
                          f"to fill the LAS field's {field_dtype} range", stacklevel=5)
            return
    alt = f"{name}_value"
    warnings.warn(f"{path}: {name!r} values do not fit the LAS field ({field_dtype}); kept as extra "
                  f"dimension {alt!r}, the field left at 0", stacklevel=5)
    _add_las_extra(las, alt, v, path)


def _read_las(path):
    pts, attrs, meta, (header, evlrs, array) = read(path)
    return PointCloud(pts, attrs, None, {**meta, "las": LasRecords(header, evlrs, array)})


def _write_las(path, cloud, binary, compress=False):
    src = cloud.meta.get("las")
    write(path, cloud, src if isinstance(src, LasRecords) else None, compress=compress)


def _write_laz(path, cloud, binary):  # the format asked for, not the name's extension (-o x.dat --format laz)
    _write_las(path, cloud, binary, compress=True)


def _las_name(name: str) -> bool:
    """32 bytes at most (a LAS extra dimension's name)."""
    return 0 < len(name.encode()) <= 32


#: attribute names LAS keeps for itself (its coordinate fields, and names laspy's LasData answers itself)
_RESERVED = frozenset({"x", "y", "z", "X", "Y", "Z", "points", "header", "point_format"})
#: LAS's own one-bit fields, which take booleans as they are
_FLAGS = frozenset({"synthetic", "key_point", "withheld", "overlap", "scan_direction_flag", "edge_of_flight_line"})
FORMATS = tuple(Format(ext, _read_las, writer, reserved=_RESERVED, booleans=False, flags=_FLAGS, spellable=_las_name,
                       spelling="32 bytes at most") for ext, writer in ((".las", _write_las), (".laz", _write_laz)))
