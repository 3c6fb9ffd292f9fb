"""Ground-truth scans of meshes: what an ideal scanner records of real surfaces.

Three semantics (docs/scenes.md, "Synthetic scenes and ground truth"):

``"center"``
    One ray per pulse, through the pulse centre: the first surface hit. This
    is what a ray caster returns (pulse-centre semantics).
``"nearest"``
    The closest surface anywhere inside the pulse's pyramid (the paper's
    nearest-in-pulse rule), approximated by ``k x k`` sub-rays per pulse (plus
    the centre ray when k is even) and keeping the nearest hit. A pulse whose centre misses but whose pyramid
    clips a surface is still returned when any sub-ray hits.
``"dense"``
    The paper's method to the letter: the surfaces sampled on a regular grid
    (``spacing``, 5 mm) streamed through the binning reduction. Only for
    :class:`~slr_ray.scenes.RectangleScene` (it needs the planar polygons).

Embree works in float32. Rays are cast from the scanner with the mesh
recentred on the scanner in float64 first, and every hit is then recomputed
in float64 on the plane of the triangle it hit, so hits lie on the surface to
float64 precision wherever the scene is.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .arrays import as_origin, unravel_ids
from .core import BinTables, ranges_of
from .errors import InputValueError, refuse_memory
from .io import atomic_path
from .options import Options
from .pattern import ScanPattern, as_pattern, pulse_rays
from .progress import bar as progress_bar
from .raycast import RayScene

__all__ = ["MeshScan", "MeshOptions", "scan_mesh", "scan_mesh_to_file", "load_meshscan", "MESH_MODES"]

MESH_MODES = ("center", "nearest", "dense")


@dataclass(frozen=True, eq=False)
class MeshScan:
    """A labelled point cloud scanned from a mesh.

    Attributes
    ----------
    points : (m, 3) float64
        Hit points, in the mesh's coordinates.
    labels : (m,) int64
        Label of the face hit (the scene's ``face_labels``, or the face index).
    ranges : (m,) float64
        Distance from the origin.
    pulses : (m, 2) int64
        Pulse bin ``(v, h)``; one point per pulse. Sorted by pulse for
        ``'center'`` and ``'nearest'``; in sample order for ``'dense'``
        (sorting 10^8 points would double the memory of a primary scan).
    origin : (3,) float64
    pattern : ScanPattern
    mode : str
    seconds : float
    """

    points: np.ndarray
    labels: np.ndarray
    ranges: np.ndarray
    pulses: np.ndarray
    origin: np.ndarray
    pattern: ScanPattern
    mode: str
    seconds: float = 0.0

    def __len__(self) -> int:
        return len(self.points)

    def offsets32(self) -> np.ndarray:
        """``(m, 3) float32`` offsets from the scanner: compact storage (mm at 100 m)."""
        return (self.points - self.origin).astype(np.float32)

    def save(self, path):
        """Write compactly (npz): float32 offsets from the origin (12 bytes a
        point: 8 um at 100 m), int32 labels (4 bytes), the flat pulse id
        ``v * n_azimuth + h`` as uint32 (4 bytes), origin and pattern.
        Read back with :func:`load_meshscan`. Atomic."""
        path = Path(path)
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, offsets=self.offsets32(), labels=self.labels.astype(np.int32),
                         pulse_ids=(self.pulses[:, 0] * self.pattern.n_azimuth + self.pulses[:, 1]).astype(
                             np.uint32 if self.pattern.n_pulses < 2**32 else np.int64), origin=self.origin,
                         meta=np.array(json.dumps({"pattern": self.pattern.to_dict(), "mode": self.mode,
                                                   "seconds": self.seconds})))
        return path

    def summary(self) -> dict:
        return {"mode": self.mode, "origin": self.origin.tolist(), "pattern": self.pattern.to_dict(),
                "points_out": len(self), "pulses": self.pattern.n_pulses,
                "seconds": round(self.seconds, 6)}


def load_meshscan(path) -> "MeshScan":
    """Read a :class:`MeshScan` written by :meth:`MeshScan.save`."""
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        origin = z["origin"].astype(np.float64)
        offsets = z["offsets"].astype(np.float64)
        labels = z["labels"].astype(np.int64)
        ids = z["pulse_ids"].astype(np.int64)
    pattern = ScanPattern.from_dict(meta["pattern"])
    pulses = np.column_stack([ids // pattern.n_azimuth, ids % pattern.n_azimuth])
    ranges = np.sqrt((offsets * offsets).sum(axis=1))
    return MeshScan(offsets + origin, labels, ranges, pulses, origin, pattern, meta["mode"],
                    meta.get("seconds", 0.0))


def _check_mesh_args(scene_or_mesh, origin, pattern, mode, supersample, face_labels):
    pattern = as_pattern(pattern)
    origin = as_origin(origin)
    if mode not in MESH_MODES:
        raise InputValueError(f"mode must be one of {MESH_MODES}, got {mode!r}")
    mesh = getattr(scene_or_mesh, "mesh", scene_or_mesh)
    if face_labels is None:
        face_labels = getattr(scene_or_mesh, "face_labels", None)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    labels = np.arange(len(faces)) if face_labels is None else np.asarray(face_labels, np.int64)
    if len(labels) != len(faces):
        raise InputValueError(f"face_labels has {len(labels)} values for {len(faces)} faces")
    if mode == "nearest" and (int(supersample) != supersample or supersample < 1):
        raise InputValueError(f"supersample must be an integer >= 1, got {supersample}")
    if mode == "nearest":  # one row of pulses is the smallest batch: its k x k sub-rays, ~100 bytes each
        refuse_memory(100.0 * pattern.shape[1] * (int(supersample) ** 2 + 1),
                      f"a 'nearest' scan of {int(supersample)} x {int(supersample)} rays a pulse "
                      f"({pattern.shape[1]:,} pulses a row)", "use a smaller supersample")
    if mode == "dense":  # a capability, not a class: the scene samples its own surfaces
        if not callable(getattr(scene_or_mesh, "dense_samples", None)):
            raise InputValueError("mode='dense' needs a RectangleScene (planar polygons to sample)")
    return mesh, faces, labels, origin, pattern


@dataclass(frozen=True, eq=False)
class MeshOptions(Options):
    """How :func:`scan_mesh` samples each pulse and casts its rays.

    Attributes
    ----------
    supersample : int
        ``k`` for ``'nearest'``: k x k sub-rays per pulse at the centres of a
        k x k grid, plus the centre ray when k is even (k = 1 is ``'center'``).
        Cost grows as k^2.
    spacing : float
        Grid spacing in metres for ``'dense'``.
    face_labels : (f,) int or None
        Labels per face for a bare mesh (default: the face index).
    rays_per_batch : int
        Rays cast at once (bounds memory).
    band_pulses : int or None
        ``'dense'``: reduce in bands of whole zenith rows of at most this many
        pulses, one pass over the samples each: the tables hold one band's
        occupied pulses at a time, for the time of a pass per band. The same
        scan (tested). Occupancy is rarely even: 73 % of the 0.00576 deg
        rect-1000 primary's pulses lie within 10 deg of the horizon, so two
        equal bands did not lower its peak (18.4 GiB); bands must be narrow
        there. Default: one pass.
    """

    supersample: int = 4
    spacing: float = 0.005
    face_labels: object = None
    rays_per_batch: int = 1 << 21
    band_pulses: int | None = None


def _hit_chunks(scene_or_mesh, origin, pattern, mode, o: MeshOptions, progress=False):
    """Yield the scan chunk by chunk: (offsets (k, 3) f8, labels (k,), ranges (k,), pulses (k, 2))."""
    supersample, rays_per_batch = o.supersample, o.rays_per_batch
    mesh, faces, labels, origin, pattern = _check_mesh_args(
        scene_or_mesh, origin, pattern, mode, supersample, o.face_labels)
    if mode == "dense":
        yield from _dense_chunks(scene_or_mesh, origin, pattern, o.spacing)
        return
    k = 1 if mode == "center" else int(supersample)
    caster = RayScene.triangles(np.asarray(mesh.vertices, np.float64), faces, centre=origin)
    nv, nh = pattern.shape
    rmin, rmax = pattern.range_limits
    rows_per = max(1, rays_per_batch // (nh * k * k))
    bar = None
    if progress:
        bar = progress_bar(total=nv, desc=f"scan {mode}", unit="row")
    try:
        for r0 in range(0, nv, rows_per):
            rows = slice(r0, min(nv, r0 + rows_per))
            dirs, vv, hh = pulse_rays(pattern, rows, k)
            if k % 2 == 0:  # even k has no sub-ray through the centre: add it, so that
                # "nearest" finds every pulse "center" finds
                extra = pulse_rays(pattern, rows, 1)
                dirs, vv, hh = (np.concatenate([a, b]) for a, b in zip((dirs, vv, hh), extra))
            hits = caster.intersect(origin, dirs, exact=True)
            face, t = hits.primitives, hits.distances
            hit = (face >= 0) & (t > 0) & (t >= rmin) & (t <= rmax)
            sel = np.flatnonzero(hit)
            if k > 1 and len(sel):
                key = vv[sel] * nh + hh[sel]
                order = np.lexsort((t[sel], key))  # per pulse, the nearest sub-ray first
                key, first = key[order], np.ones(len(order), bool)
                first[1:] = key[1:] != key[:-1]
                sel = sel[order[first]]
            if bar is not None:
                bar.update(rows.stop - rows.start)
            if len(sel):
                yield (dirs[sel] * t[sel, None], labels[face[sel]], t[sel],
                       np.column_stack([vv[sel], hh[sel]]))
    finally:
        if bar is not None:
            bar.close()


def scan_mesh(scene_or_mesh, origin, pattern, mode: str = "center", options: MeshOptions | None = None, *,
              progress: bool = False, **keywords) -> MeshScan:
    """Scan a mesh (or a :class:`~slr_ray.scenes.RectangleScene`) from ``origin``.

    Parameters
    ----------
    scene_or_mesh : RectangleScene or trimesh.Trimesh
    origin : (3,) float
    pattern : ScanPattern, str or float
    mode : {'center', 'nearest', 'dense'}
        Truth semantics (module docstring).
    options : MeshOptions or dict, optional
        ``supersample``, ``spacing``, ``face_labels``, ``rays_per_batch``,
        ``band_pulses`` (:class:`MeshOptions`); each may also be given as a
        keyword (``supersample=2``).
    progress : bool
        Show a progress bar (tqdm) on stderr.

    Returns
    -------
    MeshScan
        In memory (about 56 bytes a point). For primary scans of 10^8 points
        and more, :func:`scan_mesh_to_file` streams to a compact file instead.
    """
    t0 = time.perf_counter()
    o = MeshOptions.of(options, **keywords)
    origin = as_origin(origin)
    if mode == "dense":
        _check_mesh_args(scene_or_mesh, origin, pattern, mode, o.supersample, o.face_labels)
        pattern = as_pattern(pattern)
        pts, lab, rng, pulses = _dense_scan(scene_or_mesh, origin, pattern, o.spacing, o.band_pulses)
        return MeshScan(pts, lab, rng, pulses, origin, pattern, mode, time.perf_counter() - t0)
    parts = list(_hit_chunks(scene_or_mesh, origin, pattern, mode, o, progress))
    pattern = as_pattern(pattern)
    if parts:
        # fill preallocated arrays, freeing each chunk once copied: the peak stays
        # near one copy of the scan (a 0.00576 deg dense primary is ~2.3e8 points)
        n = sum(len(p[2]) for p in parts)
        pts = np.empty((n, 3))
        lab = np.empty(n, parts[0][1].dtype)
        rng = np.empty(n)
        pulses = np.empty((n, 2), parts[0][3].dtype)
        end = n
        while parts:
            off, lb, rg, pu = parts.pop()
            start = end - len(rg)
            np.add(off, origin, out=pts[start:end])
            lab[start:end], rng[start:end], pulses[start:end] = lb, rg, pu
            end = start
            del off, lb, rg, pu
    else:
        pts, lab, rng, pulses = np.empty((0, 3)), np.empty(0, np.int64), np.empty(0), np.empty((0, 2), np.int64)
    return MeshScan(pts, lab, rng, pulses, origin, pattern, mode, time.perf_counter() - t0)


def scan_mesh_to_file(scene_or_mesh, origin, pattern, path, mode: str = "center", **options) -> dict:
    """:func:`scan_mesh`, streamed chunk by chunk into a compact file (no full scan in memory).

    The file is what :meth:`MeshScan.save` writes (20 bytes a point) and
    :func:`load_meshscan` reads; it appears complete or not at all. Options
    are those of :func:`scan_mesh`. Returns a summary (points, seconds, bytes).
    """
    t0 = time.perf_counter()
    progress = options.pop("progress", False)
    o = MeshOptions.of(options.pop("options", None), **options)
    origin = as_origin(origin)
    pattern = as_pattern(pattern)
    with _CompactWriter(path, origin, pattern, mode) as w:
        for chunk in _hit_chunks(scene_or_mesh, origin, pattern, mode, o, progress):
            w.write(*chunk)
        w.seconds = time.perf_counter() - t0
    return {"path": str(path), "mode": mode, "points_out": w.count, "seconds": round(w.seconds, 3),
            "bytes": Path(path).stat().st_size, "pattern": pattern.to_dict(), "origin": origin.tolist()}


class _CompactWriter:
    """Append scan chunks to raw temporary files, then assemble the npz of
    :meth:`MeshScan.save` (stored, not compressed) by streaming copies."""

    def __init__(self, path, origin, pattern, mode):
        self.path = Path(path)
        if not self.path.parent.is_dir():
            raise InputValueError(f"cannot write {path}: no directory {self.path.parent}")
        self.origin, self.pattern, self.mode = origin, pattern, mode
        self.dir = tempfile.TemporaryDirectory(prefix=".slr_ray_", dir=self.path.parent)
        d = Path(self.dir.name)
        self.id_dtype = np.dtype(np.uint32 if pattern.n_pulses < 2**32 else np.int64)
        self.files = {"offsets": (open(d / "offsets", "wb"), np.dtype(np.float32), (3,)),
                      "labels": (open(d / "labels", "wb"), np.dtype(np.int32), ()),
                      "pulse_ids": (open(d / "pulse_ids", "wb"), self.id_dtype, ())}
        self.count = 0
        self.seconds = 0.0

    def __enter__(self):
        return self

    def write(self, offsets, labels, ranges, pulses):
        f = self.files
        f["offsets"][0].write(np.ascontiguousarray(offsets, np.float32).tobytes())
        f["labels"][0].write(labels.astype(np.int32).tobytes())
        ids = pulses[:, 0] * self.pattern.n_azimuth + pulses[:, 1]
        f["pulse_ids"][0].write(ids.astype(self.id_dtype).tobytes())
        self.count += len(offsets)

    def __exit__(self, exc_type, exc, tb):
        try:
            for fh, _, _ in self.files.values():
                fh.close()
            if exc_type is not None:
                return False
            meta = {"pattern": self.pattern.to_dict(), "mode": self.mode, "seconds": self.seconds}
            small = {"origin": self.origin, "meta": np.array(json.dumps(meta))}
            with atomic_path(self.path) as tmp:
                with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
                    for name, (fh, dtype, tail) in self.files.items():
                        header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                                  "shape": (self.count, *tail)}
                        with zf.open(name + ".npy", "w", force_zip64=True) as out:
                            np.lib.format.write_array_header_2_0(out, header)
                            with open(fh.name, "rb") as src:
                                shutil.copyfileobj(src, out, 1 << 24)
                    for name, arr in small.items():
                        with zf.open(name + ".npy", "w") as out:
                            np.lib.format.write_array(out, arr, allow_pickle=False)
        finally:
            self.dir.cleanup()
        return False


def _dense_scan(scene, origin, pattern, spacing, band_pulses=None):
    """The dense scan's arrays, filled in place: the count is known after the
    reduction, so the second pass writes each winner straight into its row
    (no list of chunks copied at the end). Peak: the larger of the reduction's
    tables and the result plus its keys (a 0.00576 deg primary of a
    1000-rectangle scene: 2e8 points, 56 bytes each)."""
    keys, want = _dense_winners(scene, origin, pattern, spacing, band_pulses)
    n = len(want)
    pts = np.empty((n, 3))
    lab = np.empty(n, np.int64)
    rng = np.empty(n)
    start = 0
    for chunk, labels in scene.dense_samples(spacing, copy=False):
        lo, hi = np.searchsorted(want, [start, start + len(chunk)])
        if hi > lo:
            local = want[lo:hi] - start
            pts[lo:hi] = chunk[local]
            lab[lo:hi] = labels[local]
            rng[lo:hi] = ranges_of(chunk, local, origin)
        start += len(chunk)
    del want
    pulses = unravel_ids(keys, pattern.n_azimuth)
    return pts, lab, rng, pulses


#: memory allowed for the slot array of a dense scan's reduction (see BinTables)
_DENSE_SLOT_BYTES = 2 * 2**30


def _dense_winners(scene, origin, pattern, spacing, band_pulses=None):
    """Pass 1 over the dense sample stream: ``(pulse keys, sample indices)`` of the
    winners, by sample index (the reduction's tables are freed on return).

    With ``band_pulses``, the pattern is reduced in bands of whole zenith rows
    of at most that many pulses, one pass over the samples each (the tables
    hold one band's occupied pulses at a time)."""
    nv, nh = pattern.shape
    rows = nv if band_pulses is None else max(1, int(band_pulses) // nh)
    bands = [(v0 * nh, min(nv, v0 + rows) * nh) for v0 in range(0, nv, rows)]
    keys, want = [], []
    for band in bands:
        # slots up to 2 GiB: a 0.0144 deg pattern's 3.1e8 pulses (1.25 GB) bin 1.9e9 dense
        # samples in 38 s instead of 46 s through hash tables; finer patterns hash
        tables = BinTables(origin, pattern, key_range=band if len(bands) > 1 else None,
                           slot_bytes=_DENSE_SLOT_BYTES)
        for pts, _ in scene.dense_samples(spacing, copy=False):
            tables.add(pts)
        k, _, w = tables.winners(with_ranges=False, release=True)
        del tables
        keys.append(k)
        want.append(w)
    if len(bands) == 1:
        return keys[0], want[0]
    keys, want = np.concatenate(keys), np.concatenate(want)
    order = np.argsort(want, kind="stable")  # sorted runs, one per band: a merge
    return keys[order], want[order]


def _dense_chunks(scene, origin, pattern, spacing):
    """Two passes over the dense sample stream: reduce, then yield the winners chunk by chunk."""
    keys, want = _dense_winners(scene, origin, pattern, spacing)
    nh = pattern.n_azimuth
    start = 0
    for pts, lab in scene.dense_samples(spacing, copy=False):
        lo, hi = np.searchsorted(want, [start, start + len(pts)])
        if hi > lo:
            local = want[lo:hi] - start
            sel = pts[local]
            ranges = ranges_of(sel, np.arange(hi - lo), origin)
            k = keys[lo:hi]
            yield sel - origin, lab[local], ranges, np.column_stack([k // nh, k % nh])
        start += len(pts)
