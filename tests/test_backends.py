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
