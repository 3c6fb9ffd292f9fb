"""E57 files (ASTM E2807) through pye57/libE57: :func:`read_scans` and :func:`write`.

:mod:`slr_ray.io` reads and writes ``.e57`` with these (``read_cloud``,
``read_e57_scans``, ``write_cloud``); they take and give plain arrays and
any object with ``points``, ``attributes`` and ``origin``, so this module
does not import :mod:`slr_ray.io`.
"""

from __future__ import annotations

import uuid
import warnings

import numpy as np

from ..errors import FormatError, MissingDependencyError
from .cloud import PointCloud
from .format import Format

__all__ = ["read_scans", "read_e57_scans", "write", "FORMATS"]


def _pye57():
    try:
        import pye57
    except ImportError as exc:
        raise MissingDependencyError('E57 needs pye57: pip install "slr_ray[e57]"') from exc
    return pye57


def read_scans(path) -> list:
    """Every scan of an E57 file as ``(points, attributes, origin, meta)`` (global frame; origin =
    the scan's pose translation; a pose's rotation other than the identity in
    ``meta['e57_rotation']``, 3 x 3; its quaternion as the file holds it, w x y z, in
    ``meta['e57_quaternion']``). A scan without a pose gets origin None: the
    E57 standard reads an absent pose as identity (scanner at the file's
    origin), but a missing pose is as often a lost one, so the caller decides
    (``--origin 0 0 0``). Points flagged
    invalid (``cartesianInvalidState`` != 0) hold no coordinates and are left
    out; their number is in ``meta['e57_invalid']``."""
    pye57 = _pye57()
    try:
        e57 = pye57.E57(str(path))
        out = []
        for i in range(e57.scan_count):
            raw = e57.read_scan_raw(i)
            header = e57.get_header(i)
            has_pose = bool(header.has_pose())
            quat = None
            if has_pose:
                rot = np.asarray(header.rotation_matrix, np.float64)
                origin = np.asarray(header.translation, np.float64)
                try:  # as the file holds it (w, x, y, z): the matrix above is of the quaternion normalised
                    quat = [float(e.value()) for e in header.node["pose"]["rotation"]]
                except Exception:  # no rotation: the identity
                    quat = None
            else:
                rot, origin = np.eye(3), None
            local = np.column_stack([raw["cartesianX"], raw["cartesianY"], raw["cartesianZ"]]).astype(np.float64)
            valid = np.ones(len(local), bool)
            if "cartesianInvalidState" in raw:
                valid = np.asarray(raw["cartesianInvalidState"]) == 0
            pts = local[valid] @ rot.T + (origin if origin is not None else 0.0)
            attrs = {k: np.asarray(v)[valid] for k, v in raw.items()
                     if k not in ("cartesianX", "cartesianY", "cartesianZ", "cartesianInvalidState")}
            if not valid.all():
                warnings.warn(f"{path}: scan {i} has {int((~valid).sum())} invalid points (no coordinates, "
                              "cartesianInvalidState != 0): left out", stacklevel=3)
            meta = {"e57_scan": i, "e57_invalid": int((~valid).sum()), "e57_pose": has_pose}
            if quat is not None:
                meta["e57_quaternion"] = quat
            if has_pose and not np.array_equal(rot, np.eye(3)):  # the scan's own axes (a sequence's frame)
                meta["e57_rotation"] = rot.tolist()
            out.append((pts, attrs, origin, meta))
        return out
    except FormatError:
        raise
    except Exception as exc:
        raise FormatError(f"cannot read {path} as .e57: {type(exc).__name__}: {exc}") from exc



#: E57 fields slr_ray writes from attributes of the same name (LAS colours map to these too).
_E57_COLOURS = {"red": "colorRed", "green": "colorGreen", "blue": "colorBlue"}


def write(path, cloud, binary=True):
    """E57 (libE57 via pye57): coordinates in the scan frame with the origin as the pose's
    translation; the attributes E57 defines (intensity, colorRed/Green/Blue, rowIndex,
    columnIndex; LAS red/green/blue as colours, 16-bit values scaled to 8) and no other:
    the rest are named in a warning, never written under a wrong type."""
    pye57 = _pye57()
    from pye57.e57 import SUPPORTED_POINT_FIELDS

    if len(cloud) == 0:
        raise FormatError(f"{path}: libE57 cannot write a scan of zero points; choose another format")
    origin = cloud.origin if cloud.origin is not None else np.zeros(3)
    local = cloud.points - origin
    data = {"cartesianX": local[:, 0], "cartesianY": local[:, 1], "cartesianZ": local[:, 2]}
    dropped, scaled = [], []
    for k, v in cloud.attributes.items():
        name = _E57_COLOURS.get(k, k)
        code = SUPPORTED_POINT_FIELDS.get(name)
        v = np.asarray(v)
        if code is None or name.startswith(("cartesian", "spherical")) or v.ndim != 1 or v.dtype.kind not in "biuf":
            dropped.append(k)
            continue
        if code == "B" and len(v) and v.max() > 255:  # 16-bit colours (LAS) into E57's 8 bits
            v = (v.astype(np.float64) * (255 / 65535)).round()
            scaled.append(k)
        data[name] = v.astype({"f": np.float32, "d": np.float64, "B": np.uint8, "H": np.uint16,
                               "b": np.int8}[code])
    channels = [c for c in ("colorRed", "colorGreen", "colorBlue") if c in data]
    if 0 < len(channels) < 3:  # E57 colour is three channels or none
        dropped += [k for k in cloud.attributes if _E57_COLOURS.get(k, k) in channels]
        for c in channels:
            del data[c]
    if dropped:
        warnings.warn(f"{path}: E57 has no field for {sorted(dropped)}; not written", stacklevel=3)
    if scaled:
        warnings.warn(f"{path}: 16-bit colours {sorted(scaled)} scaled to E57's 8 bits", stacklevel=3)
    e57 = pye57.E57(str(path), mode="w")
    try:
        _e57_scan(e57, data, np.asarray(origin, float))
    finally:
        e57.close()


