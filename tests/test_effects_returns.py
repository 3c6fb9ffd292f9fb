"""Beam divergence and multiple returns (slr_ray.effects.returns) against geometry."""

import math

import laspy
import numpy as np
import pytest

from slr_ray import InputValueError, ScanPattern, prepare
from slr_ray.effects import Effects, simulate
from slr_ray.effects.returns import footprint_samples, group_returns, select_returns, subray_directions
from slr_ray.io import write_cloud

DIV_MRAD = 50.0  # full angle: a 0.25 m footprint radius at 10 m
Y_EDGE = 10 * math.tan(math.radians(1.5)) + 0.1  # the near wall's edge, 0.1 m beside pulse (0, 0)'s axis


def _grid(x, y0, y1, z0, z1, step):
    y, z = np.meshgrid(np.arange(y0, y1, step), np.arange(z0, z1, step), indexing="ij")
    return np.column_stack([np.full(y.size, x), y.ravel(), z.ravel()])


def step_edge():
    """A near wall (x = 10, y >= Y_EDGE) in front of a far wall (x = 20), as discs
    that tile each wall (radius > spacing / sqrt 2), the near wall's discs ending at its edge."""
    r_near, s_near = 0.004, 0.005
    near = _grid(10.0, Y_EDGE + r_near, 0.65, -0.35, 0.35, s_near)
    far = _grid(20.0, -0.2, 1.25, -0.7, 0.7, 0.01)
    pts = np.vstack([near, far])
    radii = np.r_[np.full(len(near), r_near), np.full(len(far), 0.008)]
    normals = np.tile([-1.0, 0.0, 0.0], (len(pts), 1))
    return pts, radii, normals, len(near)


def near_share_analytic():
    """Share of a uniform cone beyond a chord: the circular segment of the edge's angular distance."""
    d = np.array([math.cos(math.radians(1.5)), math.sin(math.radians(1.5)), 0.0])
    n = np.array([-Y_EDGE, 10.0, 0.0]) / math.hypot(Y_EDGE, 10.0)  # the plane through the origin and the edge
    c = math.asin(abs(n @ d)) / (0.5 * DIV_MRAD * 1e-3)
    return (math.acos(c) - c * math.sqrt(1 - c * c)) / math.pi


def test_footprint_weights_are_cell_areas():
    off, w = footprint_samples(0.01, 4)
    assert len(w) == 1 + 6 + 12 + 18 and w.sum() == pytest.approx(1.0)
    assert off[:, 0].max() < 0.005  # the outer ring's cells end at the half-angle
    # a half-plane through the axis takes half the footprint, whatever its direction
    for a in (0.0, 0.3, 1.0):
        side = np.cos(off[:, 1] - a) * off[:, 0]
        assert w[side > 1e-12].sum() + 0.5 * w[np.abs(side) <= 1e-12].sum() == pytest.approx(0.5, abs=1e-9)


def test_subrays_lie_on_their_cone():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    off, _ = footprint_samples(0.02, 3)
    sub = subray_directions(d, off).reshape(50, len(off), 3)
    assert np.allclose(np.linalg.norm(sub, axis=2), 1.0)
    ang = np.arccos(np.clip(np.einsum("pj,psj->ps", d, sub), -1, 1))
    assert np.allclose(ang, off[None, :, 0], atol=1e-7)


