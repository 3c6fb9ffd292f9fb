import numpy as np
import pytest

from slr_ray.similarity import nearest_distances, similarity


def test_agrees_with_open3d():
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3000, 3)) * 5 + [4e5, 5e6, 20]
    b = a[::2] + rng.normal(scale=0.08, size=(1500, 3))
    pa, pb = o3d.geometry.PointCloud(), o3d.geometry.PointCloud()
    # Open3D works in float64 too, but recentre for a fair comparison at UTM coordinates
    pa.points = o3d.utility.Vector3dVector(a - a.mean(axis=0))
    pb.points = o3d.utility.Vector3dVector(b - a.mean(axis=0))
    d_o3d = np.asarray(pa.compute_point_cloud_distance(pb))
    np.testing.assert_allclose(nearest_distances(a, b), d_o3d, atol=1e-9)
    assert similarity(a, b, 0.1) == pytest.approx(np.mean(d_o3d < 0.1))


def test_known_values_and_empty_inputs():
    a = np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0]])
    b = np.array([[0.05, 0, 0], [1.2, 0, 0]])
    assert similarity(a, b, 0.1) == pytest.approx(1 / 3)
    assert similarity(a, b, 0.25) == pytest.approx(2 / 3)
    assert np.isnan(similarity(np.empty((0, 3)), b))
    assert similarity(a, np.empty((0, 3))) == 0.0
    assert np.all(np.isinf(nearest_distances(a, np.empty((0, 3)))))
    with pytest.raises(ValueError):
        similarity(a, b, 0)


def test_bounded_search_equals_unbounded():
    """similarity bounds the neighbour search at the threshold: the same count as
    an unbounded search, including points at exactly the threshold."""
    rng = np.random.default_rng(1)
    a = rng.uniform(-3, 3, size=(4000, 3))
    b = a[::3] + rng.normal(scale=0.1, size=(1334, 3))
    full = nearest_distances(a, b)
    for t in (0.02, 0.1, 0.3, 10.0):
        bounded = nearest_distances(a, b, upper_bound=t)
        near = full < t
        np.testing.assert_array_equal(bounded[near], full[near])
        assert np.all(np.isinf(bounded[full > t]))
        assert similarity(a, b, t) == np.count_nonzero(near) / len(a)
    # a point exactly at the threshold is not within it, bounded or not
    x = np.array([[0.0, 0.0, 0.0]])
    assert similarity(x, np.array([[0.5, 0.0, 0.0]]), 0.5) == 0.0
    assert similarity(x, np.array([[0.5, 0.0, 0.0]]), np.nextafter(0.5, 1)) == 1.0
