import numpy as np
import pytest

from slr_ray import InputValueError, ScanAccumulator, ScanPattern, simulate_scan

from conftest import scene_cloud


@pytest.mark.parametrize("n_chunks", [1, 2, 7, 50])
def test_chunks_reduce_to_the_one_shot_answer(n_chunks, table_kind):
    pts = scene_cloud(30000, 7)
    pattern = ScanPattern(0.7, max_range=40)
    ref = simulate_scan(pts, [1, 0, 0.5], pattern)
    acc = ScanAccumulator([1, 0, 0.5], pattern, n_threads=2)
    for chunk in np.array_split(pts, n_chunks):
        acc.add(chunk)
    got = acc.result()
    np.testing.assert_array_equal(got.indices, ref.indices)
    np.testing.assert_array_equal(got.ranges, ref.ranges)
    np.testing.assert_array_equal(got.pulses, ref.pulses)
    assert acc.n_points == len(pts) and acc.n_bins == len(ref)


def test_duplicates_across_chunks_keep_the_first(table_kind):
    acc = ScanAccumulator([0, 0, 0], 1.0)
    acc.add(np.array([[5.0, 1, 1]]))
    acc.add(np.array([[5.0, 1, 1], [1.0, 1, 1]]))
    acc.add(np.array([[5.0, 1, 1]]))
    assert acc.result().indices.tolist() == [0, 2]


def test_memory_grows_with_bins_not_points():
    # 200 000 points in a handful of pulses: the state stays tiny (hash tables)
    rng = np.random.default_rng(0)
    acc = ScanAccumulator([0, 0, 0], 0.01)
    for _ in range(20):
        acc.add(rng.normal([10, 0, 0], 1e-4, size=(10000, 3)))
    assert acc.n_bins < 100
    assert acc.nbytes < 2**20


def test_bad_chunk_leaves_state_unchanged():
    acc = ScanAccumulator([0, 0, 0], 1.0)
    acc.add(np.array([[1.0, 0, 0]]))
    bad = np.array([[2.0, 0, 0], [np.nan, 0, 0]])
    with pytest.raises(InputValueError, match="1 row"):
        acc.add(bad)
    acc.add(np.array([[0.5, 0, 0]]))
    assert acc.result().indices.tolist() == [1] and acc.n_points == 2


def test_result_can_be_taken_midway():
    pts = scene_cloud(5000, 8)
    acc = ScanAccumulator([0, 0, 0], 2.0)
    acc.add(pts[:2500])
    half = acc.result()
    np.testing.assert_array_equal(half.indices, simulate_scan(pts[:2500], [0, 0, 0], 2.0).indices)
    acc.add(pts[2500:])
    np.testing.assert_array_equal(acc.result().indices, simulate_scan(pts, [0, 0, 0], 2.0).indices)
