"""Synthetic rectangle scenes (the paper's Experiment 1), built as meshes.

The paper samples every surface on a 5 mm grid (about 9.5e8 points a scene).
As a mesh the same scene is a few thousand triangles, and a scan of it is
exact ray casting (:func:`slr_ray.scan_mesh`) or, to follow the paper to the
letter, a dense grid streamed through the binning reduction
(:func:`dense_samples`), never held in memory at once.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit

from . import lazy
from .effects import Effects
from .errors import InputValueError, refuse_memory
from .paper import SCANNER_HEIGHT

#: trimesh, loaded on first use (slr_ray.lazy: the command line starts without it)
trimesh = lazy.module("trimesh")
#: scipy.spatial.transform, loaded on first use (slr_ray.lazy)
spatial_transform = lazy.module("scipy.spatial.transform")

__all__ = ["RectangleScene", "rectangle_scene", "load_scene_spec", "scene_from_spec", "scene_effects",
           "dense_samples", "SCENES_DIR", "MESH_FORMATS"]

#: Mesh files a scene can be written to (trimesh's exporters).
MESH_FORMATS = ("ply", "obj", "stl", "glb", "off")

#: Directory of the scene specs and validation configs: those shipped in the
#: package (``slr_ray/data/scenes``, also ``scenes/`` of the source tree), or
#: ``$SLR_RAY_SCENES`` when set. Any spec can also be given by path.
SCENES_DIR = (Path(os.environ["SLR_RAY_SCENES"]) if os.environ.get("SLR_RAY_SCENES")
              else Path(__file__).resolve().parent / "data" / "scenes")


@dataclass
class RectangleScene:
    """A ground disc and planar rectangles.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        All surfaces, triangulated (ground first).
    face_labels : (f,) int64
        0 for ground, ``k >= 1`` for rectangle ``k`` (numbered as drawn).
    polygons : list of (p, 3) float64
        Each present rectangle after clipping, as a convex polygon.
    polygon_labels : (q,) int64
        Label of each polygon.
    n_rectangles : int
        Rectangles drawn.
    n_present : int
        Rectangles at least partly above the ground and inside the disc.
    params : dict
        The parameters that built the scene.
    """

    mesh: object
    face_labels: np.ndarray
    polygons: list
    polygon_labels: np.ndarray
    n_rectangles: int
    n_present: int
    params: dict = field(default_factory=dict)

    def dense_samples(self, spacing: float = 0.005, chunk: int = 1 << 22, copy: bool = True):
        """:func:`dense_samples` of this scene: what a dense mesh scan (``scan_mesh(..., mode='dense')``)
        asks of a scene, so that :mod:`slr_ray.meshscan` needs no scene class."""
        return dense_samples(self, spacing, chunk, copy)

    def info(self) -> dict:
        return {
            "n_rectangles": self.n_rectangles,
            "n_present": self.n_present,
            "n_faces": int(len(self.mesh.faces)),
            "surface_area_m2": float(self.mesh.area),
            **{k: v for k, v in self.params.items() if k != "n_rectangles"},
        }


def _clip(poly: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Sutherland-Hodgman: keep the part of a convex polygon where n.p >= offset."""
    if len(poly) == 0:
        return poly
    d = poly @ normal - offset
    out = []
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if d[i] >= 0:
            out.append(poly[i])
        if (d[i] >= 0) != (d[j] >= 0):
            t = d[i] / (d[i] - d[j])
            out.append(poly[i] + t * (poly[j] - poly[i]))
    return np.array(out) if len(out) >= 3 else np.empty((0, 3))


def _polygon_area(poly: np.ndarray) -> float:
    if len(poly) < 3:
        return 0.0
    c = np.cross(poly[1:-1] - poly[0], poly[2:] - poly[0])
    return 0.5 * float(np.linalg.norm(c.sum(axis=0)))


