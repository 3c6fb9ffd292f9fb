"""Reading and writing point clouds with every per-point attribute.

A cloud is a :class:`PointCloud`: float64 ``(n, 3)`` coordinates and a dict of
per-point arrays (intensity, colour, labels...), which :func:`subset` carries
through the indices of a scan. Formats are chosen by extension:

========  ============================================================
``.npy``  ``(n, 3)`` or ``(n, k)`` array (columns after the third become
          ``column_3``...), or a structured array with ``x, y, z`` fields
``.npz``  ``points`` ``(n, 3)`` plus any other length-``n`` arrays as
          attributes; optional ``origin`` ``(3,)``
``.ply``  ascii or binary, via plyfile; every vertex property is kept
``.las``  LAS/LAZ via laspy (lazrs): every dimension is kept (classification
``.laz``  2 is ground); coordinates to the file's scale (1 mm by default)
``.bin``  KITTI Velodyne frames: float32 x, y, z, intensity; the sensor is at
          the origin of each frame
``.xyz``  plain text, whitespace-separated: x y z, then intensity, r, g, b
``.txt``  (Semantic3D) or further columns as ``column_3``...
``.pcd``  Point Cloud Library files, ascii or binary (not binary_compressed):
          every field kept; VIEWPOINT's translation as the origin
``.e57``  via pye57: points in the global frame (each scan's pose applied),
          the pose's translation as the scanner origin; a file with several
          scans: :func:`read_e57_scans` (one cloud each)
========  ============================================================

Writes are atomic: the file appears under its name complete, or not at all.
"""

from __future__ import annotations

import os
import tempfile
import warnings
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from . import e57, las, pcd
from .las import check_las_size
from .errors import FormatError, OutputError
from .outputs import label_destinations, label_path, label_targets, part_prefix, resolve

__all__ = ["PointCloud", "LasRecords", "read_cloud", "write_cloud", "read_e57_scans", "check_format",
           "check_las_size", "label_path", "FORMATS"]

FORMATS = (".npy", ".npz", ".ply", ".las", ".laz", ".bin", ".xyz", ".txt", ".e57", ".pcd")


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


def check_format(path, fmt=None) -> str:
    """The point-cloud format of ``path`` (its extension, or ``fmt``), e.g. ``'.las'``.

    Raises
    ------
    FormatError
        for a format slr_ray cannot read and write.
    """
    if os.path.isdir(path):  # its 'extension' is nothing, or a directory name's ('unknown format .')
        raise FormatError(f"{path} is a directory, not a point-cloud file")
    ext = (fmt if fmt else Path(path).suffix).lower()
    if not ext.startswith("."):
        ext = "." + ext
    if ext not in FORMATS:
        raise FormatError(f"unknown point-cloud format {ext!r} for {path}; supported: {', '.join(FORMATS)}")
    return ext


