import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slr_ray.cellgrid import CellGrid, GridUnsuitable
from slr_ray.errors import InputValueError


def _brute(q, r, radius):
    if len(r) == 0:
        return np.zeros(len(q), bool)
    d = np.sqrt(((q[:, None, :] - r[None, :, :]) ** 2).sum(-1))
    return (d < radius).any(axis=1)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 60), st.integers(0, 60), st.integers(0, 2**31 - 1), st.floats(0.01, 2.0),
       st.sampled_from([0.0, 1e3, -4e6, 5.2e6, 1e12]))
def test_any_within_equals_brute_force(n, m, seed, radius, offset):
    rng = np.random.default_rng(seed)
    r = rng.uniform(-1, 1, (n, 3)) * rng.choice([0.1, 1, 10]) + offset
    # queries near reference points (matches and near misses) and anywhere
    near = r[rng.integers(0, n, m)] + rng.normal(scale=radius, size=(m, 3)) if n else np.empty((0, 3))
    q = np.vstack([near, rng.uniform(-3, 3, (m, 3)) + offset])
    got = CellGrid(r, radius).any_within(q)
    np.testing.assert_array_equal(got, _brute(q, r, radius))


def test_points_exactly_at_the_radius_do_not_count_and_cells_do_not_lose_neighbours():
    # powers of two: distances exact; pairs straddling cell borders in every axis
    r = np.array([[0.0, 0, 0]])
    g = CellGrid(r, 0.125)
    q = np.array([[0.125, 0, 0], [0, -0.125, 0], [0.0, 0, 0.124999], [-0.0883, -0.0883, 0]])
    np.testing.assert_array_equal(g.any_within(q), [False, False, True, True])
    rng = np.random.default_rng(0)
    grid_pts = np.round(rng.uniform(-5, 5, (2000, 3)) / 0.125) * 0.125  # on cell-size lattice
    shifted = grid_pts + rng.choice([-1, 1], (2000, 3)) * rng.uniform(0, 0.07, (2000, 3))
    np.testing.assert_array_equal(CellGrid(grid_pts, 0.125).any_within(shifted),
                                  _brute(shifted, grid_pts, 0.125))


def test_smaller_radius_empty_clouds_and_non_finite_queries():
    r = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    g = CellGrid(r, 0.5)
    q = np.array([[0.3, 0, 0], [5.0, 0, 0], [0.9, 0.1, 0]])
    np.testing.assert_array_equal(g.any_within(q), [True, False, True])
    np.testing.assert_array_equal(g.any_within(q, 0.2), [False, False, True])
    with pytest.raises(InputValueError, match="NaN"):
        g.any_within(np.array([[np.nan, 0, 0]]))
    with pytest.raises(ValueError):
        g.any_within(q, 0.6)  # larger than the cells
    assert CellGrid(np.empty((0, 3)), 0.1).any_within(q).tolist() == [False] * 3
    assert g.any_within(np.empty((0, 3))).shape == (0,)
    with pytest.raises(ValueError):
        CellGrid(r, 0.0)


def test_clouds_the_grid_cannot_hold_are_refused():
    with pytest.raises(GridUnsuitable, match="spans"):
        CellGrid(np.array([[0.0, 0, 0], [1e6, 0, 0]]), 0.1)


def test_a_radius_too_small_for_int64_cell_counts_is_refused_not_wrapped():
    """20 m of cloud at a 1e-30 m radius is 2e31 cells: more than int64 holds. The count once
    wrapped to a negative number, passed the size check, and every query found nothing."""
    r = np.random.default_rng(0).uniform(-10, 10, (50, 3))
    for radius in (1e-30, 1e-300):
        with pytest.raises(GridUnsuitable, match="spans"):
            CellGrid(r, radius)


def test_far_coordinates_and_tiny_radii_are_gridded_exactly():
    # the case a CI run once found refused: UTM-size coordinates, 3 cm cells
    rng = np.random.default_rng(1)
    for offset, radius in [(-4e6, 0.03125), (5.3e6, 1e-3), (1e12, 0.05)]:
        r = rng.uniform(-1, 1, (300, 3)) * 20 * radius + offset
        q = np.vstack([r + rng.normal(scale=radius, size=r.shape), rng.uniform(-1, 1, (300, 3)) + offset])
        np.testing.assert_array_equal(CellGrid(r, radius).any_within(q), _brute(q, r, radius))


def test_agreement_falls_back_to_a_kdtree_where_the_grid_cannot_hold_the_cloud():
    from slr_ray.similarity import agreement

    t = np.array([[0.0, 0, 0], [5e5, 0, 0]])
    s = np.array([[0.05, 0, 0], [5e5, 0.5, 0], [3e5, 0, 0]])
    a = agreement(t, s, 0.1)  # 5e6 cells along x: kd-tree
    assert (a.coverage, a.precision) == (0.5, 1 / 3)
