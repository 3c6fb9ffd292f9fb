"""Motion during a sweep (slr_ray.effects.motion): a straight wall lands where the poses say."""

import numpy as np
import pytest

from slr_ray import InputValueError, ScanPattern, prepare
from slr_ray.effects import Effects, pose, simulate
from slr_ray.effects.motion import as_poses, interpolate_poses, to_frame

PATTERN = ScanPattern(1.0, zenith_range=(80, 100))


def wall(step=0.02):
    """The wall x = 10, y in [-12, 12], z in [-2, 2]."""
    y, z = np.meshgrid(np.arange(-12, 12, step), np.arange(-2, 2, step), indexing="ij")
    return np.column_stack([np.full(y.size, 10.0), y.ravel(), z.ravel()])


def wall_scanner(backend):
    pts = wall()
    opts = {"radius": 0.015, "normals": np.tile([-1.0, 0, 0], (len(pts), 1))} if backend == "embree" else {}
    return prepare(pts, backend, **opts)


START, END = pose([0.0, 0.0, 0.0], yaw_deg=0.0), pose([2.0, 1.0, 0.0], yaw_deg=10.0)


@pytest.mark.parametrize("backend", ["embree", "binning"])
def test_wall_scanned_while_moving_lands_where_the_poses_say(backend):
    sc = wall_scanner(backend)
    es = simulate(sc, None, PATTERN, Effects(motion=True, motion_sectors=90), poses=[START, END])
    assert es.frame == "sensor-end" and len(es) > 100
    # the wall, in the end pose's frame: a plane through to_frame(wall point) with the rotated normal
    n_end = END[:3, :3].T @ [1.0, 0, 0]
    p0 = to_frame([[10.0, 0, 0]], END)[0]
    tol = 0.02 if backend == "binning" else 1e-6
    assert np.max(np.abs((es.points - p0) @ n_end)) < 0.05 + tol
    # each return's range is the distance along its ray from the pose its column fired from
    nh = PATTERN.shape[1]
    sector = (es.pulses[:, 1] * 90) // nh
    t = (sector + 0.5) / 90
    rot, org = interpolate_poses([START, END], t)
    world = es.points @ END[:3, :3].T + END[:3, 3]
    assert np.allclose(np.linalg.norm(world - org, axis=1), es.ranges, atol=1e-6)
    assert np.allclose(world[:, 0], 10.0, atol=0.05 if backend == "binning" else 1e-6)
    # not what a sensor standing at the end pose would see: the sweep's first columns differ by metres
    ray_x = ((world - org) / es.ranges[:, None])[:, 0]
    assert np.allclose(es.ranges, (10.0 - org[:, 0]) / ray_x, atol=1e-6 if backend == "embree" else 0.1)
    assert np.ptp(org[:, 0]) > 1.5


def test_static_poses_give_the_static_scan():
    sc = wall_scanner("embree")
    o = [0.5, -0.2, 0.1]
    moving = simulate(sc, None, PATTERN, Effects(motion=True), poses=[pose(o), pose(o)])
    static = simulate(sc, o, PATTERN, Effects())
    # per pulse, the same disc; the static scan keeps points, the cast one the disc surface
    a = dict(zip(map(tuple, moving.pulses), moving.indices))
    b = dict(zip(map(tuple, static.ideal.pulses), static.ideal.indices))
    same = [a[k] == b[k] for k in a if k in b]
    assert len(same) > 100 and np.mean(same) > 0.95
    assert np.allclose(moving.points + o, to_frame(moving.points, np.linalg.inv(pose(o))), atol=1e-9)


def test_poses_are_checked():
    with pytest.raises(InputValueError, match="two or more"):
        as_poses([np.eye(4)])
    bad = np.eye(4)
    bad[0, 0] = 2
    with pytest.raises(InputValueError, match="rigid"):
        as_poses([np.eye(4), bad])
    with pytest.raises(InputValueError, match="poses"):
        simulate(prepare(wall(0.5)), [0, 0, 0], PATTERN, Effects(motion=True))