def read_cloud(path, format: str | None = None, check_finite: bool = True, allow_empty: bool = True) -> PointCloud:
    """Read a point cloud; the format comes from the extension unless given.

    Parameters
    ----------
    check_finite : bool
        Refuse coordinates that are NaN or infinite (default), naming the file
        and how many; False reads them as they are (an organised PCD's
        no-return points, to be removed by the caller).
    allow_empty : bool
        A file of no points reads as an empty cloud (default); False refuses
        it (``FormatError: PATH: no points``), in every format alike: what the
        commands do, since an empty input is nearly always a failed export
        and a scan of it would be an empty file with exit status 0.

    Raises
    ------
    FileNotFoundError
        no such file.
    FormatError
        unknown extension, or a file that cannot be parsed (truncated, corrupt,
        a declared count that is not what the file holds), non-finite
        coordinates (unless ``check_finite=False``), a recorded scanner origin
        that is not three finite numbers, no points (with ``allow_empty=False``).
    """
    path = Path(path)
    ext = check_format(path, format)
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a directory, not a point cloud file")
    if not path.exists():
        raise FileNotFoundError(f"no such file: {path}")
    if not path.is_file():
        raise FormatError(f"{path} is not a regular file (a FIFO, a device...): slr_ray reads clouds from files")
    try:
        cloud = _READERS[ext](path)
    except FormatError:
        raise
    except Exception as exc:  # corrupt files raise anything from the parsers
        raise FormatError(f"cannot read {path} as {ext}: {type(exc).__name__}: {exc}") from exc
    pts = np.asarray(cloud.points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise FormatError(f"{path}: expected (n, 3) coordinates, got shape {pts.shape}")
    if pts.dtype.kind not in "fiu":
        raise FormatError(f"{path}: coordinates must be real numbers, got dtype {pts.dtype}")
    cloud.points = np.ascontiguousarray(pts, dtype=np.float64)
    if not allow_empty and len(pts) == 0:
        raise FormatError(f"{path}: no points")
    if check_finite:
        bad = ~np.isfinite(cloud.points).all(axis=1)
        if bad.any():
            rows = np.flatnonzero(bad)
            raise FormatError(f"{path}: {len(rows):,} of {len(pts):,} points have NaN or infinite coordinates "
                              f"(rows {', '.join(map(str, rows[:5]))}{', ...' if len(rows) > 5 else ''}): "
                              "remove them first (nothing is dropped silently)")
    for k, v in cloud.attributes.items():
        if np.ndim(v) == 0:
            raise FormatError(f"{path}: attribute {k!r} is a single value, not one a point ({len(pts)} points)")
        if len(v) != len(pts):
            raise FormatError(f"{path}: attribute {k!r} has {len(v)} values for {len(pts)} points")
    if cloud.origin is not None:
        o = np.asarray(cloud.origin)
        if o.shape != (3,) or o.dtype.kind not in "fiu" or not np.isfinite(o.astype(np.float64)).all():
            raise FormatError(f"{path}: the recorded scanner origin is not three finite numbers "
                              f"({o.tolist() if o.size <= 9 else f'shape {o.shape}'})")
        cloud.origin = o.astype(np.float64)
    return cloud


def _read_npy(path):
    with open(path, "rb") as f:
        if f.read(6) != b"\x93NUMPY":
            raise FormatError(f"{path}: not a .npy file (no NumPy header)")
    a = np.load(path, allow_pickle=False)
    if a.dtype.names:
        if not {"x", "y", "z"} <= set(a.dtype.names):
            raise FormatError(f"{path}: structured array without x, y, z fields")
        pts = np.column_stack([a["x"], a["y"], a["z"]])
        return PointCloud(pts, {n: a[n] for n in a.dtype.names if n not in ("x", "y", "z")})
    if a.ndim != 2 or a.shape[1] < 3:
        raise FormatError(f"{path}: expected an (n, 3) or wider array, got shape {a.shape}")
    return PointCloud(a[:, :3], {f"column_{j}": a[:, j] for j in range(3, a.shape[1])})


def _read_npz(path):
    with open(path, "rb") as f:
        if f.read(2) != b"PK":
            raise FormatError(f"{path}: not a .npz file (not a zip archive)")
    with np.load(path, allow_pickle=False) as z:
        if "points" not in z.files:
            raise FormatError(f"{path}: no 'points' array (has {z.files})")
        pts = z["points"]
        origin = z["origin"].astype(np.float64) if "origin" in z.files else None
        attrs = {k: z[k] for k in z.files if k not in ("points", "origin")}
    return PointCloud(pts, attrs, origin)


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
    pts = np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64)
    return PointCloud(pts, {n: np.asarray(v[n]) for n in names if n not in ("x", "y", "z")})


def _ply_text_rows(path) -> int:
    """Non-blank lines after an ASCII PLY's ``end_header``."""
    with open(path, "rb") as f:
        for line in f:
            if line.strip() == b"end_header":
                break
        return sum(1 for line in f if line.strip())


def _read_las(path):
    pts, attrs, meta, (header, evlrs, array) = las.read(path)
    return PointCloud(pts, attrs, None, {**meta, "las": LasRecords(header, evlrs, array)})


def _write_las(path, cloud, binary, compress=False):
    src = cloud.meta.get("las")
    las.write(path, cloud, src if isinstance(src, LasRecords) else None, compress=compress)


def _write_laz(path, cloud, binary):  # the format asked for, not the name's extension (-o x.dat --format laz)
    _write_las(path, cloud, binary, compress=True)


