"""The pulse geometry of slr_ray.core: the fast angle path against libm, and the
three table kinds against each other and a brute-force reference."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slr_ray import ScanAccumulator, ScanPattern
from slr_ray.core import BinTables, grid, pulse_ids, tables
from slr_ray.core.grid import block_keys_range, kernel_params, keys_exact
from slr_ray.errors import StateError
from slr_ray.errors import InputValueError
from slr_ray.threads import default_threads

from conftest import brute_force_scan


def exact_keys(points, origin, pattern):
    params = kernel_params(origin, pattern)
    keys = np.empty(len(points), np.int64)
    keys_exact(np.ascontiguousarray(points, np.float64), *params[:9], keys)
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
    keys, _ = pulse_ids(pts, np.zeros(3), pattern)
    np.testing.assert_array_equal(keys, exact_keys(pts, np.zeros(3), pattern))


@settings(max_examples=200, deadline=None)
@given(xyz=st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3),
       res=st.sampled_from([0.001, 0.0144, 0.144, 1.0, 33.3]))
def test_fast_path_equals_libm_anywhere(xyz, res):
    pattern = ScanPattern(res)
    pts = np.array([xyz])
    keys, ranges = pulse_ids(pts, np.zeros(3), pattern)
    if ranges[0] > 0:  # below ~1e-154 m the squared range underflows: "at the origin"
        assert keys[0] == exact_keys(pts, np.zeros(3), pattern)[0]
    else:
        assert keys[0] == -1


@pytest.mark.parametrize("pattern", [
    ScanPattern(0.5, zenith_range=(45, 45.000001)),  # a view narrower than twice the margin
    ScanPattern(1e-6, zenith_range=(45, 45.000001)),
    ScanPattern(0.144, zenith_range=(0, 0.5)),  # the pole at the view's edge
])
def test_fast_path_equals_libm_in_views_narrower_than_its_margins(pattern):
    pts = near_edge_points(pattern, eps=(0.0, 1e-15, 1e-12, 1e-9, 5e-9, 1e-8, 2e-8, 1e-7))
    keys, _ = pulse_ids(pts, np.zeros(3), pattern)
    np.testing.assert_array_equal(keys, exact_keys(pts, np.zeros(3), pattern))
    assert (keys >= 0).any() and (keys == -1).any()


def test_fast_path_keeps_its_margin_at_a_view_edge_between_bin_edges():
    # 70.3 deg of view in 2 deg bins: the view ends inside a bin, where only the
    # view's margin sends a point to libm; the polynomial is 3.8e-12 rad low at
    # 100.3 deg, so without the margin points just outside would be kept
    pattern = ScanPattern(2.0, zenith_range=(30, 100.3))
    th1 = pattern.radians[3]
    rng = np.random.default_rng(3)
    n = 5000
    theta = th1 + rng.uniform(-2e-11, 2e-11, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = rng.uniform(0.5, 50, n)
    pts = np.column_stack([r * np.sin(theta) * np.cos(phi), r * np.sin(theta) * np.sin(phi), r * np.cos(theta)])
    ref = exact_keys(pts, np.zeros(3), pattern)
    assert (ref == -1).sum() > n // 4 and (ref >= 0).sum() > n // 4
    np.testing.assert_array_equal(pulse_ids(pts, np.zeros(3), pattern)[0], ref)


@pytest.mark.parametrize("where", [0, 1, grid.BLOCK // 2, grid.BLOCK - 1])
@pytest.mark.parametrize("odd", [[0.0, 0.0, 1.0], [2.0, 0.0, 0.5], [np.nan, 1.0, 1.0], [1.0, np.inf, 0.0],
                                 [0.0, 0.0, 0.0]])
def test_a_block_runs_the_exact_pass_whenever_one_point_needs_it(where, odd):
    # the second pass counts the points it leaves undecided, and a block skips the
    # third only when there are none: one such point anywhere in a block is decided
    pattern = ScanPattern(1.0)
    rng = np.random.default_rng(where)
    theta = np.radians(rng.integers(1, 179, grid.BLOCK) + rng.uniform(0.1, 0.9, grid.BLOCK))
    phi = np.radians(rng.integers(0, 360, grid.BLOCK) + rng.uniform(0.1, 0.9, grid.BLOCK))
    pts = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    pts *= rng.uniform(0.5, 50, (grid.BLOCK, 1))
    params = kernel_params(np.zeros(3), pattern)
    ref = exact_keys(pts, np.zeros(3), pattern)
    keys = np.empty(grid.BLOCK, np.int64)
    ranges = np.empty(grid.BLOCK)
    keys[:], ranges[:] = pulse_ids(pts, np.zeros(3), pattern)  # every point sure: no third pass
    np.testing.assert_array_equal(keys, ref)
    pts[where] = odd
    work = grid.scratch()
    bad = grid.block_keys(pts, 0, grid.BLOCK, *params, *work)
    keys = work[5][:grid.BLOCK]
    finite = bool(np.isfinite(odd).all())
    assert bad == (0 if finite else 1)
    assert keys[where] == (exact_keys(pts[where:where + 1], np.zeros(3), pattern)[0] if any(odd) and finite
                           else -1 if finite else -2)
    others = np.arange(grid.BLOCK) != where
    np.testing.assert_array_equal(keys[others], ref[others])


@pytest.mark.parametrize("zenith_range", [(0, 180), (3, 180), (0, 30)])
def test_fast_path_equals_libm_where_the_squares_are_subnormal(zenith_range):
    # below ~1e-154 m the squares in the fast angles are subnormal: sqrt(dx*dx + dy*dy)
    # is off by up to ~2e-162 m while the range stays > 0, so the fast zenith was off
    # by up to 0.1 rad and the sure-keys pass gave a wrong bin (2e-162, 3e-162, 1e-161:
    # 7616 for 6896), called a point outside the view that is in it ((1e-162, 0,
    # 1e-161) in a 3-180 deg view) or one in the view that is not ((1e-162, 4e-162,
    # 7e-162) in a 0-30 deg view)
    pattern = ScanPattern(1.0, zenith_range=zenith_range)
    pts = np.array([[2e-162, 3e-162, 1e-161], [1e-162, 0.0, 1e-161], [1e-162, 4e-162, 7e-162],
                    [-5e-162, 1e-162, 5e-162], [3e-160, -2e-160, 1e-159], [1e-150, 2e-150, 3e-150]])
    keys, ranges = pulse_ids(pts, np.zeros(3), pattern)
    assert (ranges > 0).all()
    np.testing.assert_array_equal(keys, exact_keys(pts, np.zeros(3), pattern))
    rng = np.random.default_rng(0)
    pts = np.round(rng.uniform(-9, 9, (4 * grid.BLOCK, 3))) * 10.0 ** rng.integers(-163, -150, (4 * grid.BLOCK, 1))
    keys, ranges = pulse_ids(pts, np.zeros(3), pattern)
    ref = exact_keys(pts, np.zeros(3), pattern)
    ref[ranges == 0] = -1
    np.testing.assert_array_equal(keys, ref)


def test_axes_and_signed_zeros_take_the_exact_path():
    pts = np.array([[0.0, 0, 1], [0, 0, -1], [-0.0, 0, 1], [1, 0, 0], [-1, 0, 0], [-1, -0.0, 0],
                    [0, 1, 0], [0, -1, 0], [1e-300, 1e-300, 1], [1, 1, 0.0]])
    pattern = ScanPattern(1.0)
    keys, _ = pulse_ids(pts, np.zeros(3), pattern)
    np.testing.assert_array_equal(keys, exact_keys(pts, np.zeros(3), pattern))


def _tables(kind, origin, pattern, n_threads, monkeypatch):
    """Tables of one kind; "slots": a slot array per thread, "shared-slots": one for all."""
    monkeypatch.setattr(BinTables, "dense_bytes", 2**62 if kind == "dense" else 0)
    monkeypatch.setattr(BinTables, "slot_bytes", 2**62 if kind.endswith("slots") else 0)
    monkeypatch.setattr(BinTables, "own_slots", kind == "slots")
    t = BinTables(origin, pattern, n_threads)
    assert t.kind == kind.split("-")[-1]
    return t


def test_dense_slot_and_hash_tables_agree(monkeypatch):
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(50000, 3)) * 10
    pts[1000:1100] = pts[:100]  # exact ties: the lower index must win in every kind
    pattern = ScanPattern(0.5)
    results = {}
    for kind in ("dense", "slots", "shared-slots", "hash"):
        t = _tables(kind, np.zeros(3), pattern, 3, monkeypatch)
        t.add(pts)
        results[kind] = t.winners()
        for a, b in zip(t.winners(pts), results[kind]):  # ranges recomputed or carried: the same
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(results["dense"][2], brute_force_scan(pts, np.zeros(3), pattern))
    for kind in ("slots", "shared-slots", "hash"):
        for a, b in zip(results["dense"], results[kind]):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("kind", ["dense", "slots", "shared-slots", "hash"])
def test_reset_tables_forget_the_last_position(kind, monkeypatch):
    # a reused table must give what a fresh one gives, whether or not the last
    # scan was read out (winners) before the reset
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(30000, 3)) * 10
    pattern = ScanPattern(1.0)
    t = _tables(kind, np.zeros(3), pattern, 2, monkeypatch)
    for i, origin in enumerate(rng.normal(size=(4, 3)) * 5):
        t.reset(origin)
        t.add(pts[i * 1000:])
        if i % 2:
            t.add(pts[:1000])
        else:  # interrupted: never read out
            t.winners(pts[i * 1000:])
            t.reset(origin)
            t.add(pts)
        expected = brute_force_scan(pts, origin, pattern) if i % 2 == 0 else None
        got = t.winners()[2]
        if expected is not None:
            np.testing.assert_array_equal(got, expected)
        else:
            ref = _tables(kind, origin, pattern, 1, monkeypatch)
            ref.add(np.vstack([pts[i * 1000:], pts[:1000]]))
            np.testing.assert_array_equal(got, ref.winners()[2])


def test_accumulator_adds_after_reading_out(monkeypatch):
    # winners() then more points: the merged dense tables must still take them
    rng = np.random.default_rng(6)
    pts = rng.normal(size=(20000, 3))
    acc = ScanAccumulator(np.zeros(3), 2.0, n_threads=2)
    acc.add(pts[:10000])
    acc.result()
    acc.add(pts[10000:])
    np.testing.assert_array_equal(acc.result().indices, brute_force_scan(pts, np.zeros(3), ScanPattern(2.0)))


def test_polynomial_atan2_is_within_its_bound():
    # the fast path's correctness rests on |fast - libm| < _FAST_TOL; the
    # polynomial's own error is ~1e-11, checked here with a wide margin
    import math

    rng = np.random.default_rng(9)
    ang = np.concatenate([rng.uniform(-np.pi, np.pi, 200000),
                          (np.arange(-8, 9) * np.pi / 8 + rng.normal(scale=1e-9, size=(50, 17))).ravel()])
    r = 10 ** rng.uniform(-6, 6, len(ang))
    y, x = r * np.sin(ang), r * np.cos(ang)
    theta, fast = np.empty(len(x)), np.empty(len(x))
    grid._approx_angles(x, y, np.ones(len(x)), theta, fast, len(x))  # fast = atan2(y, x)
    exact = np.array([math.atan2(a, b) for a, b in zip(y, x)])
    assert np.abs(fast - exact).max() < 1e-10 < grid._FAST_TOL


@pytest.mark.parametrize("pattern", [
    ScanPattern(0.5, zenith_range=(40, 100), min_range=2.0, max_range=20.0),
    ScanPattern(2.0, zenith_range=(0, 135), max_range=5.0),
])
def test_fast_path_outside_the_view_and_range_limits(pattern):
    # points just inside and outside the zenith limits and the range limits
    rng = np.random.default_rng(10)
    d_theta, d_phi, th0, th1 = pattern.radians
    rmin, rmax = pattern.range_limits
    n = 20000
    theta = rng.choice([th0, th1], n) + rng.choice([-1e-7, -1e-9, 0.0, 1e-9, 1e-7, 0.3, -0.3], n)
    theta = np.clip(theta, 0, np.pi)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = np.where(rng.random(n) < 0.5, rng.uniform(0.5 * rmin, 1.5 * rmin + 1, n),
                 rmax * (1 + rng.choice([-1e-15, 0.0, 1e-15, -0.1, 0.1], n)))
    pts = np.column_stack([r * np.sin(theta) * np.cos(phi), r * np.sin(theta) * np.sin(phi), r * np.cos(theta)])
    keys, ranges = pulse_ids(pts, np.zeros(3), pattern)
    ref = exact_keys(pts, np.zeros(3), pattern)
    ref[(ranges < rmin) | (ranges > rmax) | (ranges == 0)] = -1
    np.testing.assert_array_equal(keys, ref)
    assert (keys == -1).any() and (keys >= 0).any()


@pytest.mark.parametrize("zenith_range", [(0, 180), (0, 80)])
def test_range_limits_at_a_points_own_range_and_ranges_that_overflow(zenith_range):
    # the sure-keys pass folds the range tests into r >= max(rmin, tiny) and
    # r <= min(rmax, DBL_MAX): limits set to a point's own computed range and one ulp
    # either side, a single admitted range (min_range == max_range), and finite
    # coordinates whose squared range overflows (range inf: seen without max_range,
    # not seen with one, never counted as not finite; the fast zenith of such a
    # point is 90 deg whatever its direction, inside a 7 deg bin, outside a 0-80 view)
    rng = np.random.default_rng(11)
    theta = np.radians(rng.integers(1, 179, 64) + rng.uniform(0.1, 0.9, 64))
    phi = np.radians(rng.integers(0, 360, 64) + rng.uniform(0.1, 0.9, 64))
    u = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    pts = np.concatenate([u * rng.uniform(0.5, 50, (64, 1)), u[:8] * 1e155, u[8:16] * 1e-150,
                          u[16:24] * 5e-162, [[1.0, np.inf, 0.0], [np.inf, 0.0, 1.0], [0.0, 1.0, np.nan]]])
    finite = np.isfinite(pts).all(axis=1)
    _, r = pulse_ids(pts[finite], np.zeros(3), ScanPattern(7.0))
    assert np.isinf(r[64:72]).all()
    for i in (0, 5, 64, 72, 80):
        for lo, hi in ((r[i], r[i]), (np.nextafter(r[i], np.inf), None), (None, np.nextafter(r[i], 0)),
                       (r[i], None), (None, r[i]), (0.0, 1e308), (1e-149, 1e-145)):
            pattern = ScanPattern(7.0, zenith_range=zenith_range, min_range=lo, max_range=hi)
            rmin, rmax = pattern.range_limits
            ref = exact_keys(pts[finite], np.zeros(3), pattern)
            ref[(r == 0) | (r < rmin) | (r > rmax)] = -1
            np.testing.assert_array_equal(pulse_ids(pts[finite], np.zeros(3), pattern)[0], ref)
            work = grid.scratch()
            assert grid.block_keys(pts, 0, len(pts), *kernel_params(np.zeros(3), pattern), *work) == 3
            np.testing.assert_array_equal(work[5][:len(pts)], np.concatenate([ref, [-2, -2, -2]]))


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
    assert default_threads() >= 1
    with pytest.raises(InputValueError, match="n_threads"):
        BinTables(np.zeros(3), ScanPattern(1.0), n_threads=-1)
    with pytest.raises(InputValueError, match="n_threads"):
        BinTables(np.zeros(3), ScanPattern(1.0), n_threads=257)


@pytest.mark.parametrize("kind", ["slots", "shared-slots", "hash"])
def test_released_tables_give_the_same_winners_and_refuse_more(kind, monkeypatch):
    rng = np.random.default_rng(11)
    pts = rng.normal(size=(30000, 3)) * 10
    pattern = ScanPattern(0.5)
    a = _tables(kind, np.zeros(3), pattern, 2, monkeypatch)
    b = _tables(kind, np.zeros(3), pattern, 2, monkeypatch)
    a.add(pts)
    b.add(pts)
    keep = a.winners(with_ranges=False)
    gone = b.winners(with_ranges=False, release=True)
    for x, y in zip(keep, gone):
        np.testing.assert_array_equal(x, y) if x is not None else None
    with pytest.raises(StateError, match="released"):
        b.add(pts)
    with pytest.raises(StateError, match="released"):
        b.winners()


def test_compact_and_wide_hash_records_agree_and_widen_when_indices_outgrow_them(monkeypatch):
    # 16-byte records (int32 key, uint32 index) must give exactly the 24-byte ones'
    # winners, ties included, also when a stream passes their index limit midway
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(40000, 3)) * 10
    pts[20000:20100] = pts[:100]  # exact ties: the lower index wins
    pattern = ScanPattern(0.5)
    compact = _tables("hash", np.zeros(3), pattern, 2, monkeypatch)
    assert compact.tables[0].compact and compact.tables[0].tab.itemsize == 16
    for s in range(0, len(pts), 7001):
        compact.add(pts[s:s + 7001])
    monkeypatch.setattr(tables, "_COMPACT_MAX_PULSES", 0)  # 24-byte records from the start
    wide = _tables("hash", np.zeros(3), pattern, 2, monkeypatch)
    assert not wide.tables[0].compact
    wide.add(pts)
    monkeypatch.setattr(tables, "_COMPACT_MAX_PULSES", 2**31 - 1)
    monkeypatch.setattr(tables, "_COMPACT_MAX_POINTS", 25000)  # widened at the chunk that passes it
    widened = _tables("hash", np.zeros(3), pattern, 2, monkeypatch)
    for s in range(0, len(pts), 7001):
        widened.add(pts[s:s + 7001])
        assert widened.tables[0].compact == (s + 7001 - 1 <= 25000)
    expected = brute_force_scan(pts, np.zeros(3), pattern)
    for t in (compact, wide, widened):
        keys, ranges, idx = t.winners(pts)
        np.testing.assert_array_equal(idx, expected)
        np.testing.assert_array_equal(keys, pulse_ids(pts[idx], np.zeros(3), pattern)[0])


def test_pulse_keys_split_over_threads_equal_one_pass():
    # inputs above 2**20 points are keyed by several threads: the same keys and ranges
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(3 * 2**20 + 7, 3)) * 30 + [4e5, -3e6, 20]
    origin = np.array([4e5 + 1, -3e6 - 2, 21.5])
    p = ScanPattern(0.2, max_range=80)
    keys, ranges = pulse_ids(pts, origin, p)
    k1, r1 = np.empty(len(pts), np.int64), np.empty(len(pts))
    block_keys_range(pts, *kernel_params(origin, p), k1, r1, 0, len(pts))
    np.testing.assert_array_equal(keys, k1)
    np.testing.assert_array_equal(ranges, r1)
    assert (keys == -1).any() and (keys >= 0).any()


def test_every_compiled_kernel_is_cached_to_disk():
    # compile once, load afterwards: the CLI and the tests must not recompile (a kernel
    # declared without cache=True has numba's NullCache)
    import importlib

    from numba.core.registry import CPUDispatcher

    kernels = []
    for name in ("slr_ray.core.grid", "slr_ray.core.tables", "slr_ray.core.beams"):
        mod = importlib.import_module(name)
        kernels += [(name, k) for k, v in vars(mod).items() if isinstance(v, CPUDispatcher)]
        uncached = [k for k, v in vars(mod).items() if isinstance(v, CPUDispatcher)
                    and type(v._cache).__name__ == "NullCache"]
        assert not uncached, (name, uncached)
    assert len(kernels) > 20


@pytest.mark.parametrize("kind", ["dense", "slots", "shared-slots", "hash"])
@pytest.mark.parametrize("n", [0, 1, 2, 63, 64, 65, 127, 128, 129, 4097])
def test_winners_in_index_order_at_word_boundaries(kind, n, monkeypatch):
    # the winners are put in index order by one bit a point and a count per 64-bit
    # word: indices 0, 63, 64, the last one, every point a winner or a few, empty
    rng = np.random.default_rng(n)
    pattern = ScanPattern(2.0)
    for spread in (1000.0, 0.01):  # nearly every point its own pulse / a few pulses
        pts = rng.normal(size=(n, 3)) * spread
        for n_threads in (1, 3):
            t = _tables(kind, np.zeros(3), pattern, n_threads, monkeypatch)
            t.add(pts[: n // 2])
            t.add(pts[n // 2:])
            keys, ranges, idx = t.winners()
            expected = brute_force_scan(pts, np.zeros(3), pattern)
            np.testing.assert_array_equal(idx, expected)
            k, r = pulse_ids(pts, np.zeros(3), pattern)
            np.testing.assert_array_equal(keys, k[expected])
            np.testing.assert_array_equal(ranges, r[expected])
            assert keys.dtype == idx.dtype == np.int64 and ranges.dtype == np.float64


@pytest.mark.parametrize("kind", ["slots", "shared-slots"])
def test_slot_tables_fold_ties_across_threads_and_chunks(kind, monkeypatch):
    # own slot tables split each chunk's points between threads and are folded at the
    # end: copies of a point in another thread's share, in a later chunk, or read out
    # midway (a fold, then more points) must still leave the lowest index
    rng = np.random.default_rng(21)
    pts = rng.normal(size=(60000, 3)) * 10
    pts[40000:40500] = pts[:500]  # the last thread's share of the first chunk
    pts[45000:45500] = pts[20000:20500]  # the first thread's share of a later chunk: its copy folds in
    pts[55000:55500] = pts[100:600]  # a later chunk
    pts[59990:] = pts[20000:20010]
    pattern = ScanPattern(0.5)
    expected = brute_force_scan(pts, np.zeros(3), pattern)
    t = _tables(kind, np.zeros(3), pattern, 3, monkeypatch)
    for s in range(0, len(pts), 15000):  # never read out midway
        t.add(pts[s:s + 15000])
    np.testing.assert_array_equal(t.winners()[2], expected)
    t = _tables(kind, np.zeros(3), pattern, 3, monkeypatch)
    assert t._private == (kind == "slots")
    t.add(pts[:45000])
    np.testing.assert_array_equal(t.winners()[2], brute_force_scan(pts[:45000], np.zeros(3), pattern))
    assert t.n_bins == len(t.winners()[2])  # a second read-out folds nothing twice
    t.add(pts[45000:52000])
    t.add(pts[52000:])
    keys, ranges, idx = t.winners()
    np.testing.assert_array_equal(idx, expected)
    k, r = pulse_ids(pts, np.zeros(3), pattern)
    np.testing.assert_array_equal(keys, k[expected])
    np.testing.assert_array_equal(ranges, r[expected])
    pulses, _, idx2 = t.winners(as_pulses=True)
    np.testing.assert_array_equal(idx2, expected)
    np.testing.assert_array_equal(pulses, pattern.unravel(k[expected]))
    t.reset(np.ones(3))  # cleared at the occupied bins only: a fresh table's answer
    t.add(pts)
    np.testing.assert_array_equal(t.winners()[2], brute_force_scan(pts, np.ones(3), pattern))


def test_folding_own_slot_tables_keeps_the_lowest_index_on_ties():
    # the fold meets a later point in the first table and its exact copy, earlier in
    # the input, in another (threads take chunks as they come free): the lower index wins
    from slr_ray.core.slots import SlotTable

    rng = np.random.default_rng(22)
    pts = rng.normal(size=(20000, 3)) * 10
    pts = np.vstack([pts, pts])  # every point again, 20000 later
    pattern = ScanPattern(0.5)
    params = kernel_params(np.zeros(3), pattern)
    band = (np.int64(0), np.int64(pattern.n_pulses))
    late = SlotTable(np.zeros(pattern.n_pulses, np.int32))
    late.reduce(pts, params, band, 0, 20000, 40000)
    early = SlotTable(np.zeros(pattern.n_pulses, np.int32))
    early.reduce(pts, params, band, 0, 0, 20000)
    late.absorb(early)
    assert sorted(late.tab["idx"].tolist()) == brute_force_scan(pts[:20000], np.zeros(3), pattern).tolist()


@pytest.mark.parametrize("kind", ["slots", "shared-slots"])
@pytest.mark.parametrize("expected_bins", [0, 1, 5000, 10**6])
def test_slot_tables_sized_from_an_expected_count_give_the_same_scan(kind, expected_bins, monkeypatch):
    # a prepared scanner sizes its second scan's tables from its first scan's bins: any
    # hint (none, too small: the tables grow, too large: room left over) is the same answer
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(40000, 3)) * 10
    pts[30000:31000] = pts[:1000]  # ties across the threads' shares
    pattern = ScanPattern(0.5)
    monkeypatch.setattr(BinTables, "dense_bytes", 0)
    monkeypatch.setattr(BinTables, "slot_bytes", 2**62)
    monkeypatch.setattr(BinTables, "own_slots", kind == "slots")
    t = BinTables(np.zeros(3), pattern, 3, expected_bins=expected_bins)
    first = len(t.tables[0].rec)
    assert first >= max(tables.INITIAL_CAPACITY, expected_bins if kind == "slots" else expected_bins // 3)
    t.add(pts)
    np.testing.assert_array_equal(t.winners()[2], brute_force_scan(pts, np.zeros(3), pattern))
    t.reset(np.ones(3))
    t.add(pts)
    np.testing.assert_array_equal(t.winners()[2], brute_force_scan(pts, np.ones(3), pattern))


def test_a_prepared_scanner_sizes_its_own_tables_from_its_first_scan(monkeypatch):
    from slr_ray import prepare

    monkeypatch.setattr(BinTables, "dense_bytes", 0)  # slot tables
    pts = np.random.default_rng(6).normal(size=(50000, 3)) * 10
    pattern = ScanPattern(0.2)
    scanner = prepare(pts, n_threads=2)
    a = scanner.scan(np.zeros(3), pattern)  # one shared slot array
    assert scanner._cache.kind == "slots" and not scanner._cache._private
    b = scanner.scan(np.zeros(3), pattern)  # tables of its own per thread, sized from a
    tabs = scanner._cache
    assert tabs._private and len(tabs.tables[0].rec) >= len(a) > tables.INITIAL_CAPACITY
    np.testing.assert_array_equal(a.indices, b.indices)


@pytest.mark.parametrize("parts", [1, 2, 3, 7])
def test_a_fold_split_over_threads_equals_the_serial_fold(parts):
    # absorb_parallel: records the table has compared in place, new ones appended at
    # offsets from the first pass; the same records, in the same order, as absorb
    from concurrent.futures import ThreadPoolExecutor

    from slr_ray.core.slots import SlotTable

    rng = np.random.default_rng(parts)
    n_pulses = 5000

    def table(keys, ranges, idx, capacity=16):
        t = SlotTable(np.zeros(n_pulses, np.int32), capacity)
        best = {}
        for k, r, i in zip(keys, ranges, idx):
            if k not in best or (r, i) < best[k]:
                best[k] = (r, i)
        for k, (r, i) in best.items():
            while t.count >= len(t.rec):
                t._grow()
            t.rec[t.count] = (k, r, i)
            t.slots[k] = t.count + 1
            t.count += 1
        return t

    def pair():
        n = 3000
        k1 = rng.integers(0, n_pulses, n)
        k2 = rng.integers(0, n_pulses, n)
        r1 = rng.integers(0, 5, n).astype(float)  # many equal ranges: ties on the index
        r2 = rng.integers(0, 5, n).astype(float)
        return table(k1, r1, np.arange(n)), table(k2, r2, np.arange(n, 2 * n) - rng.integers(0, 2 * n, n) % 7)

    a, b = pair()
    a2 = SlotTable(a.slots.copy(), len(a.rec))
    a2.rec[:a.count] = a.rec[:a.count]
    a2.count = a.count
    a.absorb(b)
    with ThreadPoolExecutor(parts) as pool:
        a2.absorb_parallel(b, pool, parts)
    assert a2.count == a.count
    np.testing.assert_array_equal(a2.rec[:a2.count], a.rec[:a.count])
    np.testing.assert_array_equal(a2.slots, a.slots)


@pytest.mark.parametrize("n_threads", [2, 3])
@pytest.mark.parametrize("release", [False, True])
def test_own_slot_tables_resolved_in_parallel_give_the_exact_scan(monkeypatch, n_threads, release):
    # enough bins in each thread's table (> 65,536) that the losers of bins held by several
    # tables are found in parallel shares (three tables: pairs side by side); release=True folds
    rng = np.random.default_rng(8)
    pts = rng.normal(size=(400_000, 3)) * 10
    pts[300_000:340_000] = pts[:40_000]  # copies in another thread's share: ties on the index
    pts[200_000:210_000] = pts[350_000:360_000] * 1.0000001  # near copies, the later one nearer
    pattern = ScanPattern(0.1)
    monkeypatch.setattr(BinTables, "parallel_records", 1000)  # however the threads shared the chunks
    t = _tables("slots", np.zeros(3), pattern, n_threads, monkeypatch)
    t.add(pts)
    want = brute_force_scan(pts, np.zeros(3), pattern)
    assert t.n_bins == len(want)
    np.testing.assert_array_equal(t.winners(pts, release=release)[2], want)
    if release:
        return
    t.add(pts[:1000] * 0.5)  # more points after a read-out: each table's records changed, read again
    np.testing.assert_array_equal(t.winners()[2], brute_force_scan(np.concatenate([pts, pts[:1000] * 0.5]),
                                                                   np.zeros(3), pattern))
    t.reset(np.full(3, 0.5))
    t.add(pts)
    np.testing.assert_array_equal(t.winners()[2], brute_force_scan(pts, np.full(3, 0.5), pattern))


@pytest.mark.parametrize("first", [64 * 3000, 64 * 3000 + 37])
def test_own_slot_tables_marked_side_by_side_only_on_whole_words(monkeypatch, first):
    # chunks of whole 64-point words let the tables mark the read-out's bitmap side by side;
    # an add that starts inside a word (the second, after 192,037 points) turns that off
    rng = np.random.default_rng(9)
    pts = rng.normal(size=(300_000, 3)) * 10
    pts[250_000:260_000] = pts[:10_000]
    pattern = ScanPattern(0.1)
    monkeypatch.setattr(BinTables, "parallel_records", 1000)
    t = _tables("slots", np.zeros(3), pattern, 2, monkeypatch)
    t.add(pts[:first])
    assert t._word_aligned
    np.testing.assert_array_equal(t.winners()[2], brute_force_scan(pts[:first], np.zeros(3), pattern))
    t.add(pts[first:])
    assert t._word_aligned == (first % 64 == 0)
    np.testing.assert_array_equal(t.winners()[2], brute_force_scan(pts, np.zeros(3), pattern))
    t.reset(np.zeros(3))
    assert t._word_aligned


def _definition_winners(points, origin, pattern):
    """The nearest-in-pulse rule straight from its definition, with libm and
    Python loops only (no slr_ray kernel): ``(keys, ranges, indices)`` in index order."""
    import math

    d_theta, d_phi, th0, th1 = pattern.radians
    rmin, rmax = pattern.range_limits
    nv, nh = pattern.shape
    best = {}
    for i, (x, y, z) in enumerate(np.asarray(points, np.float64).tolist()):
        dx, dy, dz = x - origin[0], y - origin[1], z - origin[2]
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        if r == 0.0 or r < rmin or r > rmax:
            continue
        theta = math.atan2(math.hypot(dx, dy), dz)
        if theta < th0 or theta > th1:
            continue
        phi = math.atan2(dy, dx)
        phi = phi + 2 * math.pi if phi < 0 else phi
        key = min(int(math.floor((theta - th0) / d_theta)), nv - 1) * nh + min(int(math.floor(phi / d_phi)), nh - 1)
        if key not in best or (r, i) < best[key]:
            best[key] = (r, i)
    won = sorted((i, k, r) for k, (r, i) in best.items())
    return (np.array([k for _, k, _ in won], np.int64), np.array([r for _, _, r in won], np.float64),
            np.array([i for i, _, _ in won], np.int64))


# offsets from the scanner, multiples of 1/1024 m (exact after a shift by 1e6 m): the poles
# (dx = dy = 0), the azimuth wrap (dy = 0, +-1/1024 with dx > 0), the axes, and any grid point
_SPECIAL = [(0.0, 0.0, 5.0), (0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (7.0, 0.0, 1.0), (7.0, 2 ** -10, 1.0),
            (7.0, -(2 ** -10), 1.0), (-7.0, 0.0, 1.0), (0.0, 7.0, 0.0), (0.0, -7.0, -3.0), (3.0, 4.0, 0.0),
            (-4.0, 3.0, 0.0), (4.0, -3.0, 0.0)]
_OFFSET = st.one_of(st.sampled_from(_SPECIAL),
                    st.tuples(*[st.integers(-20 * 1024, 20 * 1024).map(lambda v: v / 1024)] * 3))


@settings(max_examples=30, deadline=None)
@given(offsets=st.lists(_OFFSET, max_size=40), repeat=st.lists(st.integers(0, 39), max_size=10),
       res=st.sampled_from([3.0, 20.0, 45.0]), shift=st.sampled_from([0.0, 1e6]),
       limits=st.sampled_from([{}, {"zenith_range": (10.0, 150.0), "min_range": 2.0, "max_range": 15.0}]),
       n_threads=st.sampled_from([1, 2]))
def test_every_table_kind_keeps_the_nearest_point_of_each_pulse_as_defined(offsets, repeat, res, shift, limits,
                                                                            n_threads):
    # ties (repeated rows, equal ranges in one pulse), the poles, the azimuth wrap and the
    # view and range limits, 1e6 m from the coordinates' origin, in chunks, every table
    # kind, the dense read-out as keys and as pulses into pooled arrays: the same
    # (keys, ranges, indices) as the definition computed with libm by plain loops
    from slr_ray.core.order import OutputPool

    origin = np.array([shift + 1.5, shift - 2.25, 0.75])
    pts = origin + np.array(offsets + [offsets[j] for j in repeat if j < len(offsets)], np.float64).reshape(-1, 3)
    pattern = ScanPattern(res, **limits)
    want = _definition_winners(pts, origin, pattern)
    mp = pytest.MonkeyPatch()
    try:
        for kind in ("dense", "slots", "shared-slots", "hash"):
            t = _tables(kind, origin, pattern, n_threads, mp)
            for _ in range(2):  # the second time on reset tables
                half = len(pts) // 2
                t.add(pts[:half])
                t.add(pts[half:])
                for a, b in zip(t.winners(), want):
                    np.testing.assert_array_equal(a, b)
                pulses, ranges, idx = t.winners(as_pulses=True, pool=OutputPool())
                np.testing.assert_array_equal(pulses[:, 0] * pattern.shape[1] + pulses[:, 1], want[0])
                np.testing.assert_array_equal(idx, want[2])
                t.reset(origin)
    finally:
        mp.undo()
