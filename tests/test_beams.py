"""The beam-table reduction (slr_ray.core.beams.beam_reduce: row lookup table,
fast azimuths) against the definition point by point, at the edges of its fast
path: band edges, column edges, the azimuth and mod-2-pi wraps, the poles,
float32 and far-away clouds, empty and one-point clouds, several threads."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slr_ray import prepare
from slr_ray.core.beams import ROW_CELLS, row_table
from slr_ray.sensors import BeamPattern, sensor
from slr_ray.sequence.union import to_frame


def nearest_per_key(keys, ranges):
    """Indices (ascending) of the nearest point per key >= 0, ties to the lowest index."""
    sel = np.flatnonzero(keys >= 0)
    order = np.lexsort((sel, ranges[sel], keys[sel]))
    k = keys[sel][order]
    first = np.ones(len(k), bool)
    first[1:] = k[1:] != k[:-1]
    return np.sort(sel[order][first])


def check(pattern, pts, origin, n_threads=None):
    """reduce() against pulse_ids (binary search and libm atan2 for every point: the
    definition, itself tested against a plain-Python loop in test_sensors)."""
    keys, ranges, idx = pattern.reduce(pts, origin, n_threads)
    k_ref, r_ref = pattern.pulse_ids(np.asarray(pts, np.float64), origin)
    want = nearest_per_key(k_ref, r_ref)
    np.testing.assert_array_equal(idx, want)
    np.testing.assert_array_equal(keys, k_ref[want])
    np.testing.assert_array_equal(ranges, r_ref[want])
    return idx


def edge_directions(pattern, n, rng, ulps=(0, 1, 2, 5, 1000)):
    """Unit directions on band edges and column edges (of each row's offset), on the
    +-180 deg azimuth wrap and on 0, moved by a few ulps either way."""
    rows = rng.integers(0, pattern.n_beams, n)
    zen = pattern.band_edges[rng.integers(0, pattern.n_beams + 1, n)]
    cols = rng.integers(0, pattern.columns + 1, n)
    az = pattern.row_offsets[rows] + cols * (2 * math.pi / pattern.columns)
    wrap = rng.random(n) < 0.2
    az[wrap] = rng.choice([math.pi, -math.pi, 0.0], wrap.sum())
    step = rng.choice(ulps, n) * rng.choice([-1, 1], n)
    zen = zen + step * np.spacing(np.abs(zen) + 1e-300)
    az = az + rng.choice(ulps, n) * rng.choice([-1, 1], n) * np.spacing(np.abs(az) + 1e-300)
    return np.column_stack([np.sin(zen) * np.cos(az), np.sin(zen) * np.sin(az), np.cos(zen)])


@pytest.mark.parametrize("name", ["velodyne_hdl64e_s2", "velodyne_vlp16", "ouster_os1_64", "velodyne_vls128"])
def test_edges_of_bands_columns_and_wraps(name):
    rng = np.random.default_rng(1)
    p = sensor(name, min_range=0.5, max_range=60.0)
    d = edge_directions(p, 40000, rng)
    pts = d * rng.choice([0.4, 0.5, 1.0, 7.3, 59.999, 60.0, 60.001, 100.0], (len(d), 1))
    # exact multiples of directions: rows land on each side of an edge by rounding alone
    pts = np.vstack([pts, d[:2000] * 3.0, d[:2000] * 30.0, -d[:2000]])
    idx = check(p, pts, np.zeros(3), n_threads=1)
    assert len(idx) > 1000


def test_signed_zero_azimuth_and_the_poles():
    # a beam table reaching both poles: x = y = 0 (the fast atan2 gives NaN there), and
    # y = +0.0 / -0.0 behind the scanner (atan2 gives +pi / -pi)
    # (elevations 60, 0, -60: the top band's edge is the zenith itself, the bottom one's the nadir)
    p = BeamPattern([60.0, 0.0, -60.0], columns=8, azimuth_offset_deg=[0.0, 22.5, -180.0])
    pts = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [-0.0, 0.0, 2.0], [0.0, -0.0, -2.0],
                    [-1.0, 0.0, 0.0], [-1.0, -0.0, 0.0], [-1.0, 0.0, 5.0], [-1.0, -0.0, -5.0],
                    [1.0, 0.0, 0.0], [1.0, -0.0, 0.0], [-2.0, 1e-300, 0.0], [-2.0, -1e-300, 0.0],
                    [0.0, 0.0, 0.0]])
    keys, _, idx = p.reduce(pts, np.zeros(3), 1)
    check(p, pts, np.zeros(3), n_threads=1)
    assert 0 in idx and 1 not in idx  # the zenith is seen, the nadir not (bands are half-open)
    assert 12 not in idx  # range 0


@pytest.mark.parametrize("offset", [0.46364762, math.atan(0.5) + 1e-8, math.atan(0.5) - 2e-8, math.atan(0.5)])
def test_points_a_subnormal_distance_off_the_axis_take_the_exact_azimuth(offset):
    # (1e-323, 5e-324) lies at atan(0.5) exactly; among subnormals the fast atan2's
    # branch test rounds and it was 3e-8 rad off, beyond its margin: with a beam
    # firing ~atan(0.5) off it, the point landed in the wrong column (0 for 359)
    p = BeamPattern([60.0, 0.0, -60.0], columns=360, azimuth_offset_deg=[math.degrees(offset), 0.0, 0.0])
    pts = np.array([[1e-323, 5e-324, 1.0], [5e-324, 1e-323, 2.0], [-1e-323, -5e-324, 2.5],
                    [1e-301, 5e-302, 2.7], [1.0, 0.5, 3.0]])
    check(p, pts, np.zeros(3), n_threads=1)


def test_close_beams_need_several_steps_from_the_table():
    # bands far narrower than a cell of the row table: the hint is off by several rows
    el = [0.0, 1e-5, 2e-5, 3e-5, 4e-5, -40.0]
    p = BeamPattern(el, columns=360)
    lut, scale = row_table(p._cos_edges, ROW_CELLS)
    assert (np.diff(p._cos_edges).min() * scale) < 1e-3  # several edges in one cell
    rng = np.random.default_rng(2)
    zen = np.radians(90 - rng.uniform(-1e-4, 1e-4, 20000))
    zen = np.concatenate([zen, p.band_edges, np.nextafter(p.band_edges, 0), np.nextafter(p.band_edges, 4)])
    az = rng.uniform(-math.pi, math.pi, len(zen))
    pts = np.column_stack([np.sin(zen) * np.cos(az), np.sin(zen) * np.sin(az), np.cos(zen)]) * 10
    check(p, pts, np.zeros(3), n_threads=1)
    assert len(np.unique(p.reduce(pts, np.zeros(3), 1)[0] // 360)) >= 4  # rows reached


def test_float32_clouds_and_clouds_far_from_their_origin():
    rng = np.random.default_rng(3)
    p = sensor("velodyne_hdl64e_s2")
    local = rng.normal(size=(50000, 3)) * [30, 30, 3]
    pts32 = local.astype(np.float32)
    # float32 points are widened point by point: the float64 cloud of the same values
    a = p.reduce(pts32, np.array([0.5, -0.25, 1.0]), 1)
    b = p.reduce(pts32.astype(np.float64), np.array([0.5, -0.25, 1.0]), 1)
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)
    check(p, pts32, np.array([0.5, -0.25, 1.0]), n_threads=1)
    # UTM-like coordinates: the origin is subtracted in float64 first
    origin = np.array([4.5e5, 5.2e6, 80.0])
    check(p, origin + local, origin, n_threads=2)
    far = np.vstack([origin + edge_directions(p, 5000, rng) * 20.0, origin + local[:5000]])
    check(p, far, origin, n_threads=1)


def test_empty_and_one_point_clouds():
    p = sensor("velodyne_vlp16")
    keys, ranges, idx = p.reduce(np.empty((0, 3)), np.zeros(3))
    assert len(keys) == len(ranges) == len(idx) == 0
    keys, ranges, idx = p.reduce(np.array([[10.0, 0.0, 0.0]]), np.zeros(3))
    assert idx.tolist() == [0] and ranges.tolist() == [10.0] and keys.tolist() == [p.columns * 8]
    assert len(p.reduce(np.array([[0.0, 0.0, 10.0]]), np.zeros(3))[2]) == 0  # above the top band
    assert len(prepare(np.empty((0, 3))).scan([0, 0, 0], p)) == 0


@pytest.mark.parametrize("n_threads", [1, 2, 3])
def test_threads_split_the_points_and_ties_keep_the_lowest_index(n_threads):
    # enough points for several threads; every point repeated far away in the input
    # (the copy falls to another thread), so each pulse's nearest point is tied
    rng = np.random.default_rng(4)
    base = rng.normal(size=(150000, 3)) * [20, 20, 2]
    pts = np.vstack([base, base[::-1]])
    p = sensor("velodyne_hdl64e_s2")
    idx = check(p, pts, np.array([1.0, 2.0, 0.5]), n_threads=n_threads)
    assert idx.max() < len(base)  # no copy beats its original


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), name=st.sampled_from(["velodyne_hdl64e_s2", "ouster_os1_128"]))
def test_any_cloud_any_origin(seed, name):
    rng = np.random.default_rng(seed)
    p = sensor(name, max_range=float(rng.uniform(5, 200)))
    origin = rng.normal(size=3) * 10 ** rng.uniform(0, 6)
    pts = origin + rng.normal(size=(4000, 3)) * 10 ** rng.uniform(-1, 2)
    pts[:500] = origin + edge_directions(p, 500, rng) * rng.uniform(0.1, 50, (500, 1))
    check(p, pts, origin, n_threads=int(rng.integers(1, 4)))


def test_posed_reduction_moves_each_point_as_to_frame_does():
    # world points seen from a rotated, far-off pose: the same returns as reducing to_frame's copy,
    # ties (every point twice) to the lower index, a block boundary crossed
    rng = np.random.default_rng(7)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    pose = np.eye(4)
    pose[:3, :3] = q * np.sign(np.linalg.det(q))
    pose[:3, 3] = [4.0e5, -3.0e6, 120.0]
    local = rng.normal(size=(6000, 3)) * [30, 30, 3]
    world = np.vstack([local, local]) @ pose[:3, :3].T + pose[:3, 3]
    p = sensor("velodyne_vlp16")
    got = p.reduce_posed(world, pose)
    want = p.reduce(to_frame(world, pose), np.zeros(3), n_threads=1)
    assert len(got[0]) > 1000 and got[2].max() < 6000
    for a, b in zip(got, want):
        assert np.array_equal(a, b)


def test_float64_points_compile_the_block_reduction_once(tmp_path):
    """A cold numba cache compiles a kernel once per argument types: the one-thread, the
    parallel and the posed reductions hand ``_reduce_block`` and ``row_table`` the same
    types (a literal 0, an omitted ``base`` and a literal table size were three more).
    Run in a process with an empty cache of its own: ``_reduce_block`` is called from compiled
    callers only, so a warm cache loads them and its signatures stay empty (the test passed
    cold only)."""
    import os
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import numpy as np
        from slr_ray.core.beams import ROW_CELLS, _reduce_block, row_table
        from slr_ray.sensors import sensor
        p = sensor("velodyne_vlp16")
        pts = np.random.default_rng(0).normal(size=(500, 3)) * 10
        p.reduce(pts, np.zeros(3), n_threads=1)
        p.reduce(pts, np.zeros(3), n_threads=2)
        p.reduce_posed(pts, np.eye(4))
        row_table(p._cos_edges, ROW_CELLS)
        print(len([s for s in _reduce_block.signatures if s[0].dtype.bitwidth == 64]), len(row_table.signatures))
    """)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert r.stdout.split() == ["1", "1"], r.stdout + r.stderr