def _read_kitti(path):
    size = os.path.getsize(path)
    if size % 16:
        raise FormatError(f"{path}: {size} bytes, not a multiple of 16 (float32 x, y, z, intensity a point): "
                          "truncated, or not a KITTI .bin")
    raw = np.fromfile(path, dtype="<f4")
    a = raw.reshape(-1, 4)
    attrs = {"intensity": a[:, 3].copy()}
    lab = label_path(path)
    if lab is not None:  # SemanticKITTI: uint32, semantic class in the low 16 bits, instance in the high 16
        if os.path.getsize(lab) != 4 * len(a):
            raise FormatError(f"{lab}: {os.path.getsize(lab)} bytes, not 4 a point: not the labels for the "
                              f"{len(a)} points of {path}")
        words = np.fromfile(lab, dtype="<u4")
        if len(words) != len(a):
            raise FormatError(f"{lab}: {len(words)} labels for {len(a)} points of {path}")
        attrs["semantic"] = (words & 0xFFFF).astype(np.uint16)
        attrs["instance"] = (words >> 16).astype(np.uint16)
    return PointCloud(a[:, :3].astype(np.float64), attrs, np.zeros(3), {"labels": str(lab) if lab else None})


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


def read_e57_scans(path) -> list:
    """Every scan of an E57 file as a :class:`PointCloud` (global frame; origin =
    the scan's pose translation, None for a scan without a pose: the caller
    decides, e.g. ``--origin 0 0 0``); points flagged invalid are left out,
    their number in ``meta['e57_invalid']`` (:func:`slr_ray.e57.read_scans`)."""
    return [PointCloud(*scan) for scan in e57.read_scans(path)]


def _read_pcd(path):
    return PointCloud(*pcd.read(path))


def _read_e57(path):
    scans = read_e57_scans(path)
    if len(scans) != 1:
        raise FormatError(f"{path} holds {len(scans)} scans: read them with slr_ray.io.read_e57_scans")
    return scans[0]


_READERS = {".npy": _read_npy, ".npz": _read_npz, ".ply": _read_ply, ".las": _read_las, ".laz": _read_las,
            ".bin": _read_kitti, ".xyz": _read_xyz, ".txt": _read_xyz, ".e57": _read_e57, ".pcd": _read_pcd}


def _umask() -> int:
    """The process's umask, read without changing it where Linux allows."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)  # elsewhere: the classic read-and-restore
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; rename it to ``path`` on success,
    remove it on failure, so no half-written file is ever left under ``path``.

    A ``path`` that is a symbolic link is written *through*: the file it
    points to is replaced and the link stays. A ``path`` that exists and is
    not a regular file (a directory, a device, a FIFO) is refused with
    :class:`~slr_ray.errors.OutputError`. The temporary is named
    ``.NAME.PID@HOST.RANDOM.partEXT``, so that the next run can tell one left
    by a killed process (:func:`slr_ray.outputs.clean_stale_parts`).

    The file gets the mode a plain ``open(path, "w")`` would give it (0666
    less the umask), not the 0600 of a temporary file: colleagues on shared
    storage can read what slr_ray writes when their umask lets them.
    """
    target = resolve(path)
    if target.exists() and not target.is_file():
        raise OutputError(f"{path} is not a regular file: refusing to write it")
    fd, tmp = tempfile.mkstemp(prefix=part_prefix(target), suffix=".part" + target.suffix, dir=target.parent)
    os.fchmod(fd, 0o666 & ~_umask())
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, target)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.filename in (None, tmp, str(tmp)):
            # a writer's 'File too large' or 'No space left on device' names no file, or our temporary;
            # numpy's tofile says '76468 requested and 1024 written', without an errno
            if exc.errno is not None:
                raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from exc
            raise OSError(f"cannot write {path}: {exc} (a full disk, or a file-size limit?)") from exc
        raise


def write_cloud(path, cloud: PointCloud, format: str | None = None, binary: bool = True) -> Path:
    """Write ``cloud`` (atomically). Returns the path written.

    PLY stores coordinates as float64 (``double``) so that nothing is lost,
    and attributes with their own dtypes. ``.npy`` can only hold coordinates
    and numeric attributes of one row each (written as extra columns).
    """
    path = Path(path)
    ext = check_format(path, format)
    if not path.parent.exists():
        raise FormatError(f"cannot write {path}: directory {path.parent} does not exist")
    cloud = _storable(path, ext, cloud)  # names the format keeps for itself moved aside, before any file
    words = None
    if ext == ".bin":
        _warn_kitti_precision(path, cloud)
        if "semantic" in cloud.attributes:  # checked before anything is written
            words = _label_words(label_targets(path)[0], cloud)
    with atomic_path(path) as tmp:
        try:
            with warnings.catch_warnings(record=True) as said:
                warnings.simplefilter("always")
                _WRITERS[ext](tmp, cloud, binary)
            for w in said:  # what the writer says, about the user's file rather than our temporary one
                warnings.warn(str(w.message).replace(str(tmp), str(path)), w.category, stacklevel=2)
        except (ValueError, TypeError, OSError) as exc:
            if str(tmp) not in str(exc):
                raise
            # the user named `path`, not our temporary file: say it in their terms
            raise FormatError(str(exc).replace(str(tmp), str(path))) from exc
    if ext == ".bin":
        written = label_destinations(path) if words is not None else []  # a link's: beside it and its file
        for dest in written:
            with atomic_path(dest) as tmp:
                words.tofile(tmp)
        for stale in label_targets(path)[len(written):]:  # an older file's labels: a reader would pair them
            if stale.is_file():                            # with this .bin
                stale.unlink()
    return path


