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

``unit="real"`` scans the drive as one real-like unit instead of the nominal
table (:data:`REAL_UNIT`): the beams off the table
(:func:`slr_ray.sensors.miscalibrated`, the same unit in every frame), the
unit's per-beam range offsets (the same in every frame), each frame's own range
noise and lost pulses (:func:`slr_ray.sensors.sensor_noise`, a seed a frame).
Its frames are written in KITTI's scan order (ring after ring, highest beam
first, each ring by azimuth counter-clockwise), so that a reader learns each
point's beam from the order (:func:`slr_ray.sensors.scan_order_beams`) as on
KITTI's own frames. ``truth`` (a new directory) receives the same layout with
the noiseless scan of the same pulses (where each kept pulse of the unit hit
the street): what a held-out frame's pulses would have measured.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import lazy
from ..io import PointCloud, atomic_path, write_cloud
from ..meshscan import scan_mesh
from ..errors import InputValueError
from ..sensors import miscalibrated, sensor_noise
from ..sensors import sensor as shipped_sensor
from .frames import write_kitti_poses

#: trimesh, loaded on first use (slr_ray.lazy: the command line starts without it)
trimesh = lazy.module("trimesh")

__all__ = ["synthetic_drive", "street_mesh", "KITTI_TR", "ROAD", "BUILDING", "CAR", "MOVING_CAR", "REAL_UNIT", "UNITS",
           "MOVING_SPEED"]

ROAD, BUILDING, CAR, MOVING_CAR = 40, 50, 10, 252
#: velodyne to camera: x forward, y left, z up -> camera x right, y down, z forward
KITTI_TR = np.array([[0.0, -1, 0, 0.0], [0, 0, -1, -0.08], [1, 0, 0, -0.27], [0, 0, 0, 1]])
#: the real-like unit's departures (benchmarks/evaluate_pairs.py's synthetic pair, docs/sequences.md):
#: each beam's elevation and azimuth off the table by a normal draw of 0.1 deg, per-beam range offsets
#: of 3 cm (KITTI's unit, fitted by the ``rays`` estimator: -4 to +7 cm), 1 cm range noise a point (the
#: HDL-64E's datasheet: distance accuracy 2 cm, one sigma, offsets included), 10 % of pulses lost
REAL_UNIT = {"elevation_sd": 0.1, "azimuth_sd": 0.1, "beam_range_sd": 0.03, "range_sd": 0.01, "dropout": 0.1}
UNITS = ("exact", "real")
#: the moving box's metres a frame
MOVING_SPEED = 1.5


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


def _scan_order(local, rows) -> np.ndarray:
    """The order of KITTI's scan (module docstring): by row (beam 0 highest), then by azimuth
    counter-clockwise from the first point of the highest ring, so that each ring's unwrapped azimuth
    starts one turn after the one before (:func:`slr_ray.sensors.scan_order_beams`)."""
    az = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2 * np.pi)
    top = rows == rows.min()
    phase = np.mod(az - az[top].min(), 2 * np.pi)
    return np.lexsort((phase, rows))


def synthetic_drive(out, n_frames: int = 24, step: float = 0.8, sensor: str = "velodyne_hdl64e_s2",
                    moving: bool = True, seed: int = 0, unit: str = "exact", truth=None) -> np.ndarray:
    """Write the drive to the new directory ``out`` (module docstring); returns the exact
    velodyne poses ``(n, 4, 4)``. The vehicle drives along x with a slow yaw; the moving box
    starts 12 m ahead and drives :data:`MOVING_SPEED` m a frame. ``unit``: ``"exact"`` (the table's
    pulse centres) or ``"real"`` (:data:`REAL_UNIT`'s departures, ``seed`` the unit's; frame
    ``i``'s noise seeded ``seed + 1 + i``); ``truth``: a new directory for the noiseless scan of
    the same pulses (``unit="real"`` only)."""
    if unit not in UNITS:
        raise InputValueError(f"unknown unit {unit!r}; choose from {list(UNITS)}")
    if truth is not None and unit != "real":
        raise InputValueError("truth: the noiseless scan of a real unit's pulses (unit='real')")
    rng = np.random.default_rng(seed)
    out = Path(out)
    dirs = [out] + ([Path(truth)] if truth is not None else [])
    for d in dirs:
        (d / "velodyne").mkdir(parents=True)
        (d / "labels").mkdir()
    pattern = shipped_sensor(sensor)
    if unit == "real":
        pattern = miscalibrated(pattern, REAL_UNIT["elevation_sd"], REAL_UNIT["azimuth_sd"], seed=seed)
    poses = np.zeros((n_frames, 4, 4))
    for i in range(n_frames):
        yaw = 0.01 * np.sin(i / 5)
        c, s = np.cos(yaw), np.sin(yaw)
        poses[i] = [[c, -s, 0, i * step], [s, c, 0, 0.05 * np.sin(i / 3)], [0, 0, 1, 0], [0, 0, 0, 1]]
        mesh, labels = street_mesh(12.0 + MOVING_SPEED * i if moving else None, length=n_frames * step + 60)
        o = poses[i][:3, 3]
        sc = scan_mesh(mesh, o, pattern, "center", face_labels=labels)
        world, sem = sc.points, np.asarray(sc.labels, np.uint16)
        intensity = rng.uniform(0.0, 1.0, len(world)).astype(np.float32)
        clouds = [world]
        if unit == "real":
            beams = pattern.beam_of_row[sc.pulses[:, 0]]
            # the unit's per-beam range offsets: one draw for every frame (seed), then this frame's own
            # range noise and lost pulses
            off, _ = sensor_noise(world, o, beams, range_sd=0.0, beam_range_sd=REAL_UNIT["beam_range_sd"],
                                  dropout=0.0, seed=seed)
            noisy, kept = sensor_noise(off, o, beams, range_sd=REAL_UNIT["range_sd"], beam_range_sd=0.0,
                                       dropout=REAL_UNIT["dropout"], seed=seed + 1 + i)
            sem, intensity = sem[kept], intensity[kept]
            clouds = [noisy, world[kept]]
            rows = sc.pulses[kept, 0]
        for d, pts in zip(dirs, clouds):
            local = (pts - o) @ poses[i][:3, :3]  # into the sensor's frame (float64)
            order = _scan_order(local, rows) if unit == "real" else slice(None)
            cloud = PointCloud(local[order], {"intensity": intensity[order], "semantic": sem[order],
                                              "instance": np.zeros(len(local), np.uint16)}, np.zeros(3))
            write_cloud(d / "velodyne" / f"{i:06d}.bin", cloud)
    cam = np.einsum("ij,njk,kl->nil", KITTI_TR, poses, np.linalg.inv(KITTI_TR))
    tr = " ".join(f"{x:.17g}" for x in KITTI_TR[:3].ravel())
    for d in dirs:
        with atomic_path(d / "poses.txt") as tmp:
            write_kitti_poses(tmp, cam)
        (d / "calib.txt").write_text(f"P0: 1 0 0 0 0 1 0 0 0 0 1 0\nTr: {tr}\n")
    return poses
