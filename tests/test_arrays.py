import numpy as np
import pytest

from slr_ray import InputTypeError, InputValueError
from slr_ray.arrays import as_origin, as_points


def test_float32_kept_and_ints_widened():
    assert as_points(np.zeros((2, 3), np.float32)).dtype == np.float32
    assert as_points(np.zeros((2, 3), np.int16)).dtype == np.float64


def test_no_copy_for_contiguous_float64():
    a = np.zeros((4, 3))
    assert as_points(a) is a


@pytest.mark.parametrize("bad", [np.zeros((3,)), np.zeros((2, 2)), np.zeros((1, 3, 1)), [[1, 2], [3]]])
def test_bad_shapes(bad):
    with pytest.raises(InputValueError, match="points"):
        as_points(bad)


@pytest.mark.parametrize("bad", [np.zeros((2, 3), complex), np.array([[1, 2, "a"]], object),
                                 np.zeros((2, 3), bool)])
def test_bad_dtypes(bad):
    with pytest.raises(InputTypeError, match="points"):
        as_points(bad)


def test_nonfinite_rows_are_counted():
    a = np.zeros((5, 3))
    a[1, 0] = np.nan
    a[3] = np.inf
    with pytest.raises(InputValueError, match="2 row"):
        as_points(a)


@pytest.mark.parametrize("bad", [[0, 0], [[0, 0, 0]], [0, 0, np.nan], "abc"])
def test_bad_origins(bad):
    with pytest.raises((InputValueError, InputTypeError), match="origin"):
        as_origin(bad)


@pytest.mark.parametrize("n", [0, 1, 2, 7, 65536 * 3 + 5, (1 << 20) + 3])  # the last: the parallel pass
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_bounds_equal_numpy(n, dtype):
    from slr_ray.arrays import bounds

    rng = np.random.default_rng(n)
    a = (rng.normal(size=(n, 4)) * 1e3 + 4e6).astype(dtype)  # 4 columns: only the first 3 count
    lo, hi = bounds(a)
    assert lo.dtype == hi.dtype == np.float64
    if n == 0:
        assert np.all(lo == np.inf) and np.all(hi == -np.inf)
    else:
        np.testing.assert_array_equal(lo, a[:, :3].min(axis=0))
        np.testing.assert_array_equal(hi, a[:, :3].max(axis=0))
    # a strided view (every other row) and a monotone column (elif branch never taken)
    if n > 2:
        np.testing.assert_array_equal(bounds(a[::2])[0], a[::2, :3].min(axis=0))
        m = np.column_stack([np.arange(n), -np.arange(n), np.zeros(n)]).astype(dtype)
        np.testing.assert_array_equal(bounds(m)[1], [n - 1, 0, 0])


def _mapped(tmp_path, a, mode="r"):
    path = tmp_path / "a.npy"
    np.save(path, a)
    return np.load(path, mmap_mode=mode)


def test_release_pages_of_a_mapped_array_keeps_its_data(tmp_path):
    from slr_ray.arrays import file_mapping, release_pages

    a = np.random.default_rng(0).normal(size=(50_000, 3))
    m = _mapped(tmp_path, a)
    view = as_points(m)  # what prepare holds: a view, still of the file
    assert file_mapping(view) is not None
    assert release_pages(view) >= a.nbytes
    np.testing.assert_array_equal(view, a)  # read back from the file cache
    assert 0 < release_pages(view[100:200:3]) < a.nbytes
    np.testing.assert_array_equal(m, a)


def test_release_pages_leaves_memory_and_copy_on_write_maps_alone(tmp_path):
    from slr_ray.arrays import file_mapping, release_pages

    a = np.ones((1000, 3))
    assert file_mapping(a) is None and release_pages(a) == 0
    assert release_pages(np.empty((0, 3))) == 0
    c = _mapped(tmp_path, a, "c")
    c[0] = 5.0  # a changed page of a private mapping exists nowhere else: never released
    assert file_mapping(c) is None and release_pages(c) == 0
    assert c[0, 0] == 5.0