def _e57_scan(e57, data: dict, translation) -> None:
    """Append one scan to an E57 file open for writing, coordinates in **double**
    precision (pye57's ``write_scan_raw`` stores them as float32: 3e-7 m lost at
    5 m, metres at UTM-size offsets). The rest as in pye57: guid, name, the
    limits and bounds E57 readers use, the pose (identity rotation,
    ``translation``), and the points in one compressed vector."""
    from pye57 import libe57

    f = e57.image_file
    scan = libe57.StructureNode(f)
    scan.set("guid", libe57.StringNode(f, "{%s}" % uuid.uuid4()))
    scan.set("name", libe57.StringNode(f, "slr_ray scan"))
    scan.set("description", libe57.StringNode(f, "written by slr_ray"))
    xyz = [np.ascontiguousarray(data[k], np.float64) for k in ("cartesianX", "cartesianY", "cartesianZ")]
    lo = np.array([a.min() for a in xyz])
    hi = np.array([a.max() for a in xyz])
    bounds = libe57.StructureNode(f)
    for axis, a, b in zip("xyz", lo + translation, hi + translation):
        bounds.set(f"{axis}Minimum", libe57.FloatNode(f, float(a)))
        bounds.set(f"{axis}Maximum", libe57.FloatNode(f, float(b)))
    scan.set("cartesianBounds", bounds)
    pose = libe57.StructureNode(f)
    rotation = libe57.StructureNode(f)
    for k, v in zip("wxyz", (1.0, 0.0, 0.0, 0.0)):
        rotation.set(k, libe57.FloatNode(f, v))
    pose.set("rotation", rotation)
    shift = libe57.StructureNode(f)
    for k, v in zip("xyz", translation):
        shift.set(k, libe57.FloatNode(f, float(v)))
    pose.set("translation", shift)
    scan.set("pose", pose)

    proto = libe57.StructureNode(f)
    names = ["cartesianX", "cartesianY", "cartesianZ"]
    for name, a, b in zip(names, lo, hi):
        proto.set(name, libe57.FloatNode(f, float((a + b) / 2), libe57.E57_DOUBLE, float(a), float(b)))
    if "intensity" in data:
        v = data["intensity"]
        a, b = float(v.min()), float(v.max())
        proto.set("intensity", libe57.FloatNode(f, a, libe57.E57_SINGLE, a, b))
        limits = libe57.StructureNode(f)
        limits.set("intensityMinimum", libe57.FloatNode(f, a))
        limits.set("intensityMaximum", libe57.FloatNode(f, b))
        scan.set("intensityLimits", limits)
        names.append("intensity")
    colours = ["colorRed", "colorGreen", "colorBlue"]
    if all(c in data for c in colours):
        limits = libe57.StructureNode(f)
        for c in colours:
            proto.set(c, libe57.IntegerNode(f, 0, 0, 255))
            limits.set(f"{c}Minimum", libe57.IntegerNode(f, 0))
            limits.set(f"{c}Maximum", libe57.IntegerNode(f, 255))
        scan.set("colorLimits", limits)
        names += colours
    for c in ("rowIndex", "columnIndex"):
        if c in data:
            a, b = int(data[c].min()), int(data[c].max())
            proto.set(c, libe57.IntegerNode(f, a, a, b))
            names.append(c)
    codecs = libe57.VectorNode(f, True)
    points = libe57.CompressedVectorNode(f, proto, codecs)
    scan.set("points", points)
    e57.data3d.append(scan)
    n = len(xyz[0])
    chunk = min(n, 1 << 20)
    arrays, buffers = e57.make_buffers(names, chunk)
    writer = points.writer(buffers)
    try:
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            for name in names:
                arrays[name][:m] = data[name][start:start + m]
            writer.write(m)
    finally:
        writer.close()


def read_e57_scans(path) -> list:
    """Every scan of an E57 file as a :class:`~slr_ray.io.PointCloud` (global frame; origin =
    the scan's pose translation, None for a scan without a pose: the caller
    decides, e.g. ``--origin 0 0 0``); points flagged invalid are left out,
    their number in ``meta['e57_invalid']`` (:func:`slr_ray.io.e57.read_scans`)."""
    return [PointCloud(*scan) for scan in read_scans(path)]


def _read_e57(path):
    scans = read_e57_scans(path)
    if len(scans) != 1:
        raise FormatError(f"{path} holds {len(scans)} scans: each scan is a frame of `slr-ray sequence` (a campaign), "
                          "or read them with slr_ray.io.read_e57_scans")
    return scans[0]


FORMATS = (Format(".e57", _read_e57, write),)
