"""The ``tsdf`` sequence method (slr_ray.sequence.tsdf): lidar_transfer's TSDF of the union's range image,
cast with the target's rays. Its hits lie on the surface the points sample, they carry the attributes of
the points they hit, and an empty or unusable union is refused in one line."""

import json

import numpy as np
import pytest

import slr_ray
from slr_ray.errors import InputValueError
from slr_ray.io import read_cloud
from slr_ray.sequence import methods as M
from slr_ray.sequence.synthetic import BUILDING, CAR, MOVING_CAR, ROAD, synthetic_drive
from slr_ray.sequence.tsdf import TSDF_VOXEL, tsdf_returns
from conftest import CliRun

WALL_X, GROUND_Z = 8.0, -1.7


@pytest.fixture(scope="module")
def scene():
    """A wall facing the sensor (x = 8 m, y in [-3, 3], z in [-1.7, 2]: label 1) standing on the ground
    (z = -1.7 m, within 20 m: label 2), densely sampled."""
    rng = np.random.default_rng(0)
    n = 60_000
    ground = np.c_[rng.uniform(-20, 20, n), rng.uniform(-20, 20, n), np.full(n, GROUND_Z)]
    wall = np.c_[np.full(n, WALL_X), rng.uniform(-3, 3, n), rng.uniform(GROUND_Z, 2, n)]
    keep = ~((ground[:, 0] > WALL_X) & (np.abs(ground[:, 1]) < 3))   # no ground behind the wall
    points = np.r_[wall, ground[keep]]
    labels = np.r_[np.ones(n, int), np.full(keep.sum(), 2)]
    return points, labels


def test_the_cast_meets_the_wall_within_a_voxel_and_carries_its_points(scene):
    points, labels = scene
    pattern = slr_ray.ScanPattern(1.0)
    ret = tsdf_returns(points, pattern)
    assert np.all(np.diff(ret.keys) > 0) and np.allclose(np.linalg.norm(ret.points, axis=1), ret.ranges)
    d, v, h = pattern.rays()
    # the pulses whose centre ray crosses the wall's plane well inside its edges (two voxels and a pulse)
    t = WALL_X / np.maximum(d[:, 0], 1e-9)
    y, z = d[:, 1] * t, d[:, 2] * t
    margin = 2 * TSDF_VOXEL + t * np.radians(1.0)
    inner = (d[:, 0] > 0) & (np.abs(y) < 3 - margin) & (z > GROUND_Z + margin) & (z < 2 - margin)
    inner_keys = pattern.ravel(np.c_[v[inner], h[inner]])
    assert inner.sum() > 500
    on = np.isin(ret.keys, inner_keys)
    assert on.sum() == inner.sum()   # every such pulse returns: no hole in the fused wall
    assert np.abs(ret.points[on, 0] - WALL_X).max() < TSDF_VOXEL
    assert np.all(labels[ret.index[on]] == 1)   # the wall's label rides on its returns
    assert np.linalg.norm(points[ret.index] - ret.points, axis=1).max() < 1.0   # the point nearest each hit
    assert np.all(labels[ret.index[ret.points[:, 0] < WALL_X - 0.5]] == 2)    # before the wall: the ground


def test_bounds_and_voxel_follow_the_options(scene):
    points, _ = scene
    pattern = slr_ray.ScanPattern(1.0)
    near = tsdf_returns(points, pattern, xy_bound=6.0)   # the wall (8 m) outside the volume
    assert len(near) and np.all(np.abs(near.points[:, :2]) <= 6.0 + 1e-9)
    coarse = tsdf_returns(points, pattern, voxel=0.2, truncation=0.6)
    assert len(coarse) > 0.5 * len(tsdf_returns(points, pattern))


@pytest.mark.parametrize("points, kw, message", [
    (np.zeros((0, 3)), {}, "no points to fuse"),
    (np.array([[200.0, 0, 0], [0, 200, 0]]), {}, "no point within the pattern's rows and the volume's bounds"),
    (np.ones((5, 2)), {}, "expected \\(n, 3\\)"),
    (np.array([[1.0, 2, 3], [np.nan, 0, 0]]), {}, "points has 1 row\\(s\\) with NaN or inf out of 2"),
    (np.ones((5, 3)), {"truncation": 0.01}, "at least one voxel"),
    (np.ones((5, 3)), {"voxel": 0.0}, "voxel must be > 0"),
])
def test_an_empty_or_degenerate_union_is_refused(points, kw, message):
    with pytest.raises(InputValueError, match=message):
        tsdf_returns(points, slr_ray.sensor("velodyne_vlp16"), **kw)


def test_options_and_flags_are_checked():
    opts = M.REGISTRY["tsdf"].options
    assert opts().to_dict() == {"voxel": 0.05, "truncation": 0.25, "xy_bound": 50.0, "z_bound": 5.0}
    with pytest.raises(InputValueError, match="--tsdf-truncation \\(0.05 m\\) must be at least one voxel"):
        opts(voxel=0.1, truncation=0.05).check()
    with pytest.raises(InputValueError, match="--tsdf-xy-bound must be metres > 0"):
        opts(xy_bound=-1.0).check()


def test_a_conversion_carries_the_street_labels(tmp_path, capsys):
    drive = tmp_path / "seq"
    synthetic_drive(drive, n_frames=3, sensor="velodyne_vlp16", step=0.8)
    out = tmp_path / "conv"
    r = CliRun(capsys)("sequence", "convert", drive, "--target-sensor", "velodyne_vlp16", "--estimator", "tsdf",
                       "--half", "1", "--tsdf-voxel", "0.1", "--tsdf-truncation", "0.4", "-o", out, "--quiet")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["settings"]["method_options"] == {"tsdf_voxel": 0.1, "tsdf_truncation": 0.4}
    cloud = read_cloud(out / "velodyne" / "000001.bin")
    labels = np.asarray(cloud.attributes["semantic"])
    assert len(cloud.points) > 1000 and set(np.unique(labels)) <= {ROAD, BUILDING, CAR}   # no moving car
    assert MOVING_CAR not in labels
    assert np.mean(labels == ROAD) > 0.2
