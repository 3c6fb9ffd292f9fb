import numpy as np

from slr_ray import ScanPattern, pulse_bins, pulse_directions, spherical_coordinates


def test_spherical_coordinates_known_directions():
    pts = np.array([[0, 0, 2.0], [0, 0, -1.0], [1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -3.0, 0]])
    r, th, ph = spherical_coordinates(pts + 10, [10, 10, 10])
    np.testing.assert_allclose(r, [2, 1, 1, 1, 1, 3])
    np.testing.assert_allclose(th, [0, np.pi, np.pi / 2, np.pi / 2, np.pi / 2, np.pi / 2])
    np.testing.assert_allclose(ph[2:], [0, np.pi / 2, np.pi, 3 * np.pi / 2])
    assert np.all((ph >= 0) & (ph < 2 * np.pi))


def test_pulse_bins_match_the_numpy_formula_on_random_points():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(100000, 3)) * 20
    pattern = ScanPattern(azimuth_resolution=0.3, zenith_resolution=0.2, zenith_range=(5, 170),
                          min_range=1, max_range=40)
    v, h, r, vis = pulse_bins(pts, [0.1, 0.2, 0.3], pattern)
    rr, th, ph = spherical_coordinates(pts, [0.1, 0.2, 0.3])
    d_theta, d_phi, th0, th1 = pattern.radians
    exp_vis = (rr >= 1) & (rr <= 40) & (th >= th0) & (th <= th1)
    np.testing.assert_array_equal(vis, exp_vis)
    np.testing.assert_array_equal(r, rr)
    np.testing.assert_array_equal(v[vis], np.floor((th[vis] - th0) / d_theta))
    np.testing.assert_array_equal(h[vis], np.floor(ph[vis] / d_phi))
    assert v[vis].max() < pattern.n_zenith and h[vis].max() < pattern.n_azimuth


def test_pulse_directions_fall_in_their_own_pulse():
    pattern = ScanPattern(azimuth_resolution=2.0, zenith_resolution=3.0, zenith_range=(10, 130))
    nv, nh = pattern.shape
    vv, hh = np.meshgrid(np.arange(nv), np.arange(nh), indexing="ij")
    pulses = np.column_stack([vv.ravel(), hh.ravel()])
    d = pulse_directions(pulses, pattern)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1)
    v, h, _, vis = pulse_bins(d * 7, [0, 0, 0], pattern)
    assert vis.all()
    np.testing.assert_array_equal(np.column_stack([v, h]), pulses)
