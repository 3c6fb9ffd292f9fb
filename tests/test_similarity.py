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


# --- agreement: coverage, precision, F-score ---------------------------------------------------------------

from hypothesis import given, settings, strategies as st  # noqa: E402

from slr_ray.similarity import agreement  # noqa: E402


def _brute(a, b, t):
    """Share of rows of a with a row of b strictly closer than t (all pairs)."""
    if len(a) == 0:
        return float("nan")
    if len(b) == 0:
        return 0.0
    d = np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)).min(axis=1)
    return float(np.mean(d < t))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 40), st.integers(0, 40), st.integers(0, 2**31 - 1), st.floats(0.05, 0.8))
def test_agreement_against_brute_force(n, m, seed, threshold):
    rng = np.random.default_rng(seed)
    a = rng.uniform(-1, 1, (n, 3)) + [3e5, -4e6, 100]  # UTM-like offsets: recentred inside
    b = (a[rng.integers(0, n, m)] if n else rng.uniform(-1, 1, (m, 3)) + [3e5, -4e6, 100]) \
        + rng.normal(scale=0.2, size=(m, 3))
    got = agreement(a, b, threshold)
    cov, prec = _brute(a, b, threshold), _brute(b, a, threshold)
    np.testing.assert_equal([got.coverage, got.precision], [cov, prec])
    assert got.coverage == similarity(a, b, threshold) or (np.isnan(got.coverage) and n == 0)
    if np.isnan(cov) or np.isnan(prec):
        assert np.isnan(got.fscore)
    else:
        assert got.fscore == pytest.approx(0 if cov + prec == 0 else 2 * cov * prec / (cov + prec))
    assert (got.true_points, got.simulated_points) == (n, m)


def test_agreement_of_identical_clouds_and_exact_threshold():
    a = np.random.default_rng(1).uniform(size=(100, 3))
    assert agreement(a, a).to_dict() | {"threshold": 0} == {
        "coverage": 1.0, "precision": 1.0, "fscore": 1.0, "threshold": 0, "true_points": 100,
        "simulated_points": 100}
    # exactly at the threshold is not within it, both ways (powers of two: no rounding)
    t, s = np.array([[0.0, 0, 0]]), np.array([[0.125, 0, 0]])
    assert agreement(t, s, 0.125).coverage == 0.0 and agreement(t, s, 0.125).precision == 0.0
    assert agreement(t, s, 0.1250001).fscore == 1.0
    with pytest.raises(ValueError):
        agreement(t, s, 0.0)
    with pytest.raises(ValueError):
        agreement(t, s, float("nan"))


def test_see_through_points_lower_precision_not_coverage():
    """A wall seen by a scanner, plus points of a wall 5 m behind it (which the
    scanner cannot see): coverage, the paper's measure, does not notice them;
    precision falls by their share."""
    g = np.linspace(0, 4, 41)
    yy, zz = np.meshgrid(g, g)
    front = np.column_stack([np.full(yy.size, 10.0), yy.ravel(), zz.ravel()])
    behind = front + [5.0, 0, 0]
    truth = front
    slr = front[::2]
    clean = agreement(truth, slr)
    dirty = agreement(truth, np.vstack([slr, behind[::4]]))
    assert dirty.coverage == clean.coverage
    assert clean.precision == 1.0
    assert dirty.precision == pytest.approx(len(slr) / (len(slr) + len(behind[::4])))
    assert dirty.fscore < clean.fscore


def test_n_threads_names_the_parallelism_and_workers_is_a_deprecated_alias():
    rng = np.random.default_rng(4)
    a, b = rng.normal(size=(300, 3)), rng.normal(size=(200, 3))
    ref = agreement(a, b, 0.3)
    assert agreement(a, b, 0.3, n_threads=1) == ref
    with pytest.warns(DeprecationWarning, match="n_threads"):
        assert agreement(a, b, 0.3, workers=1) == ref
    with pytest.warns(DeprecationWarning, match="n_threads"):
        np.testing.assert_array_equal(nearest_distances(a, b, workers=2), nearest_distances(a, b, n_threads=2))
    assert similarity(a, b, 0.3, n_threads=2) == ref.coverage
