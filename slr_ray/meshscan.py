"""Ground-truth scans of meshes: what an ideal scanner records of real surfaces.

Three semantics (DESIGN §2):

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

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .arrays import as_origin
from .backends.binning import default_threads
from .errors import InputValueError, MissingDependencyError
from .pattern import ScanPattern

__all__ = ["MeshScan", "scan_mesh", "MESH_MODES"]

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
        Pulse bin ``(v, h)``; one point per pulse, sorted by pulse.
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

    def summary(self) -> dict:
        return {"mode": self.mode, "origin": self.origin.tolist(), "pattern": self.pattern.to_dict(),
                "points_out": len(self), "pulses": self.pattern.n_pulses,
                "seconds": round(self.seconds, 6)}


def _embree():
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as exc:  # pragma: no cover - embreex is a dependency
        raise MissingDependencyError(
            "ray casting needs embreex: pip install embreex") from exc
    return rtcore_scene, TriangleMesh


class _Caster:
    """An Embree scene of a mesh, recentred on one point, with float64 refinement."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, centre: np.ndarray):
        rtcore_scene, TriangleMesh = _embree()
        self.centre = centre
        self.v = vertices - centre
        self.faces = faces
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self.scene, self.v.astype(np.float32), faces.astype(np.int32))
        a, b, c = (self.v[faces[:, j]] for j in range(3))
        n = np.cross(b - a, c - a)
        self.normals = n
        self.plane_d = np.einsum("ij,ij->i", n, a)

    def cast(self, origin_local: np.ndarray, dirs: np.ndarray):
        """(face, t) per ray; face -1 on a miss, t in float64 on the face's plane."""
        o32 = np.broadcast_to(origin_local.astype(np.float32), dirs.shape).copy()
        d32 = dirs.astype(np.float32)
        face = np.empty(len(dirs), np.int32)
        # embreex releases the GIL while casting: split the rays over the cores
        n_threads = min(default_threads(), max(1, len(dirs) // 100_000))
        if n_threads > 1:
            bounds = np.linspace(0, len(dirs), n_threads + 1).astype(int)

            def run(i):
                a, b = bounds[i], bounds[i + 1]
                face[a:b] = self.scene.run(o32[a:b], d32[a:b])

            with ThreadPoolExecutor(n_threads) as pool:
                list(pool.map(run, range(n_threads)))
        else:
            face[:] = self.scene.run(o32, d32)
        face = face.astype(np.int64)
        t = np.full(len(dirs), np.inf)
        hit = face >= 0
        f = face[hit]
        nd = np.einsum("ij,ij->i", self.normals[f], dirs[hit])
        t[hit] = (self.plane_d[f] - self.normals[f] @ origin_local) / nd
        return face, t


def _pulse_grid(pattern: ScanPattern, rows: slice, k: int):
    """Directions of k x k sub-rays for every pulse of zenith rows ``rows``."""
    d_theta, d_phi, th0, th1 = pattern.radians
    nh = pattern.n_azimuth
    v = np.arange(rows.start, rows.stop)
    sub = (np.arange(k) + 0.5) / k
    theta = th0 + (v[:, None] + sub[None, :]).ravel() * d_theta  # (rows * k)
    theta = np.minimum(theta, th1)
    phi = ((np.arange(nh)[:, None] + sub[None, :]).ravel() * d_phi)  # (nh * k)
    phi = np.minimum(phi, 2 * np.pi)
    st, ct = np.sin(theta), np.cos(theta)
    dirs = np.empty((len(theta), len(phi), 3))
    dirs[..., 0] = st[:, None] * np.cos(phi)[None, :]
    dirs[..., 1] = st[:, None] * np.sin(phi)[None, :]
    dirs[..., 2] = ct[:, None]
    vv = np.repeat(v, k)[:, None] * np.ones(len(phi), np.int64)[None, :]
    hh = np.repeat(np.arange(nh), k)[None, :] * np.ones(len(theta), np.int64)[:, None]
    return dirs.reshape(-1, 3), vv.ravel(), hh.ravel()


def scan_mesh(scene_or_mesh, origin, pattern, mode: str = "center", *, supersample: int = 4,
              spacing: float = 0.005, face_labels=None, rays_per_batch: int = 1 << 21,
              progress: bool = False) -> MeshScan:
    """Scan a mesh (or a :class:`~slr_ray.scenes.RectangleScene`) from ``origin``.

    Parameters
    ----------
    scene_or_mesh : RectangleScene or trimesh.Trimesh
    origin : (3,) float
    pattern : ScanPattern, str or float
    mode : {'center', 'nearest', 'dense'}
        Truth semantics (module docstring).
    supersample : int
        ``k`` for ``'nearest'``: k x k sub-rays per pulse at the centres of a
        k x k grid, plus the centre ray when k is even (k = 1 is ``'center'``).
        Cost grows as k^2.
    spacing : float
        Grid spacing in metres for ``'dense'``.
    face_labels : (f,) int, optional
        Labels per face for a bare mesh (default: the face index).
    rays_per_batch : int
        Rays cast at once (bounds memory).
    progress : bool
        Show a progress bar (tqdm) on stderr.

    Returns
    -------
    MeshScan
    """
    from .scan import _check_pattern

    pattern = _check_pattern(pattern)
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
    t0 = time.perf_counter()
    if mode == "dense":
        out = _scan_dense(scene_or_mesh, origin, pattern, spacing)
        return MeshScan(*out, origin, pattern, mode, time.perf_counter() - t0)
    k = 1 if mode == "center" else int(supersample)
    if k < 1:
        raise InputValueError(f"supersample must be >= 1, got {supersample}")
    caster = _Caster(np.asarray(mesh.vertices, np.float64), faces, origin)
    local = np.zeros(3)
    nv, nh = pattern.shape
    rows_per = max(1, rays_per_batch // (nh * k * k))
    parts = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=nv, unit="row", desc=f"scan {mode}", leave=False)
    for r0 in range(0, nv, rows_per):
        rows = slice(r0, min(nv, r0 + rows_per))
        dirs, vv, hh = _pulse_grid(pattern, rows, k)
        if k % 2 == 0:  # even k has no sub-ray through the centre: add it, so that
            # "nearest" finds every pulse "center" finds
            extra = _pulse_grid(pattern, rows, 1)
            dirs, vv, hh = (np.concatenate([a, b]) for a, b in zip((dirs, vv, hh), extra))
        face, t = caster.cast(local, dirs)
        hit = (face >= 0) & (t > 0)
        rmin, rmax = pattern.range_limits
        hit &= (t >= rmin) & (t <= rmax)
        if hit.any():
            sel = np.flatnonzero(hit)
            if k > 1:
                key = vv[sel] * nh + hh[sel]
                order = np.lexsort((t[sel], key))  # per pulse, the nearest sub-ray first
                key, first = key[order], np.ones(len(order), bool)
                first[1:] = key[1:] != key[:-1]
                sel = sel[order[first]]
            parts.append((sel, dirs[sel] * t[sel, None], face[sel], t[sel], vv[sel], hh[sel]))
        if bar is not None:
            bar.update(rows.stop - rows.start)
    if bar is not None:
        bar.close()
    if parts:
        pts = np.vstack([p[1] for p in parts]) + origin
        lab = labels[np.concatenate([p[2] for p in parts])]
        rng = np.concatenate([p[3] for p in parts])
        pulses = np.column_stack([np.concatenate([p[4] for p in parts]),
                                  np.concatenate([p[5] for p in parts])])
    else:
        pts, lab, rng, pulses = np.empty((0, 3)), np.empty(0, np.int64), np.empty(0), np.empty((0, 2), np.int64)
    return MeshScan(pts, lab, rng, pulses, origin, pattern, mode, time.perf_counter() - t0)


def _scan_dense(scene, origin, pattern, spacing):
    from .accumulator import ScanAccumulator
    from .scenes import RectangleScene, dense_samples

    if not isinstance(scene, RectangleScene):
        raise InputValueError("mode='dense' needs a RectangleScene (planar polygons to sample)")
    acc = ScanAccumulator(origin, pattern)
    for pts, _ in dense_samples(scene, spacing):
        acc.add(pts)
    res = acc.result()
    # second pass: pick the winners' coordinates and labels out of the same stream
    want = res.indices
    pts_out = np.empty((len(want), 3))
    lab_out = np.empty(len(want), np.int64)
    start = 0
    for pts, lab in dense_samples(scene, spacing):
        lo, hi = np.searchsorted(want, [start, start + len(pts)])
        local = want[lo:hi] - start
        pts_out[lo:hi] = pts[local]
        lab_out[lo:hi] = lab[local]
        start += len(pts)
    order = np.lexsort((res.pulses[:, 1], res.pulses[:, 0]))
    return pts_out[order], lab_out[order], res.ranges[order], res.pulses[order]
