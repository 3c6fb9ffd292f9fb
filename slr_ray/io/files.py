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
``.pcd``  Point Cloud Library files, ascii, binary or binary_compressed:
          every field kept (a ``ring`` field as its integers); VIEWPOINT's
          translation as the origin
``.pcd.bin``  nuScenes frames: float32 x, y, z, intensity, ring (by the
          name or ``format``, never by the byte count)
``.e57``  via pye57: points in the global frame (each scan's pose applied),
          the pose's translation as the scanner origin; a file with several
          scans: :func:`read_e57_scans` (one cloud each)
========  ============================================================

Writes are atomic: the file appears under its name complete, or not at all.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .. import lazy
from ..errors import FormatError, SlrWarning
from .atomic import atomic_path
from .cloud import PointCloud
from .formats import REGISTRY

#: laspy, loaded on first use (slr_ray.lazy: the command line starts without it, and without requests)
laspy = lazy.module("laspy")

__all__ = ["read_cloud", "write_cloud", "check_format", "field_names"]


def check_format(path, fmt=None) -> str:
    """The point-cloud format of ``path`` (its extension, or ``fmt``), e.g. ``'.las'``.

    Raises
    ------
    FormatError
        for a format slr_ray cannot read and write.
    """
    if os.path.isdir(path):  # its 'extension' is nothing, or a directory name's ('unknown format .')
        raise FormatError(f"{path} is a directory, not a point-cloud file")
    two = "".join(Path(path).suffixes[-2:]).lower()  # a two-part extension first: .pcd.bin (nuScenes)
    ext = (fmt if fmt else two if two in REGISTRY and two.count(".") == 2 else Path(path).suffix).lower()
    if not ext.startswith("."):
        ext = "." + ext
    if ext not in REGISTRY:
        raise FormatError(f"unknown point-cloud format {ext!r} for {path}; supported: {', '.join(REGISTRY)}")
    return ext


def field_names(path, fmt=None) -> frozenset | None:
    """The attribute names a file's points carry, from its header alone (LAS/LAZ dimensions, PCD
    ``FIELDS``, PLY vertex properties; x, y, z left out), or None where the header does not tell
    (another format, an unreadable header: :func:`read_cloud` says why when it reads the file)."""
    try:
        ext = check_format(path, fmt)
        if ext in (".las", ".laz"):
            with laspy.open(str(path)) as reader:
                names = list(reader.header.point_format.dimension_names)
        elif ext in (".pcd", ".ply"):
            names, end = [], {".pcd": b"DATA", ".ply": b"end_header"}[ext]
            with open(path, "rb") as f:
                for _ in range(1000):
                    words = f.readline().split()
                    if not words or words[0] == end:
                        break
                    if ext == ".pcd" and words[0].upper() == b"FIELDS":
                        names = [w.decode("ascii", "replace") for w in words[1:]]
                    elif ext == ".ply" and words[0] == b"element" and names:
                        break  # the vertex element's properties end where the next element starts
                    elif ext == ".ply" and words[0] == b"property" and words[1] != b"list":
                        names.append(words[-1].decode("ascii", "replace"))
                else:
                    return None
                if not words or (ext == ".pcd" and not names):
                    return None
        else:
            return None
    except Exception:  # noqa: BLE001 - a header that does not tell; reading the file says why
        return None
    return frozenset(names) - {"x", "y", "z", "X", "Y", "Z"}


#: Coordinates beyond this (metres; a million kilometres) are no scan's: :func:`read_cloud` refuses them
#: (UTM and Earth-centred coordinates stay under 1e7 m; 1e300 is finite, and its square overflows)
MAX_COORDINATE = 1e9

#: Coarsest coordinate resolution (metres) a file may store before :func:`read_cloud` warns. A float32
#: coordinate is rounded to the spacing of the floats around it (``np.spacing``): 7.6e-6 m at 100 m (a KITTI
#: frame, in the sensor frame: far below anything measured), but 0.5 m at 5e6 m (UTM northings). 1 mm is
#: 1/50 of the 5 cm tolerance of ``evaluate``'s F-score and well under a lidar's range noise (1-3 cm), so
#: below it the storage changes no result; above it (float32 beyond 16,384 m) results are silently coarse.
#: float64 keeps 1e-9 m at 1e7 m: never warned of.
COARSE_RESOLUTION = 1e-3


def _warn_coarse(path, pts):
    """Warn once (one line) when ``pts`` are stored in a float narrower than float64 whose spacing at the
    largest finite ``|coordinate|`` is coarser than :data:`COARSE_RESOLUTION`."""
    if pts.dtype.kind != "f" or pts.dtype.itemsize >= 8 or not len(pts):
        return
    finite = pts if np.isfinite(pts).all() else pts[np.isfinite(pts)]
    if not finite.size:
        return
    big = max(-float(finite.min()), float(finite.max()))
    res = float(np.spacing(pts.dtype.type(big)))
    if res > COARSE_RESOLUTION:
        warnings.warn(f"{path}: {pts.dtype} coordinates up to {big:.6g} m are stored to {res:g} m (the spacing "
                      f"of {pts.dtype} there): results are no finer; store float64, or subtract an offset "
                      "(a local origin) first", SlrWarning, stacklevel=3)


def read_cloud(path, format: str | None = None, check_finite: bool = True, allow_empty: bool = True) -> PointCloud:
    """Read a point cloud; the format comes from the extension unless given.

    Parameters
    ----------
    check_finite : bool
        Refuse coordinates that are NaN or infinite, or beyond
        :data:`MAX_COORDINATE` (default), naming the file and how many; False
        reads them as they are (an organised PCD's no-return points, to be
        removed by the caller).
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
        cloud = REGISTRY[ext].read(path)
    except FormatError:
        raise
    except Exception as exc:  # corrupt files raise anything from the parsers
        raise FormatError(f"cannot read {path} as {ext}: {type(exc).__name__}: {exc}") from exc
    pts = np.asarray(cloud.points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise FormatError(f"{path}: expected (n, 3) coordinates, got shape {pts.shape}")
    if pts.dtype.kind not in "fiu":
        raise FormatError(f"{path}: coordinates must be real numbers, got dtype {pts.dtype}")
    _warn_coarse(path, pts)
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
        # 1e300 is finite, and squared overflows: numpy's warnings, then noise, downstream (min and max:
        # no copy of a large cloud; the rows are looked for only when there are some)
        if len(pts) and max(-cloud.points.min(), cloud.points.max()) > MAX_COORDINATE:
            rows = np.flatnonzero((np.abs(cloud.points) > MAX_COORDINATE).any(axis=1))
            raise FormatError(f"{path}: {len(rows):,} of {len(pts):,} points have coordinates beyond "
                              f"{MAX_COORDINATE:g} m (rows {', '.join(map(str, rows[:5]))}"
                              f"{', ...' if len(rows) > 5 else ''}; the largest {np.abs(cloud.points[rows]).max():g}): "
                              "no scan's (a corrupt file, or other units?); remove them first")
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
    fmt = REGISTRY[ext]
    state = fmt.before(path, cloud) if fmt.before else None  # checked before anything is written
    with atomic_path(path) as tmp:
        try:
            with warnings.catch_warnings(record=True) as said:
                warnings.simplefilter("always")
                fmt.write(tmp, cloud, binary)
            for w in said:  # what the writer says, about the user's file rather than our temporary one
                warnings.warn(str(w.message).replace(str(tmp), str(path)), w.category, stacklevel=2)
        except (ValueError, TypeError, OSError) as exc:
            if str(tmp) not in str(exc):
                raise
            # the user named `path`, not our temporary file: say it in their terms
            raise FormatError(str(exc).replace(str(tmp), str(path))) from exc
    if fmt.after:
        fmt.after(path, state)
    return path


def _storable(path, ext, cloud) -> PointCloud:
    """``cloud`` with each attribute under a name format ``ext`` can store: a name
    it reserves becomes ``NAME_value`` (said in a warning); a name it cannot
    spell is a :class:`~slr_ray.errors.FormatError`, raised before any file."""
    fmt = REGISTRY[ext]
    bad = [k for k in cloud.attributes if not fmt.spellable(k)]
    if bad:
        raise FormatError(f"{path}: {ext} cannot name attribute(s) {bad} ({fmt.spelling}): rename them, or write .npz")
    flags = [k for k, v in cloud.attributes.items() if np.asarray(v).dtype == np.bool_
             and not fmt.booleans and k not in fmt.flags]
    if flags:
        warnings.warn(f"{path}: {ext} has no boolean type; {', '.join(map(repr, flags))} written as uint8 0/1 "
                      "(read back as uint8; .npz keeps booleans)", stacklevel=3)
    reserved = fmt.reserved
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