#: attribute names a format keeps for itself: written as ``NAME_value`` (LAS: its coordinate fields, and
#: names laspy's LasData answers itself; .npz: the reader's 'points' and 'origin')
_RESERVED = {".las": {"x", "y", "z", "X", "Y", "Z", "points", "header", "point_format"},
             ".npz": {"points", "origin"}, ".ply": {"x", "y", "z"}, ".pcd": {"x", "y", "z"}, ".npy": {"x", "y", "z"}}
_RESERVED[".laz"] = _RESERVED[".las"]


#: formats without a boolean type: boolean attributes are written as uint8 0/1, with a warning
_NO_BOOL = {".ply", ".pcd", ".las", ".laz"}
#: LAS's own one-bit fields, which take booleans as they are
_LAS_FLAGS = {".las": {"synthetic", "key_point", "withheld", "overlap", "scan_direction_flag", "edge_of_flight_line"}}
_LAS_FLAGS[".laz"] = _LAS_FLAGS[".las"]


def _spellable(ext, name) -> bool:
    """Whether format ``ext`` can name an attribute ``name`` (PLY, PCD: ASCII without blanks; LAS: 32 bytes)."""
    if ext in (".ply", ".pcd"):
        return name.isascii() and name.isprintable() and len(name.split()) == 1 and name == name.strip()
    if ext in (".las", ".laz"):
        return 0 < len(name.encode()) <= 32
    return True


def _storable(path, ext, cloud) -> PointCloud:
    """``cloud`` with each attribute under a name format ``ext`` can store: a name
    it reserves becomes ``NAME_value`` (said in a warning); a name it cannot
    spell is a :class:`~slr_ray.errors.FormatError`, raised before any file."""
    bad = [k for k in cloud.attributes if not _spellable(ext, k)]
    if bad:
        raise FormatError(f"{path}: {ext} cannot name attribute(s) {bad} "
                          f"({'32 bytes at most' if ext in ('.las', '.laz') else 'ASCII without blanks'}): "
                          "rename them, or write .npz")
    flags = [k for k, v in cloud.attributes.items() if np.asarray(v).dtype == np.bool_
             and ext in _NO_BOOL and k not in _LAS_FLAGS.get(ext, ())]
    if flags:
        warnings.warn(f"{path}: {ext} has no boolean type; {', '.join(map(repr, flags))} written as uint8 0/1 "
                      "(read back as uint8; .npz keeps booleans)", stacklevel=3)
    reserved = _RESERVED.get(ext, set())
    if not reserved & set(cloud.attributes):
        return cloud
    attrs, moved = {}, []
    for k, v in cloud.attributes.items():
        name = k
        while name in reserved or name in attrs or (name != k and name in cloud.attributes):
            name += "_value"
        attrs[name] = v
        if name != k:
            moved.append(f"{k!r} as {name!r}")
    warnings.warn(f"{path}: {ext} keeps these names for itself; written {', '.join(moved)}", stacklevel=3)
    return PointCloud(cloud.points, attrs, cloud.origin, cloud.meta)


def _label_words(path, cloud) -> np.ndarray:
    """SemanticKITTI labels of a KITTI ``.bin``: little-endian uint32, semantic | instance << 16."""
    sem = np.asarray(cloud.attributes["semantic"])
    inst = np.asarray(cloud.attributes.get("instance", np.zeros(len(sem), np.uint32)))
    for name, v in (("semantic", sem), ("instance", inst)):
        if v.dtype.kind not in "iu" or (len(v) and (v.min() < 0 or v.max() > 0xFFFF)):
            raise FormatError(f"{path}: SemanticKITTI {name} labels must be integers in [0, 65535]")
    return ((sem.astype(np.uint32) & 0xFFFF) | (inst.astype(np.uint32) << 16)).astype("<u4")


