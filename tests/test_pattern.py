import math

import numpy as np

import pytest

from slr_ray import PRESETS, InputValueError, ScanPattern, preset


def test_resolution_sets_both_axes():
    p = ScanPattern(resolution=0.144)
    assert p.azimuth_resolution == p.zenith_resolution == 0.144
    assert p.shape == (1250, 2500)


def test_axes_can_differ():
    p = ScanPattern(azimuth_resolution=0.622, zenith_resolution=0.048, zenith_range=(30, 130))
    assert p.n_zenith == math.ceil(100 / 0.048)
    assert p.n_azimuth == math.ceil(360 / 0.622)
    assert p.resolution is None


@pytest.mark.parametrize("res, n", [(0.144, 2500), (0.036, 10000), (0.0144, 25000),
                                    (0.00576, 62500), (90, 4), (0.001, 360000), (7, 52)])
def test_whole_bin_counts_despite_rounding(res, n):
    assert ScanPattern(res).n_azimuth == n


@pytest.mark.parametrize("kwargs", [
    dict(resolution=0), dict(resolution=-1), dict(resolution=180.5),
    dict(resolution=float("nan")), dict(resolution="fine"), dict(),
    dict(resolution=1, zenith_range=(10, 10)), dict(resolution=1, zenith_range=(90, 10)),
    dict(resolution=1, zenith_range=(-1, 10)), dict(resolution=1, zenith_range=(0, 181)),
    dict(resolution=1, min_range=-1), dict(resolution=1, max_range=-0.1),
    dict(resolution=1, min_range=5, max_range=1), dict(resolution=1, zenith_range=(1,)),
])
def test_invalid_patterns_raise_value_error_naming_the_field(kwargs):
    with pytest.raises(ValueError) as err:
        ScanPattern(**kwargs)
    assert isinstance(err.value, InputValueError)
    assert any(w in str(err.value) for w in ("resolution", "zenith_range", "range"))


def test_presets_match_the_paper():
    assert preset("slr").resolution == 0.144
    syns = preset("syns")
    assert (syns.resolution, syns.zenith_range, syns.max_range) == (0.036, (0.0, 135.0), 120.0)
    assert preset("primary").resolution == 0.0144
    assert preset("primary-fine").resolution == 0.00576
    assert set(PRESETS) == {"slr", "syns", "primary", "primary-fine"}
    with pytest.raises(InputValueError, match="unknown pattern preset"):
        preset("nope")


def test_dict_round_trip_and_with():
    p = ScanPattern(0.2, zenith_range=(0, 135), min_range=1, max_range=50)
    assert ScanPattern.from_dict(p.to_dict()) == p
    q = p.with_(max_range=10)
    assert q.max_range == 10 and q.resolution == 0.2 and p.max_range == 50
    assert p.with_(resolution=1.0).shape == (135, 360)


def test_patterns_whose_pulses_overflow_the_keys_are_refused_with_the_finest_that_fits():
    from slr_ray.pattern import MAX_PULSES

    for res in (1e-8, 1e-300, 5e-324):
        with pytest.raises(ValueError, match=r"finest resolution for this field of view is 1.19e-07"):
            ScanPattern(res)
    with pytest.raises(ValueError, match="finest"):
        ScanPattern(azimuth_resolution=1e-16, zenith_resolution=1.0)
    p = ScanPattern(1.2e-7)
    assert p.n_pulses <= MAX_PULSES


def test_the_finest_pattern_keeps_every_point_of_a_sparse_cloud():
    """At 1.2e-7 deg (4.5e18 pulses) random points fall in distinct pulses: all come back
    (before the key check, 1e-8 deg returned 99,995 of 200,000 points)."""
    import slr_ray

    pts = np.random.default_rng(3).normal(size=(20_000, 3)) * 10
    scan = slr_ray.simulate_scan(pts, [0.1, 0.2, 0.3], ScanPattern(1.2e-7))
    assert len(scan) == len(pts)