def _ground_mesh(ring: np.ndarray, ground_z: float, radius: float, inner: float = 0.5,
                 ratio: float = 1.1):
    """The ground polygon as concentric rings of quads (radii growing by ``ratio``).

    A fan of 1024 triangles from the centre describes the same surface, but its
    long thin triangles make a poor BVH: rays at grazing angles test many of
    them (casting is ~3x slower). Rings keep the triangles' aspect near 1:10.
    """
    n = len(ring)
    unit = ring[:, :2] / radius
    n_rings = max(1, int(math.ceil(math.log(radius / inner) / math.log(ratio))))
    radii = np.geomspace(inner, radius, n_rings + 1) if radius > inner else np.array([radius])
    verts = [np.array([[0.0, 0.0, ground_z]])]
    for r in radii:
        verts.append(np.column_stack([unit * r, np.full(n, ground_z)]))
    j = np.arange(n)
    k = (j + 1) % n
    faces = [np.column_stack([np.zeros(n, int), 1 + j, 1 + k])]
    for q in range(len(radii) - 1):
        a, b = 1 + q * n, 1 + (q + 1) * n
        faces.append(np.column_stack([a + j, b + j, b + k]))
        faces.append(np.column_stack([a + j, b + k, a + k]))
    return np.vstack(verts), np.vstack(faces)


def rectangle_scene(
    n_rectangles: int = 1000,
    seed: int | None = 0,
    *,
    ground_radius: float = 100.0,
    ground_z: float = -SCANNER_HEIGHT,
    side_range: tuple[float, float] = (0.1, 10.1),
    xy_range: tuple[float, float] = (-100.0, 100.0),
    z_range: tuple[float, float] = (-5.0, 10.0),
    ground_segments: int = 1024,
) -> RectangleScene:
    """The paper's synthetic scene: a ground disc and random rectangles.

    Parameters
    ----------
    n_rectangles : int
        Rectangles drawn (the paper: 0, 500, 1000, 2000).
    seed : int
        Same seed, same scene.
    ground_radius, ground_z : float
        Ground disc (100 m at z = -1.65, the scanner 1.65 m above it).
    side_range : (2,) float
        Side lengths are uniform in this range (metres).
    xy_range, z_range : (2,) float
        Centre coordinates are uniform in these ranges.
    ground_segments : int
        The disc is a regular polygon with this many sides (1024: its edge is
        within 0.5 mm of the circle); rectangles are clipped to the same polygon.

    Returns
    -------
    RectangleScene

    Notes
    -----
    Orientations are uniform on SO(3) (``scipy.spatial.transform.Rotation.random``).
    Each rectangle is clipped on the geometry: the part below the ground plane
    and the part outside the disc are cut away, so a rectangle crossing the
    ground keeps its upper part. One that keeps no area is not present.
    """
    _check_scene(n_rectangles, ground_radius, ground_z, ground_segments, side_range, xy_range, z_range)
    # the arrays, the clipped polygons (Python objects) and the mesh: about 1.5 kB a rectangle
    refuse_memory(1500.0 * n_rectangles + 100.0 * ground_segments, f"a scene of {int(n_rectangles):,} rectangles",
                  "ask for fewer rectangles")
    n = int(n_rectangles)
    rng = np.random.default_rng(seed)
    sides = rng.uniform(*side_range, size=(n, 2))
    centres = np.column_stack([rng.uniform(*xy_range, size=(n, 2)), rng.uniform(*z_range, size=n)])
    rot = spatial_transform.Rotation.random(n, random_state=rng).as_matrix() if n else np.empty((0, 3, 3))

    ring, edge_normals, apothem = _ground_polygon(ground_radius, ground_z, ground_segments)

    gv, gf = _ground_mesh(ring, ground_z, ground_radius)
    vertices, faces, labels = [gv], [gf], [np.zeros(len(gf), np.int64)]
    polygons, polygon_labels = [], []
    base = len(vertices[0])
    unit = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]])
    up = np.array([0.0, 0.0, 1.0])
    for k in range(n):
        poly = centres[k] + (unit * [sides[k, 0], sides[k, 1], 0]) @ rot[k].T
        poly = _clip_to_ground(poly, up, ground_z, edge_normals, apothem)
        if _polygon_area(poly) <= 0.0:
            continue
        m = len(poly)
        vertices.append(poly)
        faces.append(np.column_stack([np.zeros(m - 2, int), np.arange(1, m - 1), np.arange(2, m)]) + base)
        labels.append(np.full(m - 2, k + 1, np.int64))
        polygons.append(poly)
        polygon_labels.append(k + 1)
        base += m
    mesh = trimesh.Trimesh(np.vstack(vertices), np.vstack(faces), process=False)
    params = dict(n_rectangles=n, seed=seed, ground_radius=ground_radius, ground_z=ground_z,
                  side_range=list(side_range), xy_range=list(xy_range), z_range=list(z_range),
                  ground_segments=ground_segments)
    return RectangleScene(mesh, np.concatenate(labels), polygons,
                          np.array(polygon_labels, np.int64), n, len(polygons), params)


