"""The binning backend: a prepared scanner reuses its tables, scans from several
threads at once, and reduces patterns that do not stream with their own reduction."""

import warnings

import numpy as np
import pytest

from slr_ray import ScanPattern, prepare, sensor
from slr_ray.backends import Backend

from conftest import brute_force_scan


def test_prepared_scanner_reuses_its_tables_exactly():
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(20000, 3)) * 10
    scanner = prepare(pts)
    for origin, res in [((0, 0, 0), 1.0), ((3, 1, 0), 1.0), ((3, 1, 0), 0.5), ((-2, 0, 1), 1.0)]:
        got = scanner.scan(origin, res)
        np.testing.assert_array_equal(got.indices, brute_force_scan(pts, np.asarray(origin, float),
                                                                    ScanPattern(res)))
        np.testing.assert_array_equal(got.ranges, np.linalg.norm(pts[got.indices] - origin, axis=1))


def test_concurrent_scans_of_one_scanner_agree():
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(8)
    pts = rng.normal(size=(40000, 3)) * 10
    scanner = prepare(pts, n_threads=1)
    origins = rng.normal(size=(8, 3))
    with ThreadPoolExecutor(4) as pool:
        scans = list(pool.map(lambda o: scanner.scan(o, 1.0), origins))
    for o, got in zip(origins, scans):
        np.testing.assert_array_equal(got.indices, brute_force_scan(pts, o, ScanPattern(1.0)))



def test_a_beam_table_is_reduced_by_its_own_rule():
    rng = np.random.default_rng(12)
    pts = rng.normal(size=(20000, 3)) * 10
    pattern = sensor("velodyne_vlp16", columns=360)
    assert not pattern.streamable
    got = prepare(pts).scan([0, 0, 0], pattern)
    keys, ranges = pattern.pulse_ids(pts, np.zeros(3))
    best = {}
    for i in np.flatnonzero(keys >= 0):  # nearest per pulse, ties to the lowest index
        k = keys[i]
        if k not in best or ranges[i] < ranges[best[k]]:
            best[k] = i
    np.testing.assert_array_equal(got.indices, sorted(best.values()))
    assert got.backend is Backend.BINNING and f"{got.backend}" == "binning"


def test_names_moved_to_the_core_still_import_with_a_warning():
    from slr_ray import core
    from slr_ray.backends import binning

    with pytest.warns(DeprecationWarning, match="slr_ray.core.pulse_ids"):
        assert binning.pulse_keys is core.pulse_ids
    with pytest.warns(DeprecationWarning, match="slr_ray.core.BinTables"):
        assert binning.BinTables is core.BinTables
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(AttributeError):
            binning.no_such_name
    pattern = sensor("velodyne_vlp16")
    pts = np.random.default_rng(0).normal(size=(50, 3))
    with pytest.warns(DeprecationWarning, match="pulse_ids"):
        old = pattern.keys(pts, np.zeros(3))
    for a, b in zip(old, pattern.pulse_ids(pts, np.zeros(3))):
        np.testing.assert_array_equal(a, b)
