"""Motion during a sweep (slr_ray.effects.motion): a straight wall lands where the poses say."""

import numpy as np
import pytest

from slr_ray import InputValueError, ScanPattern, prepare
from slr_ray.effects import Effects, pose, simulate
from slr_ray.effects.motion import (as_poses, azimuth_times, column_sectors, column_times, deskew, interpolate_poses,
                                   to_firing_frames, to_frame)
from slr_ray.pattern import pulse_rays

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


def test_column_times_default_and_kitti_timing():
    n = 2011
    assert np.allclose(column_times(n), (np.arange(n) + 0.5) / n)
    # clockwise from the rear: KISS-ICP's timing of KITTI's raw frames, 0.5 (1 - atan2(y, x) / pi)
    az = (np.arange(n) + 0.5) * 360.0 / n
    kiss = 0.5 * (1 - np.radians(np.where(az > 180, az - 360, az)) / np.pi)
    assert np.allclose(column_times(n, 180.0, clockwise=True), kiss)
    assert np.allclose(azimuth_times([179.9, -179.9, 0.0], 180.0, True), [0.1 / 360, 359.9 / 360, 0.5])


@pytest.mark.parametrize("start, cw", [(0.0, False), (180.0, True), (95.0, False), (-30.0, True)])
@pytest.mark.parametrize("sectors", [1, 7, 72, 360])
def test_sectors_never_straddle_the_sweep_start(start, cw, sectors):
    n = 360
    starts, stops, times = column_sectors(n, sectors, start, cw)
    assert starts[0] == 0 and stops[-1] == n and np.array_equal(starts[1:], stops[:-1])
    tc = column_times(n, start, cw)
    for a, b, t in zip(starts, stops, times):
        assert np.all(np.abs(np.diff(tc[a:b])) < 0.5)  # times of a sector run on without a wrap
        assert t == pytest.approx(tc[a:b].mean())
    assert len(starts) in (min(sectors, n), min(sectors, n) + 1)


@pytest.mark.parametrize("start, cw", [(0.0, False), (180.0, True)])
def test_raw_frame_is_direction_times_range_and_deskews_onto_the_wall(start, cw):
    sc = wall_scanner("embree")
    eff = Effects(motion=True, motion_frame="firing", sweep_start_deg=start, sweep_clockwise=cw)
    es = simulate(sc, None, PATTERN, eff, poses=[START, END])
    assert es.frame == "firing" and len(es) > 100
    # a raw frame: each return along its pulse's own direction in the sensor frame it fired from
    dirs = pulse_rays(PATTERN)[0].reshape(*PATTERN.shape, 3)[es.pulses[:, 0], es.pulses[:, 1]]
    assert np.allclose(es.points, dirs * es.ranges[:, None], atol=1e-9)
    # deskewed (time from each point's azimuth) it lands on the wall x = 10 in the world
    world = deskew(es.points, [START, END], start, cw)
    assert np.allclose(world[:, 0], 10.0, atol=1e-6)
    # and the same returns written at the sweep's end are those world points in the end frame
    end = simulate(sc, None, PATTERN, Effects(motion=True, sweep_start_deg=start, sweep_clockwise=cw),
                   poses=[START, END])
    assert np.allclose(end.points, to_frame(world, END), atol=1e-6)


def test_firing_frames_undo_each_columns_pose():
    rng = np.random.default_rng(3)
    n = 90
    h = rng.integers(0, n, 500)
    local = rng.normal(size=(500, 3)) * 10
    poses = [START, pose([1.0, 0.5, 0.2], yaw_deg=-20, pitch_deg=3), END]
    starts, _, times = column_sectors(n, 12, 180.0, True)
    rot, org = interpolate_poses(poses, times)
    sec = np.searchsorted(starts, h, side="right") - 1
    world = np.einsum("mij,mj->mi", rot[sec], local) + org[sec]
    assert np.allclose(to_firing_frames(world, h, n, poses, 12, 180.0, True), local, atol=1e-9)


def test_sweep_options_are_checked():
    with pytest.raises(InputValueError, match="motion_frame"):
        Effects(motion_frame="start")
    with pytest.raises(InputValueError, match="sweep_clockwise"):
        Effects(sweep_clockwise="yes")
    with pytest.raises(InputValueError, match="sweep_start_deg"):
        Effects(sweep_start_deg=float("nan"))


def test_to_frame_is_one_function_and_undoes_its_pose():
    # one to_frame (#47): the sequence's unions use the motion effect's, and it inverts R p + t
    # to rounding for any rotation and a far-off translation
    import slr_ray.sequence
    import slr_ray.sequence.union

    assert slr_ray.sequence.union.to_frame is to_frame and slr_ray.sequence.to_frame is to_frame
    rng = np.random.default_rng(3)
    for _ in range(20):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        T = pose()
        T[:3, :3] = q * np.sign(np.linalg.det(q))
        T[:3, 3] = rng.normal(size=3) * 10 ** rng.uniform(0, 6)
        local = rng.normal(size=(200, 3)) * 50
        got = to_frame(local @ T[:3, :3].T + T[:3, 3], T)
        assert got.dtype == np.float64
        assert np.allclose(got, local, atol=1e-9 * max(1.0, np.abs(T[:3, 3]).max()))