def _check_scene(n_rectangles, ground_radius, ground_z, ground_segments, side_range, xy_range, z_range) -> None:
    """:func:`rectangle_scene`'s arguments refused where they make no scene."""
    _check_number("n_rectangles", n_rectangles, integer=True, low=0)
    _check_number("ground_radius", ground_radius, low=0, open_low=True)
    _check_number("ground_z", ground_z)
    _check_number("ground_segments", ground_segments, integer=True, low=8)
    for name, r in (("side_range", side_range), ("xy_range", xy_range), ("z_range", z_range)):
        if len(r) != 2 or not all(isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(v)
                                  for v in r) or not r[0] <= r[1]:
            raise InputValueError(f"{name} must be two finite numbers, min <= max, got {list(r)!r}")
    if not side_range[0] > 0:
        raise InputValueError(f"side_range must be 0 < min <= max, got {side_range}")


def _ground_polygon(ground_radius, ground_z, ground_segments) -> tuple:
    """``(ring, edge_normals, apothem)`` of the ground disc's regular polygon."""
    ang = (np.arange(ground_segments) + 0.5) * (2 * np.pi / ground_segments)
    ring = np.column_stack([ground_radius * np.cos(ang), ground_radius * np.sin(ang),
                            np.full(ground_segments, ground_z)])
    # half-planes of the polygon's edges: n.p >= -apothem with n pointing inwards
    mid = (ang + np.pi / ground_segments)
    edge_normals = -np.column_stack([np.cos(mid), np.sin(mid), np.zeros_like(mid)])
    apothem = ground_radius * math.cos(math.pi / ground_segments)
    return ring, edge_normals, apothem


def _clip_to_ground(poly, up, ground_z, edge_normals, apothem) -> np.ndarray:
    """The part of polygon ``poly`` above the ground plane and inside the ground polygon (may be empty)."""
    poly = _clip(poly, up, ground_z)
    if len(poly) and np.hypot(poly[:, 0], poly[:, 1]).max() > apothem:
        for nrm in edge_normals:
            poly = _clip(poly, nrm, -apothem)
            if not len(poly):
                break
    return poly


def _check_number(name, v, integer: bool = False, low=None, open_low: bool = False) -> None:
    """A scene parameter: a finite number (an integer if ``integer``), >= ``low`` (> with ``open_low``)."""
    ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)
    if ok and integer:
        ok = int(v) == v
    if ok and low is not None:
        ok = v > low if open_low else v >= low
    if not ok:
        kind = "an integer" if integer else "a finite number"
        bound = "" if low is None else f" {'>' if open_low else '>='} {low}"
        raise InputValueError(f"{name} must be {kind}{bound}, got {v!r}")