#: Largest coordinate error (m) a KITTI ``.bin`` (float32) may add before :func:`write_cloud` warns.
KITTI_TOLERANCE = 1e-3


def _warn_kitti_precision(path, cloud) -> None:
    """Warn when float32 storage moves a coordinate by more than :data:`KITTI_TOLERANCE`."""
    pts = np.asarray(cloud.points, np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return
    err = float(np.abs(pts.astype(np.float32).astype(np.float64) - pts).max())
    if err > KITTI_TOLERANCE:
        warnings.warn(f"{path}: KITTI .bin stores float32 coordinates: these (up to "
                      f"{np.abs(pts).max():.4g} m from 0) move by up to {err:.3g} m; write .las/.ply/.npz "
                      "to keep them, or subtract an offset first", stacklevel=3)


def _columns(cloud):
    """Coordinates and every attribute as float64 columns ``(n, 3 + k)`` (empty clouds too)."""
    n = len(cloud)
    cols = [np.asarray(cloud.points, np.float64)]
    for v in cloud.attributes.values():
        v = np.asarray(v, np.float64)
        cols.append(v.reshape(n, int(np.prod(v.shape[1:], dtype=np.int64))))
    return cols


def _exact_in_float64(v) -> bool:
    """Whether every value of dtype ``v.dtype`` is a float64 (so a plain column keeps it)."""
    return v.dtype.kind == "b" or (v.dtype.kind == "f" and v.dtype.itemsize <= 8) or \
        (v.dtype.kind in "iu" and v.dtype.itemsize <= 4)


def _write_npy(path, cloud, binary):
    """Plain float64 columns (x, y, z, then each attribute) when float64 holds every
    attribute exactly; otherwise (int64, uint64 attributes) a structured array with
    fields ``x, y, z`` and each attribute in its own dtype, so no digit is lost."""
    attrs = {k: np.asarray(v) for k, v in cloud.attributes.items()}
    if all(_exact_in_float64(v) for v in attrs.values()):
        cols = _columns(cloud)
        data = np.hstack(cols) if len(cols) > 1 else cloud.points
        lost = [k for j, (k, v) in enumerate(attrs.items()) if k != f"column_{3 + j}" or v.ndim > 1]
        if lost:  # plain columns keep every value, not the names
            warnings.warn(f"{path}: .npy columns keep values, not names: {lost} read back as column_3... "
                          "(write .npz to keep the names)", stacklevel=3)
    else:
        bad = [k for k, v in attrs.items() if v.dtype.kind not in "biuf" or k in ("x", "y", "z")]
        if bad:
            raise FormatError(f".npy cannot store attribute(s) {bad} beside x, y, z")
        data = np.empty(len(cloud), [("x", "f8"), ("y", "f8"), ("z", "f8")]
                        + [(k, v.dtype, v.shape[1:]) for k, v in attrs.items()])
        data["x"], data["y"], data["z"] = np.asarray(cloud.points, np.float64).T
        for k, v in attrs.items():
            data[k] = v
    with open(path, "wb") as f:
        np.save(f, data)


def _write_npz(path, cloud, binary):
    """``np.savez_compressed``'s layout, each array written by name: an attribute
    called ``file`` or ``allow_pickle`` is an array like any other, not a keyword."""
    arrays = {"points": cloud.points, **cloud.attributes}
    if cloud.origin is not None:
        arrays["origin"] = cloud.origin
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as z:
        for name, a in arrays.items():
            with z.open(name + ".npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(a), allow_pickle=False)


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


#: VLR/EVLR user ids that describe the file's own layout and would be wrong for a subset
def _write_kitti(path, cloud, binary):
    dropped = sorted(k for k in cloud.attributes if k not in ("intensity", "semantic", "instance"))
    if dropped:
        warnings.warn(f"{path}: KITTI .bin holds x, y, z and intensity only; not written: {dropped}",
                      stacklevel=3)
    a = np.empty((len(cloud), 4), np.float32)
    a[:, :3] = cloud.points
    a[:, 3] = cloud.attributes.get("intensity", 0.0)
    a.tofile(path)


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


_WRITERS = {".npy": _write_npy, ".npz": _write_npz, ".ply": _write_ply, ".las": _write_las, ".laz": _write_laz,
            ".bin": _write_kitti, ".xyz": _write_xyz, ".txt": _write_xyz, ".e57": e57.write,
            ".pcd": pcd.write}
