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


@pytest.mark.parametrize("kind", ["slots", "hash"])
def test_scans_kept_by_the_caller_are_never_overwritten(kind, monkeypatch):
    # fine patterns' scans take their arrays from a pool of the scanner's last
    # outputs: a set is reused only once no scan (nor any array taken from one)
    # refers to it
    from slr_ray.core import BinTables

    monkeypatch.setattr(BinTables, "dense_bytes", 0)
    monkeypatch.setattr(BinTables, "slot_bytes", 2**62 if kind == "slots" else 0)
    rng = np.random.default_rng(9)
    pts = rng.normal(size=(30000, 3)) * 10
    scanner = prepare(pts, n_threads=2)
    origins = rng.normal(size=(6, 3))
    want = [brute_force_scan(pts, o, ScanPattern(1.0)) for o in origins]
    kept = [scanner.scan(o, 1.0) for o in origins]  # all held: every one its own arrays
    held_indices = scanner.scan(origins[0], 1.0).indices  # only one array of a scan held
    for o, w, got in zip(origins, want, kept):
        np.testing.assert_array_equal(got.indices, w)
        np.testing.assert_array_equal(got.ranges, np.linalg.norm(pts[w] - o, axis=1))
        np.testing.assert_array_equal(got.pulses, ScanPattern(1.0).unravel(
            ScanPattern(1.0).pulse_ids(pts[w], o)[0]))
    for _ in range(3):
        np.testing.assert_array_equal(scanner.scan(origins[1], 1.0).indices, want[1])  # dropped at once
    np.testing.assert_array_equal(held_indices, want[0])
    if kind == "slots":  # the dropped scans' arrays were reused
        scanner.scan(origins[2], 1.0)  # dropped at once: its set is free again
        b = scanner.scan(origins[3], 1.0)
        c = scanner.scan(origins[4], 1.0)
        np.testing.assert_array_equal(b.indices, want[3])
        np.testing.assert_array_equal(c.indices, want[4])
        assert not np.shares_memory(b.indices, c.indices)
    del kept
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(4) as pool:
        scans = list(pool.map(lambda o: scanner.scan(o, 1.0), np.repeat(origins, 3, axis=0)))
    for o, got in zip(np.repeat(origins, 3, axis=0), scans):
        np.testing.assert_array_equal(got.indices, brute_force_scan(pts, o, ScanPattern(1.0)))


def test_a_file_mapped_cloud_scans_in_chunks_to_the_same_answer(tmp_path, monkeypatch):
    """A validation's spilled primary is binned chunk by chunk, each chunk's pages
    released once read: the same points, ranges and pulses as in memory
    (ties across chunk ends go to the lower index, as in one pass)."""
    import slr_ray.backends.binning as binning

    rng = np.random.default_rng(3)
    pts = np.round(rng.normal(size=(30_000, 3)) * 10, 1)  # coarse: many exact ties in range
    pts[1000:] = pts[rng.integers(0, 1000, len(pts) - 1000)]  # duplicates far apart in index
    np.save(tmp_path / "p.npy", pts)
    mapped = np.load(tmp_path / "p.npy", mmap_mode="r")
    released = []
    real = binning.release_pages
    monkeypatch.setattr(binning, "MAPPED_CHUNK", 7001)
    monkeypatch.setattr(binning, "release_pages", lambda a: released.append(len(a)) or real(a))
    plain = prepare(mapped)
    plain.scan((0, 0, 0), 1.0)
    assert released == []  # off by default: a loop over positions would fault the cloud in every scan
    for origin in ((0, 0, 0), (3, -2, 1)):
        want = prepare(pts).scan(origin, 1.0)
        scanner = prepare(mapped)
        scanner.release_mapped = True
        got = scanner.scan(origin, 1.0)
        np.testing.assert_array_equal(got.indices, want.indices)
        np.testing.assert_array_equal(got.ranges, want.ranges)
        np.testing.assert_array_equal(got.pulses, want.pulses)
        np.testing.assert_array_equal(got.indices, brute_force_scan(pts, np.asarray(origin, float),
                                                                    ScanPattern(1.0)))
    assert released[:5] == [7001, 7001, 7001, 7001, 30_000 - 4 * 7001]