def load_toml_spec(spec, table: str, what: str, prefix: str = "") -> tuple[dict, Path]:
    """A TOML file by path, or by name in ``scenes/`` (``<prefix><name>.toml``),
    that must hold ``[table]``. Returns (the whole document, its path)."""
    path = Path(spec)
    if not path.suffix:
        path = SCENES_DIR / f"{prefix}{spec}.toml"
    if not path.is_file():
        known = sorted(p.stem[len(prefix):] for p in SCENES_DIR.glob(f"{prefix}*.toml")) \
            if SCENES_DIR.is_dir() else []
        raise InputValueError(f"no {what} {spec!r} (looked for {path}); shipped: {known}")
    with open(path, "rb") as f:
        try:
            data = tomllib.load(f)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:  # binary (a cloud given for a config)
            raise InputValueError(f"{path}: not valid TOML: {exc}") from None
    if table not in data:
        raise InputValueError(f"{path}: no [{table}] table")
    return data, path


def load_scene_spec(spec) -> dict:
    """Read a scene spec: a path to a TOML file, or the name of one in ``scenes/``.

    A spec has a ``[scene]`` table with the keyword arguments of
    :func:`rectangle_scene` (``n_rectangles``, ``seed``...).
    """
    return load_toml_spec(spec, "scene", "scene spec")[0]


def scene_from_spec(spec) -> RectangleScene:
    """Build the scene a spec (name or path) describes."""
    kwargs = dict(load_scene_spec(spec)["scene"])
    kwargs.pop("name", None)
    kwargs.pop("description", None)
    for key in ("side_range", "xy_range", "z_range"):
        if key in kwargs:
            kwargs[key] = tuple(kwargs[key])
    try:
        return rectangle_scene(**kwargs)
    except TypeError as exc:
        raise InputValueError(f"scene spec {spec!r}: {exc}") from None


def scene_effects(spec) -> Effects | None:
    """The sensor effects a scene requires: its ``[effects]`` table
    (:class:`~slr_ray.effects.Effects` keys, e.g. ``range_noise = 0.02``), or
    None when it has none. Unknown keys are an error naming the file; a
    relative ``ray_drop`` path is read from the file's directory."""
    data, path = load_toml_spec(spec, "scene", "scene spec")
    if "effects" not in data:
        return None
    try:
        return Effects.from_dict(data["effects"], relative_to=path.parent).check_needs()
    except InputValueError as exc:
        raise InputValueError(f"{path}: [effects]: {exc}") from None


@njit(cache=True, nogil=True)
def _fill_ground(x0, spacing, nx, ny, r2, z, j, cap, buf):
    """Ground samples of rows j, j+1... while they fit in ``buf``; returns (n, next row)."""
    n = 0
    while j < ny:
        y = x0 + j * spacing
        w2 = r2 - y * y
        if w2 < 0:
            j += 1
            continue
        w = math.sqrt(w2)
        lo = max(0, int(math.floor((-w - x0) / spacing)) - 1)
        hi = min(nx - 1, int(math.ceil((w - x0) / spacing)) + 1)
        if n + (hi - lo + 1) > cap:
            break
        for i in range(lo, hi + 1):
            x = x0 + i * spacing
            if x * x + y * y <= r2:
                buf[n, 0] = x
                buf[n, 1] = y
                buf[n, 2] = z
                n += 1
        j += 1
    return n, j


@njit(cache=True, nogil=True)
def _fill_polygon(o, e1, e2, uv, sign, u0, v0, nu, nv, spacing, a, cap, buf, labels, label, at):
    """Grid samples of rows a, a+1... of one planar convex polygon, from buf[at];
    returns (new end, next row)."""
    m = uv.shape[0]
    n = at
    while a < nu:
        if n + nv > cap:
            break
        u = u0 + a * spacing
        for b in range(nv):
            v = v0 + b * spacing
            inside = True
            for k in range(m):
                ax = uv[k, 0]
                ay = uv[k, 1]
                bx = uv[(k + 1) % m, 0]
                by = uv[(k + 1) % m, 1]
                if sign * ((bx - ax) * (v - ay) - (by - ay) * (u - ax)) < 0:
                    inside = False
                    break
            if inside:
                for c in range(3):
                    buf[n, c] = o[c] + u * e1[c] + v * e2[c]
                labels[n] = label
                n += 1
        a += 1
    return n, a


