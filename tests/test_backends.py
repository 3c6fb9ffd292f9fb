"""The backend protocol: prepare once, scan many; typed options."""

import numpy as np
import pytest

import slr_ray
from slr_ray import InputValueError, ScanPattern
from slr_ray.backends import Backend, BinningOptions, EmbreeOptions, available_backends, options_for, prepare


def _cloud(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-10, 10, (n, 3))


def test_registry_names_and_available():
    assert [b.value for b in Backend] == ["binning", "embree"]
    assert available_backends()[0] == "binning" and "embree" in available_backends()
    with pytest.raises(InputValueError, match="unknown backend"):
        prepare(_cloud(), "optix")


@pytest.mark.parametrize("backend", ["binning", "embree"])
def test_prepare_then_scan_equals_simulate_scan_at_every_position(backend):
    pts = _cloud()
    scanner = prepare(pts, backend)
    assert isinstance(scanner, slr_ray.Scanner) and scanner.backend == backend and len(scanner) == len(pts)
    p = ScanPattern(2.0)
    for origin in ([0, 0, 0], [3.0, -2.0, 1.0], [-8.0, 8.0, 0.5]):
        a = scanner.scan(origin, p)
        b = slr_ray.simulate_scan(pts, origin, p, backend=backend)
        assert np.array_equal(a.indices, b.indices) and np.array_equal(a.pulses, b.pulses)
        assert a.backend == backend and a.n_input == len(pts)


def test_scanner_does_not_copy_or_modify_the_points():
    pts = _cloud()
    before = pts.copy()
    s = prepare(pts)
    s.scan([0, 0, 0], 1.0)
    assert s.points is pts and np.array_equal(pts, before)


def test_options_are_typed_and_unknown_keys_are_refused():
    assert options_for("binning", {"n_threads": 2}) == BinningOptions(n_threads=2)
    o = options_for("embree", {"radius": 0.05}, orientation="billboard")
    assert isinstance(o, EmbreeOptions) and o.radius == 0.05 and o.orientation == "billboard"
    with pytest.raises(InputValueError, match="unknown option.*'radiuss'.*known"):
        options_for("embree", {"radiuss": 0.05})
    with pytest.raises(InputValueError, match="unknown option"):
        slr_ray.simulate_scan(_cloud(), [0, 0, 0], 1.0, n_thread=2)
    with pytest.raises(InputValueError, match="n_threads"):
        BinningOptions(n_threads=0)
    with pytest.raises(InputValueError, match="given for backend"):
        options_for("binning", EmbreeOptions())
    with pytest.raises(InputValueError, match="engine"):
        EmbreeOptions(engine="optix")
    with pytest.raises(InputValueError, match="billboard"):
        EmbreeOptions(orientation="billboard", engine="fan")
    with pytest.raises(InputValueError, match="footprint"):
        EmbreeOptions(radius="footprint")
    assert EmbreeOptions().to_dict()["engine"] == "embree"


def test_non_finite_rows_are_refused_at_prepare_with_their_count():
    pts = _cloud()
    pts[[3, 9]] = np.nan
    with pytest.raises(InputValueError, match="2 row"):
        prepare(pts)


# --- translation invariance -----------------------------------------------------------------------------------

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_Q = 1 / 1024  # coordinates and offsets on a 1/1024 m grid: every sum and difference below is exact in float64


def _exact_cloud(seed, n):
    """A floor, a wall and clutter around the origin, and a dense patch (millimetre
    spacing: where a threshold scaled by absolute coordinates would call neighbourhoods
    degenerate); every coordinate a multiple of 1/1024 m."""
    rng = np.random.default_rng(seed)
    floor = np.column_stack([rng.uniform(-8, 8, (n, 2)), rng.normal(-1.6, 0.01, n)])
    wall = np.column_stack([rng.uniform(-8, 8, n // 2), np.full(n // 2, 6.0) + rng.normal(0, 0.01, n // 2),
                            rng.uniform(-1.6, 2, n // 2)])
    clutter = rng.uniform(-5, 5, (n // 4, 3))
    patch = np.column_stack([rng.uniform(0, 0.15, (n, 2)), rng.normal(-1.6, 0.002, n)])
    return np.unique(np.round(np.vstack([floor, wall, clutter, patch]) / _Q), axis=0) * _Q


@pytest.mark.parametrize("backend", ["binning", "embree"])
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**16), offset=st.tuples(*[st.integers(-10**7 * 1024, 10**7 * 1024)] * 3),
       origin=st.tuples(*[st.integers(-512, 512)] * 3), resolution=st.sampled_from([0.25, 0.5, 1.0]))
def test_scans_do_not_depend_on_where_the_cloud_lies(backend, seed, offset, origin, resolution):
    """Moving cloud and scanner by one offset (up to 1e7 m) changes no index and no pulse:
    the backends work on offsets from the scanner (and, for embree's normals, from each
    point), never on absolute coordinates. Exactly representable clouds, so that the
    moved cloud is the same cloud."""
    pts = _exact_cloud(seed, 1500)
    shift = np.array(offset, float) * _Q
    o = np.array(origin, float) * _Q
    moved = pts + shift
    assert np.array_equal(moved - shift, pts)  # the premise: the translation is exact
    a = prepare(pts, backend).scan(o, resolution)
    b = prepare(moved, backend).scan(o + shift, resolution)
    assert len(a) > 100
    np.testing.assert_array_equal(a.indices, b.indices)
    np.testing.assert_array_equal(a.pulses, b.pulses)
