"""Intensity (slr_ray.effects.intensity): carried, corrected by the documented model, never invented."""

import numpy as np
import pytest

from slr_ray import ScanPattern, prepare
from slr_ray.effects import Effects, simulate
from slr_ray.effects.intensity import corrected_intensity

PATTERN = ScanPattern(0.5, zenith_range=(75, 105))


def wall():
    y, z = np.meshgrid(np.arange(-4, 4, 0.03), np.arange(-2, 2, 0.03), indexing="ij")
    return np.column_stack([np.full(y.size, 10.0), y.ravel(), z.ravel()])


def test_carry_and_none_invented():
    pts = wall()
    inten = np.random.default_rng(0).uniform(0, 1, len(pts))
    sc = prepare(pts)
    es = simulate(sc, [0, 0, 0], PATTERN, Effects(intensity="carry"), intensity=inten)
    assert np.array_equal(es.intensity, inten[es.indices])
    assert simulate(sc, [0, 0, 0], PATTERN, Effects(intensity="carry")).intensity is None
    assert "intensity" not in simulate(sc, [0, 0, 0], PATTERN, Effects(intensity="carry")).to_cloud().attributes


def test_correct_follows_inverse_square_and_cosine():
    pts = wall()
    inten = np.full(len(pts), 0.5)
    normals = np.tile([-1.0, 0, 0], (len(pts), 1))
    sc = prepare(pts)
    po = np.array([5.0, 0, 0])  # the primary stood 5 m from the wall; the new scanner stands 10 m away
    es = simulate(sc, [0, 0, 0], PATTERN, Effects(intensity="correct"), intensity=inten, normals=normals,
                  primary_origin=po)
    p = pts[es.indices]
    r0, r = np.linalg.norm(p - po, axis=1), np.linalg.norm(p, axis=1)
    c0, c = (p - po)[:, 0] / r0, p[:, 0] / r
    assert np.allclose(es.intensity, np.clip(0.5 * (r0 / r) ** 2 * c / c0, 0, 0.5))
    axis = np.hypot(p[:, 1], p[:, 2]) < 0.3
    assert np.allclose(es.intensity[axis], 0.125, rtol=0.01)  # twice as far, head on: a quarter
    # the model by itself: twice the range, a quarter; never above the cloud's maximum
    assert corrected_intensity([0.4], [20.0], [10.0], [1.0], [1.0])[0] == pytest.approx(0.1)
    assert corrected_intensity([0.4, 0.8], [5.0, 20], [10.0, 20], [1.0, 1], [1.0, 1])[0] == pytest.approx(0.8)
