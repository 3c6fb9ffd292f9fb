"""A synthetic terrestrial campaign with truth: setups along a corridor, each scanned on a uniform grid.

:func:`corridor_campaign` writes a campaign of registered terrestrial setups, as a
terrestrial laser scanner's software exports them: a corridor (floor, ceiling,
walls, end walls, pillars and cabinets along the walls, a door recess) scanned
from ``n_setups`` positions along it, each setup turned about the vertical by
its own yaw, each on one uniform angular grid (:class:`~slr_ray.ScanPattern`:
``resolution`` degrees both ways, zenith ``zenith_range``), one ray per pulse
centre (:func:`slr_ray.meshscan.scan_mesh`), ranges with ``range_sd`` of noise.
What a ``sequence evaluate`` of it must do: score each held-out setup on a grid
fitted to it (its steps are ``resolution``), never on a spinning unit's table.

``form`` chooses the files (each in a layout :func:`slr_ray.sequence.read_sequence` reads):

``"e57"``
    ``campaign.e57``: one scan a setup, each in its scanner's own axes with its
    pose (rotation quaternion and translation);
``"scans"``
    ``campaign.las``: every setup's points in one world frame, ``point_source_id``
    the setup (``--scan-field``), and ``origins.txt`` (``--origins``);
``"files"``
    ``setup_K.las``, a file a setup in the world frame, and ``origins.txt``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .. import lazy
from ..errors import InputValueError, MissingDependencyError
from ..io import PointCloud, write_cloud
from ..meshscan import scan_mesh
from ..pattern import ScanPattern

#: trimesh, loaded on first use (slr_ray.lazy: the command line starts without it)
trimesh = lazy.module("trimesh")

__all__ = ["corridor_mesh", "corridor_campaign", "CAMPAIGN_FORMS", "SCANNER_HEIGHT", "LENGTH", "WIDTH"]

#: the files :func:`corridor_campaign` writes (its ``form``): an E57 of several scans, one LAS split by
#: ``point_source_id``, a LAS file a setup
CAMPAIGN_FORMS = ("e57", "scans", "files")
#: a setup's scanner above the floor (m)
SCANNER_HEIGHT = 1.5
#: the corridor's length and width (m)
LENGTH, WIDTH = 24.0, 3.0


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def corridor_mesh(length: float = 24.0, width: float = 3.0, height: float = 3.0) -> trimesh.Trimesh:
    """The corridor: x along it from 0 to ``length``, y across (walls at ``±width / 2``), the floor at
    z = 0, the ceiling at ``height``; closed at both ends; pillars every 4 m on the left wall,
    cabinets every 5 m on the right, a door recess in the right wall, a box on the floor."""
    w, h, t = width / 2, height, 0.2
    parts = [_box((-t, -w - t, -t), (length + t, w + t, 0.0)),          # floor
             _box((-t, -w - t, h), (length + t, w + t, h + t)),          # ceiling
             _box((-t, w, 0.0), (length + t, w + t, h)),                # left wall
             _box((-t, -w - t, 0.0), (7.0, -w, h)),                     # right wall, a door recess at 7-8 m
             _box((7.0, -w - 1.0 - t, 0.0), (8.0, -w - 1.0, h)),
             _box((7.0 - t, -w - 1.0, 0.0), (7.0, -w, h)), _box((8.0, -w - 1.0, 0.0), (8.0 + t, -w, h)),
             _box((8.0, -w - t, 0.0), (length + t, -w, h)),
             _box((-t, -w, 0.0), (0.0, w, h)), _box((length, -w, 0.0), (length + t, w, h))]  # end walls
    parts += [_box((x, w - 0.3, 0.0), (x + 0.4, w, h)) for x in np.arange(2.0, length - 1, 4.0)]
    parts += [_box((x, -w, 0.0), (x + 1.2, -w + 0.5, 1.8)) for x in np.arange(3.0, length - 2, 5.0) if
              not 5.5 < x < 8.5]
    parts.append(_box((length / 2 - 0.4, -0.6, 0.0), (length / 2 + 0.4, 0.2, 0.9)))
    return trimesh.util.concatenate(parts)


def _setup_poses(n: int, length: float, width: float) -> np.ndarray:
    poses = np.repeat(np.eye(4)[None], n, 0)
    for k in range(n):
        yaw = math.radians(37.0 * k + 10.0)
        c, s = math.cos(yaw), math.sin(yaw)
        poses[k, :3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        poses[k, :3, 3] = [length * (k + 1) / (n + 1), 0.25 * width * (-1) ** k / 2, SCANNER_HEIGHT]
    return poses


def corridor_campaign(out, n_setups: int = 3, resolution: float = 1.0, form: str = "e57",
                      zenith_range=(30.0, 180.0), range_sd: float = 0.002, seed: int = 0) -> dict:
    """Write the campaign (module docstring) into the new directory ``out``; returns what to give
    ``slr-ray sequence`` (``paths``, ``flags``: the command-line arguments after the paths), the
    setups' poses ``(n, 4, 4)`` (scanner to world) and the grid (``pattern``). The corridor is
    :data:`LENGTH` m long and :data:`WIDTH` m wide; the setups are spread evenly along it."""
    if form not in _WRITERS:
        raise InputValueError(f"form {form!r}: choose from {list(CAMPAIGN_FORMS)}")
    if int(n_setups) < 1:
        raise InputValueError(f"n_setups must be >= 1, got {n_setups}")
    out = Path(out)
    out.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    mesh = corridor_mesh(LENGTH, WIDTH)
    pattern = ScanPattern(resolution, zenith_range=tuple(zenith_range), name="corridor scanner")
    poses = _setup_poses(int(n_setups), LENGTH, WIDTH)
    locals_ = []
    for T in poses:  # the mesh in the scanner's own axes: its grid turns with it
        sc = scan_mesh(mesh.copy().apply_transform(np.linalg.inv(T)), np.zeros(3), pattern, "center")
        local = sc.points
        r = np.linalg.norm(local, axis=1)
        locals_.append(local * (1.0 + rng.normal(0.0, range_sd, len(r)) / r)[:, None])
    worlds = [p @ T[:3, :3].T + T[:3, 3] for p, T in zip(locals_, poses)]
    paths, flags = _WRITERS[form](out, locals_, worlds, poses)
    return {"paths": [str(p) for p in paths], "flags": flags, "poses": poses, "pattern": pattern,
            "points": [len(p) for p in locals_]}


def _origins(out, poses) -> Path:
    path = out / "origins.txt"
    path.write_text("".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in poses[:, :3, 3]))
    return path


def _as_e57(out, locals_, worlds, poses):
    path = out / "campaign.e57"
    _write_e57(path, locals_, poses)
    return [path], []


def _as_scans(out, locals_, worlds, poses):
    path = out / "campaign.las"
    ids = np.concatenate([np.full(len(p), k + 1, np.uint16) for k, p in enumerate(worlds)])
    write_cloud(path, PointCloud(np.vstack(worlds), {"point_source_id": ids}))
    return [path], ["--scan-field", "--origins", str(_origins(out, poses))]


def _as_files(out, locals_, worlds, poses):
    paths = [out / f"setup_{k}.las" for k in range(len(worlds))]
    for p, w in zip(paths, worlds):
        write_cloud(p, PointCloud(w, {}))
    return paths, ["--origins", str(_origins(out, poses))]


def _write_e57(path, locals_, poses) -> None:
    """One scan a setup, its points in its scanner's axes, its pose a quaternion (w, x, y, z) and a
    translation (pye57 stores the coordinates as float32: well under a millimetre here)."""
    try:
        import pye57
    except ImportError as exc:  # an optional extra
        raise MissingDependencyError('E57 needs pye57: pip install "slr_ray[e57]"') from exc
    e = pye57.E57(str(path), mode="w")
    try:
        for k, (p, T) in enumerate(zip(locals_, poses)):
            yaw = math.atan2(T[1, 0], T[0, 0])
            q = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
            e.write_scan_raw({"cartesianX": p[:, 0], "cartesianY": p[:, 1], "cartesianZ": p[:, 2]},
                             name=f"setup {k}", translation=T[:3, 3].copy(), rotation=q)
    finally:
        e.close()


_WRITERS = {"e57": _as_e57, "scans": _as_scans, "files": _as_files}