def _polygon_frame(poly: np.ndarray, spacing: float):
    """Plane frame and grid extent of a convex polygon: (o, e1, e2, uv, sign, u0, v0, nu, nv)."""
    o = poly[0]
    e1 = poly[1] - poly[0]
    e1 = e1 / np.linalg.norm(e1)
    nrm = np.cross(poly[1] - poly[0], poly[2] - poly[0])
    nrm /= np.linalg.norm(nrm)
    e2 = np.cross(nrm, e1)
    uv = np.column_stack([(poly - o) @ e1, (poly - o) @ e2])
    a, b = uv[1] - uv[0], uv[2] - uv[0]
    sign = float(np.sign(a[0] * b[1] - a[1] * b[0]))
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    nu = int(np.ceil((hi[0] - lo[0] - spacing / 2) / spacing))
    nv = int(np.ceil((hi[1] - lo[1] - spacing / 2) / spacing))
    return o, e1, e2, uv, sign, lo[0] + spacing / 2, lo[1] + spacing / 2, max(nu, 0), max(nv, 0)


def dense_samples(scene: RectangleScene, spacing: float = 0.005, chunk: int = 1 << 22,
                  copy: bool = True):
    """Yield ``(points, labels)`` chunks of a regular grid over every surface.

    The paper's "dense cloud" (5 mm: 40,000 points per m^2; about 1.9e9
    points for a 1000-rectangle scene), generated lazily by compiled loops:
    ground rows first (a grid in x, y clipped to the disc inscribed in the
    ground polygon), then each rectangle on a grid in its own plane, clipped
    to its polygon. At most ``chunk`` points at a time (whole rows), in a
    fixed order, so the same scene always yields the same stream.

    Parameters
    ----------
    copy : bool
        False yields views of one reused buffer (faster, no allocation per
        chunk): use each chunk before asking for the next.
    """
    if spacing <= 0:
        raise InputValueError(f"spacing must be > 0, got {spacing}")
    p = scene.params
    radius = p["ground_radius"] * math.cos(math.pi / p["ground_segments"])
    x0 = -radius + spacing / 2
    nx = max(0, int(math.ceil((2 * radius - spacing / 2) / spacing)))
    frames = [_polygon_frame(poly, spacing) for poly in scene.polygons]
    cap = max(int(chunk), nx + 3, max((f[8] for f in frames), default=0))
    refuse_memory(32.0 * cap, f"dense samples {spacing:g} m apart (rows of {cap:,} points in one buffer)",
                  "use a coarser spacing")
    buf = np.empty((cap, 3))
    labels = np.empty(cap, np.int64)
    out = (lambda n: (buf[:n].copy(), labels[:n].copy())) if copy else (lambda n: (buf[:n], labels[:n]))
    j = 0
    while j < nx:
        n, j = _fill_ground(x0, spacing, nx, nx, radius * radius, p["ground_z"], j, cap, buf)
        if n:
            labels[:n] = 0
            yield out(n)
    n = 0
    for frame, label in zip(frames, scene.polygon_labels):
        o, e1, e2, uv, sign, u0, v0, nu, nv = frame
        a = 0
        while a < nu:
            n, a = _fill_polygon(o, e1, e2, uv, sign, u0, v0, nu, nv, spacing, a, cap, buf,
                                 labels, int(label), n)
            if a < nu:  # buffer full
                yield out(n)
                n = 0
    if n:
        yield out(n)
