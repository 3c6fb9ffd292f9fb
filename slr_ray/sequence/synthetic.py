"""A synthetic drive with truth: a rectangle street, parked boxes, one moving box, exact poses.

:func:`synthetic_drive` writes a SemanticKITTI sequence (``velodyne/``,
``labels/``, ``poses.txt``, ``calib.txt``): each frame the exact scan (one ray
per pulse centre, :func:`slr_ray.meshscan.scan_mesh`) of a street by a
spinning sensor driving along it, the street's faces labelled with
SemanticKITTI classes (40 road, 50 building, 10 car, 252 moving car). The box
labelled 252 moves along the street between frames. ``calib.txt`` holds a
``Tr`` that is not the identity (KITTI's velodyne-to-camera axes), and
``poses.txt`` the camera poses ``Tr P Tr^-1``, so a reader that forgets ``Tr``
gets the poses wrong.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..io import PointCloud, atomic_path, write_cloud
from ..meshscan import scan_mesh
from ..sensors import sensor as shipped_sensor
from .frames import write_kitti_poses

__all__ = ["synthetic_drive", "street_mesh", "KITTI_TR", "ROAD", "BUILDING", "CAR", "MOVING_CAR"]

ROAD, BUILDING, CAR, MOVING_CAR = 40, 50, 10, 252
#: velodyne to camera: x forward, y left, z up -> camera x right, y down, z forward
KITTI_TR = np.array([[0.0, -1, 0, 0.0], [0, 0, -1, -0.08], [1, 0, 0, -0.27], [0, 0, 0, 1]])


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def street_mesh(moving_x: float | None = None, length: float = 80.0, width: float = 14.0,
                height: float = 1.73) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The street (x along it, sensor ``height`` above the road) and its face labels."""
    parts = [(_box((-20, -width / 2, -height - 0.2), (length, width / 2, -height)), ROAD),
             (_box((-20, width / 2, -height), (length, width / 2 + 0.5, 6.0)), BUILDING),
             (_box((-20, -width / 2 - 0.5, -height), (length, -width / 2, 6.0)), BUILDING)]
    for k, x in enumerate(np.arange(-10.0, length - 5, 9.0)):  # parked cars, both sides
        y = 4.5 if k % 2 else -4.5
        parts.append((_box((x, y - 0.9, -height), (x + 4.2, y + 0.9, -height + 1.5)), CAR))
    for x in np.arange(-15.0, length, 13.0):  # pillars on the walls: something to register on
        parts.append((_box((x, width / 2 - 0.4, -height), (x + 0.6, width / 2, 6.0)), BUILDING))
    if moving_x is not None:
        parts.append((_box((moving_x, -1.0, -height), (moving_x + 4.5, 1.0, -height + 1.6)), MOVING_CAR))
    mesh = trimesh.util.concatenate([m for m, _ in parts])
    labels = np.concatenate([np.full(len(m.faces), lab) for m, lab in parts])
    return mesh, labels


def synthetic_drive(out, n_frames: int = 24, step: float = 0.8, sensor: str = "velodyne_hdl64e_s2",
                    moving: bool = True, moving_speed: float = 1.5, seed: int = 0) -> np.ndarray:
    """Write the drive to the new directory ``out`` (module docstring); returns the exact
    velodyne poses ``(n, 4, 4)``. The vehicle drives along x with a slow yaw; the moving box
    starts 12 m ahead and drives ``moving_speed`` m a frame."""
    rng = np.random.default_rng(seed)
    out = Path(out)
    (out / "velodyne").mkdir(parents=True)
    (out / "labels").mkdir()
    pattern = shipped_sensor(sensor)
    poses = np.zeros((n_frames, 4, 4))
    for i in range(n_frames):
        yaw = 0.01 * np.sin(i / 5)
        c, s = np.cos(yaw), np.sin(yaw)
        poses[i] = [[c, -s, 0, i * step], [s, c, 0, 0.05 * np.sin(i / 3)], [0, 0, 1, 0], [0, 0, 0, 1]]
        mesh, labels = street_mesh(12.0 + moving_speed * i if moving else None, length=n_frames * step + 60)
        sc = scan_mesh(mesh, poses[i][:3, 3], pattern, "center", face_labels=labels)
        local = (sc.points - poses[i][:3, 3]) @ poses[i][:3, :3]  # into the sensor's frame (float64)
        intensity = rng.uniform(0.0, 1.0, len(local)).astype(np.float32)
        cloud = PointCloud(local, {"intensity": intensity, "semantic": np.asarray(sc.labels, np.uint16),
                                   "instance": np.zeros(len(local), np.uint16)}, np.zeros(3))
        write_cloud(out / "velodyne" / f"{i:06d}.bin", cloud)
    cam = np.einsum("ij,njk,kl->nil", KITTI_TR, poses, np.linalg.inv(KITTI_TR))
    with atomic_path(out / "poses.txt") as tmp:
        write_kitti_poses(tmp, cam)
    tr = " ".join(f"{x:.17g}" for x in KITTI_TR[:3].ravel())
    (out / "calib.txt").write_text(f"P0: 1 0 0 0 0 1 0 0 0 0 1 0\nTr: {tr}\n")
    return poses
