"""Range noise, blind zone and reflectivity range (slr_ray.effects.noise) through simulate."""

import numpy as np
import pytest

from slr_ray import ScanPattern, prepare
from slr_ray.effects import Effects, simulate
from slr_ray.effects.noise import add_range_noise, reflectivity_max_range


def wall(step=0.02):
    y, z = np.meshgrid(np.arange(-6, 6, step), np.arange(-3, 3, step), indexing="ij")
    return np.column_stack([np.full(y.size, 10.0), y.ravel(), z.ravel()])


PATTERN = ScanPattern(0.4, zenith_range=(70, 110))


def test_noise_sigma_recovered_from_a_plane():
    pts = wall()
    sc = prepare(pts)
    es = simulate(sc, [0, 0, 0], PATTERN, Effects(range_noise=0.03, seed=3))
    assert len(es) > 5000
    # fit the plane to the noisy points; perpendicular residuals are the range noise times cos(incidence)
    c = es.points.mean(axis=0)
    normal = np.linalg.svd(es.points - c, full_matrices=False)[2][-1]
    d = es.points / np.linalg.norm(es.points, axis=1, keepdims=True)
    along = ((es.points - c) @ normal) / np.abs(d @ normal)
    assert np.std(along) == pytest.approx(0.03, rel=0.05)
    assert abs(normal[0]) == pytest.approx(1.0, abs=1e-3)  # the noise leaves the plane where it was


def test_noise_is_seeded_and_off_by_default():
    sc = prepare(wall(0.05))
    a = simulate(sc, [0, 0, 0], PATTERN, Effects(range_noise=0.02, seed=1))
    b = simulate(sc, [0, 0, 0], PATTERN, Effects(range_noise=0.02, seed=1))
    c = simulate(sc, [0, 0, 0], PATTERN, Effects(range_noise=0.02, seed=2))
    ideal = simulate(sc, [0, 0, 0], PATTERN)
    assert np.array_equal(a.points, b.points) and not np.array_equal(a.points, c.points)
    assert np.array_equal(ideal.points, sc.points[ideal.indices])
    assert np.array_equal(np.sort(ideal.indices), ideal.ideal.indices)


def test_range_dependent_sigma():
    rng = np.random.default_rng(0)
    r = rng.uniform(1, 100, 200_000)
    noisy = add_range_noise(r, 0.01, 0.002, rng=5)
    z = (noisy - r) / (0.01 + 0.002 * r)
    assert np.std(z) == pytest.approx(1.0, abs=0.01) and abs(np.mean(z)) < 0.01


def test_blind_zone_and_reflectivity_range_brute_force():
    pts = np.vstack([wall(0.05) * [0.2, 1, 1], wall(0.05) * [4.0, 1, 1]])  # walls at 2 m and 40 m
    intensity = np.random.default_rng(1).uniform(0, 1, len(pts))
    sc = prepare(pts)
    ideal = simulate(sc, [0, 0, 0], PATTERN, intensity=intensity)
    es = simulate(sc, [0, 0, 0], PATTERN, Effects(min_range=3.0, max_range_at=(50.0, 0.1)), intensity=intensity)
    r = np.linalg.norm(pts[ideal.indices], axis=1)
    rmax = 50 * np.sqrt(intensity[ideal.indices] / 0.1)
    want = ideal.indices[(r >= 3.0) & (r <= rmax)]
    assert np.array_equal(np.sort(es.indices), np.sort(want))
    assert es.info["removed_range_limits"] == len(ideal) - len(want) > 0
    assert reflectivity_max_range([0.8], 50, 0.1)[0] == pytest.approx(50 * np.sqrt(8))


def test_sensor_values_from_the_table():
    from slr_ray.sensors import sensor

    hdl = sensor("velodyne_hdl64e_s2")
    eff = Effects(range_noise="sensor", max_range_at="sensor").resolve(hdl)
    assert eff.range_noise == hdl.meta["range_accuracy_m"] and eff.max_range_at == (50.0, 0.1)
