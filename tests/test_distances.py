import json

import numpy as np
import pytest

from slr_ray import InputValueError, ScanPattern, scan_mesh
from slr_ray.distances import DistanceHistogram, distance_histogram, distance_study, height_sweep, pulse_sized_bins
from slr_ray.scenes import rectangle_scene


@pytest.mark.parametrize("res", [0.144, 0.5, 2.0])
def test_edges_increase_and_start_at_the_height(res):
    e = pulse_sized_bins(1.65, res, 120.0)
    assert e[0] == 1.65 and e[-1] == 120.0 and np.all(np.diff(e) > 0)
    assert np.all(np.diff(np.diff(e[:-1])) > 0)  # bins widen with distance
    h = pulse_sized_bins(1.65, res, 120.0, horizontal=True)
    assert h[0] == 0 and np.all(np.diff(h) > 0)
    assert pulse_sized_bins(2.0, res, 50.0, from_zero=True)[:2].tolist() == [0.0, 2.0]


@pytest.mark.parametrize("height, res", [(1.65, 0.5), (0.5, 1.0), (4.0, 0.5)])
def test_a_ground_plane_fills_every_bin_with_one_ring(height, res):
    sc = rectangle_scene(0, ground_z=-height)
    p = ScanPattern(res)
    ms = scan_mesh(sc, [0, 0, 0], p)
    bins = pulse_sized_bins(height, res, 60.0)
    h = distance_histogram(ms.points, [0, 0, 0], ms.labels == 0, bins)
    inner = h.counts["ground"][:-1]  # the last bin is cut at 60 m
    assert np.all(inner == p.n_azimuth)  # one point per azimuth bin: a flat count
    assert h.counts["non_ground"].sum() == 0
    assert h.counts["ground"].sum() + h.above["ground"] + h.below["ground"] == len(ms)
    hz = distance_histogram(ms.points, [0, 0, 0], ms.labels == 0,
                            pulse_sized_bins(height, res, 60.0, horizontal=True), horizontal=True)
    assert np.all(hz.counts["ground"][:-1] == p.n_azimuth)


def test_pooling_adds_up():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(500, 3)) * 10, rng.normal(size=(700, 3)) * 10
    ga, gb = rng.random(500) < 0.4, rng.random(700) < 0.4
    ha = distance_histogram(a, [0, 0, 0], ga)
    ha += distance_histogram(b, [1, 0, 0], gb)
    ref = DistanceHistogram(ha.edges).add(a, [0, 0, 0], ga).add(b, [1, 0, 0], gb)
    for k in ("all", "ground", "non_ground"):
        np.testing.assert_array_equal(ha.counts[k], ref.counts[k])
    assert ha.n_scans == 2 and len(ha.ground_fractions) == 2
    total = ha.counts["all"].sum() + ha.below["all"] + ha.above["all"]
    assert total == 1200  # nothing lost
    d = ha.density("all")
    assert np.sum(d * np.diff(ha.edges)) == pytest.approx(1.0)
    with pytest.raises(InputValueError):
        ha += DistanceHistogram(pulse_sized_bins(2.0))


def test_lower_scanner_moves_the_ground_peak_not_the_non_ground_one():
    sc = rectangle_scene(300, seed=2)
    ms = scan_mesh(sc, [0, 0, 0], ScanPattern(0.1))
    rng = np.random.default_rng(1)
    r, a = rng.uniform(3, 20, 5), rng.uniform(0, 2 * np.pi, 5)
    pos = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(5)])  # 1.65 m above the ground
    sweep = height_sweep(ms.points, ms.labels == 0, pos, heights=(0.5, 1.65, 4.0))
    peaks = {h: v.peak("ground") for h, v in sweep.items()}
    assert peaks[0.5] < peaks[1.65] < peaks[4.0]
    ng = [v.peak("non_ground") for v in sweep.values()]
    assert max(ng) - min(ng) < 0.5 * max(peaks.values())
    for v in sweep.values():
        assert 0.2 < np.mean(v.ground_fractions) < 0.95


def test_distances_command(tmp_path, capsys):
    from slr_ray.cli import main
    from slr_ray.io import PointCloud, write_cloud

    sc = rectangle_scene(100, seed=1, ground_radius=30.0, xy_range=(-30, 30))
    ms = scan_mesh(sc, [0, 0, 0], ScanPattern(0.2))
    write_cloud(tmp_path / "scan.npz", PointCloud(ms.points, {"is_ground": ms.labels == 0}, np.zeros(3)))
    assert main(["distances", str(tmp_path / "scan.npz"), "--positions", "3", "--heights", "1", "2",
                 "--min-ground-points", "500", "--quiet", "-o", str(tmp_path / "out")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {"original.csv", "slr.csv", "height_1m.csv", "height_2m.csv", "distances.png"} <= set(res["files"])
    assert res["heights"]["1"]["peak_ground_m"] < res["heights"]["2"]["peak_ground_m"]
    assert 0 < res["original"]["ground_fraction_mean"] < 1


def test_a_cloud_without_an_origin_is_refused_before_its_ground_is_labelled(monkeypatch):
    # was: CSF first (a minute on an airborne tile), then "records no scanner origin"
    from slr_ray.io import PointCloud

    def no_csf(*a, **k):
        raise AssertionError("CSF ran")

    monkeypatch.setattr("slr_ray.positions.label_ground", no_csf)
    pts = np.random.default_rng(0).uniform(-5, 5, (200, 3))
    with pytest.raises(InputValueError, match="records no scanner origin"):
        distance_study([PointCloud(pts)], positions=1)
