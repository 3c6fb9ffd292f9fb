import numpy as np
import pytest

from slr_ray import FormatError
from slr_ray.io import PointCloud, read_cloud, write_cloud


def _cloud(n=500, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * 10 + [5e5, 4e6, 30]
    attrs = {"intensity": rng.integers(0, 65535, n).astype(np.uint16),
             "label": rng.integers(0, 9, n).astype(np.int32),
             "red": rng.integers(0, 255, n).astype(np.uint8),
             "gps_time": rng.random(n)}
    return PointCloud(pts, attrs, np.array([5e5, 4e6, 31.0]))


@pytest.mark.parametrize("ext", [".ply", ".npz"])
def test_round_trip_keeps_points_and_every_attribute(tmp_path, ext):
    c = _cloud()
    write_cloud(tmp_path / f"c{ext}", c)
    back = read_cloud(tmp_path / f"c{ext}")
    np.testing.assert_array_equal(back.points, c.points)  # float64 kept exactly
    assert set(back.attributes) == set(c.attributes)
    for k, v in c.attributes.items():
        np.testing.assert_array_equal(back.attributes[k], v)
        assert back.attributes[k].dtype == v.dtype
    if ext == ".npz":
        np.testing.assert_array_equal(back.origin, c.origin)


def test_ascii_ply(tmp_path):
    c = _cloud(20)
    write_cloud(tmp_path / "a.ply", c, binary=False)
    assert b"format ascii" in (tmp_path / "a.ply").read_bytes()[:100]
    np.testing.assert_allclose(read_cloud(tmp_path / "a.ply").points, c.points, rtol=1e-12)


def test_npy_columns(tmp_path):
    a = np.arange(20.0).reshape(5, 4)
    np.save(tmp_path / "a.npy", a)
    c = read_cloud(tmp_path / "a.npy")
    np.testing.assert_array_equal(c.points, a[:, :3])
    np.testing.assert_array_equal(c.attributes["column_3"], a[:, 3])


def test_subset_follows_indices():
    c = _cloud(50)
    s = c.subset(np.array([3, 7]))
    np.testing.assert_array_equal(s.attributes["label"], c.attributes["label"][[3, 7]])


def test_unknown_extension_and_missing_file(tmp_path):
    with pytest.raises(FormatError, match="unknown point-cloud format"):
        read_cloud(tmp_path / "x.xyzw")
    with pytest.raises(FileNotFoundError):
        read_cloud(tmp_path / "missing.ply")


@pytest.mark.parametrize("ext", [".ply", ".npz", ".npy"])
def test_corrupt_files_raise_format_error(tmp_path, ext):
    c = _cloud()
    path = tmp_path / f"c{ext}"
    write_cloud(path, c)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])
    with pytest.raises(FormatError, match="cannot read"):
        read_cloud(path)


def test_failed_write_leaves_nothing(tmp_path):
    c = _cloud(10)
    c.attributes["bad"] = np.array(["a"] * 10)
    with pytest.raises(FormatError):
        write_cloud(tmp_path / "out.ply", c)
    assert list(tmp_path.iterdir()) == []
