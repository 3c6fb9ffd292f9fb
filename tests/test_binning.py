"""Internals of the binning backend: the fast angle path and the two table kinds."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slr_ray import ScanAccumulator, ScanPattern, simulate_scan
from slr_ray.backends import binning
from slr_ray.backends.binning import BinTables, _kernel_params, _keys_exact, pulse_keys

from conftest import brute_force_scan


def exact_keys(points, origin, pattern):
    params = _kernel_params(origin, pattern)
    keys = np.empty(len(points), np.int64)
    _keys_exact(np.ascontiguousarray(points, np.float64), *params[:9], keys)
    return keys


def near_edge_points(pattern, n=20000, seed=0, eps=(0.0, 1e-15, 1e-12, 1e-9, 1e-7)):
    """Directions within eps radians of pulse edges, at many ranges."""
    rng = np.random.default_rng(seed)
    d_theta, d_phi, th0, th1 = pattern.radians
    nv, nh = pattern.shape
    v = rng.integers(0, nv + 1, n)
    h = rng.integers(0, nh + 1, n)
    e = rng.choice(eps, size=(n, 2)) * rng.choice([-1, 1], size=(n, 2))
    theta = np.clip(th0 + v * d_theta + e[:, 0], 0, np.pi)
    phi = h * d_phi + e[:, 1]
    r = 10 ** rng.uniform(-3, 4, n)
    return np.column_stack([r * np.sin(theta) * np.cos(phi), r * np.sin(theta) * np.sin(phi),
                            r * np.cos(theta)])


@pytest.mark.parametrize("pattern", [
    ScanPattern(0.144), ScanPattern(0.036, zenith_range=(0, 135)), ScanPattern(0.00576),
    ScanPattern(azimuth_resolution=0.622, zenith_resolution=0.048, zenith_range=(30, 130)),
    ScanPattern(7.0), ScanPattern(90.0), ScanPattern(0.001),
])
def test_fast_path_equals_libm_near_edges(pattern):
    pts = near_edge_points(pattern)
    keys, _ = pulse_keys(pts, np.zeros(3), pattern)
    np.testing.assert_array_equal(keys, exact_keys(pts, np.zeros(3), pattern))


@settings(max_examples=200, deadline=None)
@given(xyz=st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3),
       res=st.sampled_from([0.001, 0.0144, 0.144, 1.0, 33.3]))
def test_fast_path_equals_libm_anywhere(xyz, res):
    pattern = ScanPattern(res)
    pts = np.array([xyz])
    keys, ranges = pulse_keys(pts, np.zeros(3), pattern)
    if ranges[0] > 0:  # below ~1e-154 m the squared range underflows: "at the origin"
        assert keys[0] == exact_keys(pts, np.zeros(3), pattern)[0]
    else:
        assert keys[0] == -1


def test_axes_and_signed_zeros_take_the_exact_path():
    pts = np.array([[0.0, 0, 1], [0, 0, -1], [-0.0, 0, 1], [1, 0, 0], [-1, 0, 0], [-1, -0.0, 0],
                    [0, 1, 0], [0, -1, 0], [1e-300, 1e-300, 1], [1, 1, 0.0]])
    pattern = ScanPattern(1.0)
    keys, _ = pulse_keys(pts, np.zeros(3), pattern)
    np.testing.assert_array_equal(keys, exact_keys(pts, np.zeros(3), pattern))


def test_dense_and_hash_tables_agree():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(50000, 3)) * 10
    pattern = ScanPattern(0.5)
    dense = BinTables(np.zeros(3), pattern, 2)
    assert dense.dense
    dense.add(pts)
    old = BinTables.dense_bytes
    try:
        BinTables.dense_bytes = 0
        hashed = BinTables(np.zeros(3), pattern, 2)
        assert not hashed.dense
        hashed.add(pts)
    finally:
        BinTables.dense_bytes = old
    for a, b in zip(dense.winners(), hashed.winners()):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(hashed.winners(pts), hashed.winners()):
        np.testing.assert_array_equal(a, b)


def test_hash_tables_grow_through_many_bins(monkeypatch):
    # forces many growth steps from the 4096-slot start, across superblocks
    monkeypatch.setattr(BinTables, "superblock", 1000)
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(40000, 3))
    acc = ScanAccumulator(np.zeros(3), 0.01, n_threads=3)
    acc.add(pts)
    expected = brute_force_scan(pts, np.zeros(3), ScanPattern(0.01))
    assert acc.n_bins == len(expected) > 39990
    np.testing.assert_array_equal(acc.result().indices, expected)


def test_default_threads_is_positive():
    assert binning.default_threads() >= 1
    with pytest.raises(ValueError):
        BinTables(np.zeros(3), ScanPattern(1.0), n_threads=-1)


def test_numba_kernels_are_cached_to_disk():
    # compile once, load afterwards: the CLI and the tests must not recompile
    assert binning._block_keys._cache is not None
    assert simulate_scan(np.ones((3, 3)), np.zeros(3), 1.0).n_input == 3