def test_step_edge_gives_two_returns_with_the_predicted_split():
    pts, radii, normals, n_near = step_edge()
    sc = prepare(pts, "embree", radius=radii, normals=normals)
    pattern = ScanPattern(3.0, zenith_range=(88.5, 91.5))
    eff = Effects(divergence_mrad=DIV_MRAD, beam_rings=16, returns=("all",), min_share=0.0)
    es = simulate(sc, [0, 0, 0], pattern, eff)
    mine = (es.pulses[:, 0] == 0) & (es.pulses[:, 1] == 0)
    assert mine.sum() == 2
    first, last = np.flatnonzero(mine)
    assert es.return_number[[first, last]].tolist() == [1, 2]
    assert es.number_of_returns[[first, last]].tolist() == [2, 2]
    assert es.indices[first] < n_near <= es.indices[last]  # near wall, then far wall
    assert 10.0 < es.ranges[first] < 10.05 and 20.0 < es.ranges[last] < 20.1
    # the split the geometry predicts: the circular segment beyond the edge's chord
    expected = near_share_analytic()
    assert es.share[first] == pytest.approx(expected, abs=0.02)
    assert es.share[first] + es.share[last] == pytest.approx(1.0, abs=1e-9)
    # brute force: the same sub-rays intersected with the two walls analytically
    off, w = footprint_samples(DIV_MRAD * 1e-3, 16)
    d = np.array([[math.cos(math.radians(1.5)), math.sin(math.radians(1.5)), 0.0]])
    sub = subray_directions(d, off)
    y_at_near = 10.0 * sub[:, 1] / sub[:, 0]
    assert es.share[first] == pytest.approx(w[y_at_near >= Y_EDGE].sum(), abs=0.005)


def test_strongest_first_last_and_thresholds():
    # two pulses: one with returns of shares 0.2, 0.5, 0.3 (ranges 1, 5, 9), one with one return
    idx = np.array([[0, 1, 2, 1, 1, 2, 2, -1, 2, 2], [3] * 10])
    t = np.array([[1.0, 5.0, 9.0, 5.1, 5.2, 9.1, 9.2, np.inf, 9.3, 9.05], [4.0] * 10])
    w = np.full(10, 0.1)
    g = group_returns(idx, t, w, separation=1.0, min_share=0.0)
    assert g["return_number"].tolist() == [1, 2, 3, 1] and g["number_of_returns"].tolist() == [3, 3, 3, 1]
    assert np.allclose(g["share"], [0.1, 0.3, 0.5, 1.0])
    assert g["index"].tolist() == [0, 1, 2, 3]
    pick = lambda kinds: select_returns(g, kinds).tolist()  # noqa: E731
    assert pick(("first",)) == [0, 3] and pick(("last",)) == [2, 3] and pick(("strongest",)) == [2, 3]
    assert pick(("first", "strongest")) == [0, 2, 3]
    # strength is share times intensity where the cloud has one
    g2 = group_returns(idx, t, w, 1.0, 0.0, intensity=np.array([1.0, 4.0, 1.0, 1.0]))
    assert select_returns(g2, ("strongest",)).tolist() == [1, 3]
    # below min_share a return is not detected, and the numbering skips it
    g3 = group_returns(idx, t, w, 1.0, 0.2)
    assert g3["return_number"].tolist() == [1, 2, 1] and g3["number_of_returns"].tolist() == [2, 2, 1]


def test_returns_written_to_las_as_standard_fields(tmp_path):
    pts, radii, normals, _ = step_edge()
    sc = prepare(pts, "embree", radius=radii, normals=normals)
    eff = Effects(divergence_mrad=DIV_MRAD, beam_rings=6, returns="all", min_share=0.0)
    es = simulate(sc, [0, 0, 0], ScanPattern(3.0, zenith_range=(88.5, 91.5)), eff)
    assert es.number_of_returns.max() == 2
    path = write_cloud(tmp_path / "r.las", es.to_cloud())
    las = laspy.read(path)
    assert np.array_equal(np.asarray(las.return_number), es.return_number)
    assert np.array_equal(np.asarray(las.number_of_returns), es.number_of_returns)


def test_binning_refuses_divergence():
    with pytest.raises(InputValueError, match="embree"):
        simulate(prepare(np.eye(3)), [0, 0, 0], 1.0, Effects(divergence_mrad=3.0))


def test_no_divergence_through_cast_is_one_return_a_pulse():
    pts, radii, normals, _ = step_edge()
    sc = prepare(pts, "embree", radius=radii, normals=normals)
    es = simulate(sc, [0, 0, 0], ScanPattern(3.0, zenith_range=(88.5, 91.5)), Effects())
    assert np.all(es.return_number == 1) and es.ideal is not None
    assert np.array_equal(np.sort(es.indices), es.ideal.indices)
