"""simulate_scan with the binning backend: the nearest-in-pulse rule, exactly."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import slr_ray
from slr_ray import InputTypeError, InputValueError, ScanPattern, simulate_scan

from conftest import brute_force_scan, scene_cloud


@pytest.mark.parametrize("res", [0.5, 2.0, 10.0])
@pytest.mark.parametrize("seed", range(3))
def test_equals_brute_force(res, seed, table_kind):
    pts = scene_cloud(3000, seed)
    pattern = ScanPattern(res, zenith_range=(10, 160), min_range=0.5, max_range=25)
    scan = simulate_scan(pts, [0.3, -0.2, 0.1], pattern)
    np.testing.assert_array_equal(scan.indices, brute_force_scan(pts, [0.3, -0.2, 0.1], pattern))


coords = st.floats(-50, 50, allow_nan=False, width=64)


@settings(max_examples=60, deadline=None)
@given(
    pts=arrays(np.float64, st.tuples(st.integers(0, 300), st.just(3)), elements=coords),
    res=st.sampled_from([0.7, 3.0, 15.0, 45.0, 90.0]),
    threads=st.sampled_from([1, 2, 3]),
)
def test_equals_brute_force_hypothesis(pts, res, threads):
    pattern = ScanPattern(res)
    scan = simulate_scan(pts, [1.0, 2.0, 0.5], pattern, n_threads=threads)
    np.testing.assert_array_equal(scan.indices, brute_force_scan(pts, [1.0, 2.0, 0.5], pattern))


def test_result_fields_are_consistent(table_kind):
    pts = scene_cloud(5000, 1)
    pattern = ScanPattern(1.0)
    scan = simulate_scan(pts, [0, 0, 0], pattern)
    v, h, r, vis = slr_ray.pulse_bins(pts, [0, 0, 0], pattern)
    assert scan.indices.dtype == np.intp and np.all(np.diff(scan.indices) > 0)
    np.testing.assert_array_equal(scan.ranges, r[scan.indices])
    np.testing.assert_array_equal(scan.pulses, np.column_stack([v, h])[scan.indices])
    assert len(np.unique(scan.pulse_ids)) == len(scan)  # one point per pulse
    assert scan.n_input == len(pts) and scan.backend == "binning"


def test_occlusion_along_a_line():
    pts = np.array([[3.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [0, 0, 5.0]])
    assert simulate_scan(pts, [0, 0, 0], 1.0).indices.tolist() == [1, 3]


def test_ties_go_to_the_lowest_index(table_kind):
    pts = np.array([[1.0, 0.001, 0.01], [1.5, 0.0015, 0.015], [1.0, 0.001, 0.01]])
    # points 0 and 2 are identical; both are in one pulse with point 1 at a larger range
    scan = simulate_scan(pts, [0, 0, 0], ScanPattern(5.0), n_threads=2)
    assert scan.indices.tolist() == [0]
    # duplicates split across threads and chunks: still the lowest index
    many = np.repeat([[2.0, 2.0, 2.0]], 101, axis=0)
    assert simulate_scan(many, [0, 0, 0], 1.0, n_threads=3).indices.tolist() == [0]


def test_idempotent(table_kind):
    pts = scene_cloud(20000, 2)
    pattern = ScanPattern(0.8)
    first = simulate_scan(pts, [1, 1, 0], pattern)
    again = simulate_scan(pts[first.indices], [1, 1, 0], pattern)
    assert len(again) == len(first)
    np.testing.assert_array_equal(again.indices, np.arange(len(first)))


def test_translation_by_utm_offsets(table_kind):
    pts = scene_cloud(20000, 3)
    pattern = ScanPattern(0.5)
    base = simulate_scan(pts, [0.5, 0.25, 0.0], pattern)
    shift = np.array([5e6, 5e6, 100.0])
    moved = simulate_scan(pts + shift, np.array([0.5, 0.25, 0.0]) + shift, pattern)
    # the shifted coordinates are rounded to the float64 grid at 5e6 (1e-9 m):
    # only points within that of a bin edge may change bins
    diff = np.setxor1d(base.indices, moved.indices)
    assert len(diff) <= 2, diff
    assert len(base) > 1000


def test_float32_gives_what_its_float64_copy_gives():
    pts = (scene_cloud(20000, 4) + [4e5, 5e6, 50]).astype(np.float32)
    o = np.array([4e5 + 1.5, 5e6 - 2.0, 50.0])
    a = simulate_scan(pts, o, 0.5)
    b = simulate_scan(pts.astype(np.float64), o, 0.5)
    np.testing.assert_array_equal(a.indices, b.indices)
    np.testing.assert_array_equal(a.ranges, b.ranges)


def test_same_input_same_result_any_thread_count():
    pts = scene_cloud(30000, 5)
    ref = simulate_scan(pts, [0, 0, 0], 0.3, n_threads=1)
    for n in (2, 3, 7):
        np.testing.assert_array_equal(simulate_scan(pts, [0, 0, 0], 0.3, n_threads=n).indices, ref.indices)


# --- extremes ---------------------------------------------------------------

def test_zenith_axis_and_poles():
    pts = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, 2.0], [0.0, -0.0, -3.0]])
    scan = simulate_scan(pts, [0, 0, 0], 1.0)
    assert scan.indices.tolist() == [0, 1]
    assert scan.pulses.tolist() == [[0, 0], [179, 0]]


@pytest.mark.parametrize("angle", [0.0, np.pi, 2 * np.pi - 1e-12, -1e-15, np.pi / 2])
def test_azimuth_edges_are_in_range_and_deterministic(angle):
    pts = np.array([[np.cos(angle), np.sin(angle), 0.0]])
    pattern = ScanPattern(1.0)
    a = simulate_scan(pts, [0, 0, 0], pattern)
    assert len(a) == 1 and 0 <= a.pulses[0, 1] < 360 and 0 <= a.pulses[0, 0] < 180
    assert np.array_equal(a.pulses, simulate_scan(pts, [0, 0, 0], pattern).pulses)


def test_azimuth_wrap_bins_near_two_pi_in_the_last_bin():
    pts = np.array([[1.0, -1e-9, 0.0], [1.0, 1e-9, 0.0]])
    scan = simulate_scan(pts, [0, 0, 0], 1.0)
    assert scan.pulses[:, 1].tolist() == [359, 0]


def test_points_on_bin_edges_are_deterministic():
    deg = np.radians(np.arange(0, 360, 1.0))
    pts = np.column_stack([np.cos(deg), np.sin(deg), np.zeros_like(deg)])
    scans = [simulate_scan(pts, [0, 0, 0], 1.0, n_threads=t) for t in (1, 2)]
    np.testing.assert_array_equal(scans[0].indices, scans[1].indices)
    # a point on an edge lands on one side of it (float rounding decides, the same way every time)
    v, h, _, _ = slr_ray.pulse_bins(pts, [0, 0, 0], ScanPattern(1.0))
    k = np.arange(360)
    assert np.all((h == k) | (h == (k - 1) % 360))
    assert np.all(v == 89) | np.all(v == 90) or set(v.tolist()) <= {89, 90}
    np.testing.assert_array_equal(scans[0].pulses, np.column_stack([v, h])[scans[0].indices])


@pytest.mark.parametrize("r", [1e-3, 1.0, 1e4])
def test_ranges_from_a_millimetre_to_ten_kilometres(r):
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    scan = simulate_scan(d * r + [7, 8, 9], [7, 8, 9], 5.0)
    np.testing.assert_allclose(scan.ranges, r, rtol=1e-9)
    ref = simulate_scan(d, [0, 0, 0], 5.0)
    assert abs(len(scan) - len(ref)) <= 2


def test_tiny_resolution_needs_no_dense_grid():
    # 0.001 deg is 6.5e10 pulses: the reduction must not allocate them
    pts = scene_cloud(20000, 6)
    scan = simulate_scan(pts, [0, 0, 0], 0.001)
    assert len(scan) == len(np.unique(pts, axis=0)) - 0  # every point its own pulse
    assert scan.pulses[:, 1].max() < 360000


def test_coarse_resolution_90_degrees():
    pts = np.array([[1.0, 1, 1], [-1, 1, 1], [-1, -1, 1], [1, -1, -1], [2, 2, 2]])
    scan = simulate_scan(pts, [0, 0, 0], 90.0)
    assert scan.indices.tolist() == [0, 1, 2, 3]
    assert scan.pulses.tolist() == [[0, 0], [0, 1], [0, 2], [1, 3]]


def test_point_at_origin_is_not_seen():
    pts = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    assert simulate_scan(pts, [0, 0, 0], 1.0).indices.tolist() == [1]


def test_empty_input():
    scan = simulate_scan(np.empty((0, 3)), [0, 0, 0], 1.0)
    assert len(scan) == 0 and scan.indices.dtype == np.intp and scan.pulses.shape == (0, 2)


def test_field_of_view_and_range_limits():
    pts = np.array([[0, 0, 1.0], [1, 0, 0], [0, 1, -1], [10, 0, 0.1], [0.1, 0, 0.001]])
    pattern = ScanPattern(1.0, zenith_range=(45, 135), min_range=0.5, max_range=5)
    # zenith 0 (out), 90, 135 (kept: edge inclusive), 10 m (out), 0.1 m (out)
    assert simulate_scan(pts, [0, 0, 0], pattern).indices.tolist() == [1, 2]


# --- bad input ---------------------------------------------------------------

def test_nonfinite_rows_raise_with_count(table_kind):
    pts = scene_cloud(100, 0)
    pts[[3, 50, 70]] = np.nan
    pts[10, 2] = -np.inf
    with pytest.raises(InputValueError, match="4 row"):
        simulate_scan(pts, [0, 0, 0], 1.0)


@pytest.mark.parametrize("pts, exc", [
    (np.zeros((5, 2)), InputValueError), (np.zeros(3), InputValueError),
    (np.zeros((5, 3), complex), InputTypeError), (np.array([[None, 1, 2]]), InputTypeError),
])
def test_bad_points(pts, exc):
    with pytest.raises(exc, match="points"):
        simulate_scan(pts, [0, 0, 0], 1.0)


@pytest.mark.parametrize("origin", [[0, 0], np.zeros((1, 3)), [0, 0, np.inf]])
def test_bad_origin(origin):
    with pytest.raises(InputValueError, match="origin"):
        simulate_scan(np.zeros((2, 3)), origin, 1.0)


def test_bad_backend_and_pattern():
    with pytest.raises(InputValueError, match="unknown backend"):
        simulate_scan(np.zeros((2, 3)), [0, 0, 0], 1.0, backend="magic")
    with pytest.raises(InputTypeError, match="pattern"):
        simulate_scan(np.zeros((2, 3)), [0, 0, 0], [1.0])
    assert simulate_scan(np.ones((2, 3)), [0, 0, 0], "slr").pattern.resolution == 0.144
