"""The synthetic drive scanned by a real-like unit (slr_ray.sequence.synthetic, ``unit="real"``): its frames
depart from the table's pulse centres by the unit's departures, and the ``rays`` estimator's fit finds them."""

import numpy as np
import pytest

from slr_ray.errors import InputValueError
from slr_ray.sequence import read_sequence
from slr_ray.sequence.rays import fit_range_bias, fit_ray_model, frame_motion
from slr_ray.sequence.synthetic import REAL_UNIT, synthetic_drive
from slr_ray.sensors import miscalibrated, scan_order_beams, sensor

HDL = "velodyne_hdl64e_s2"


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    root = tmp_path_factory.mktemp("synreal")
    synthetic_drive(root / "real", n_frames=2, sensor=HDL, moving=False, unit="real", truth=root / "truth")
    synthetic_drive(root / "exact", n_frames=1, sensor=HDL, moving=False)
    return read_sequence(root / "real"), read_sequence(root / "truth"), read_sequence(root / "exact")


def test_the_real_units_frames_differ_from_the_truth_by_its_noise_and_lose_its_share(drives):
    real, truth, exact = drives
    base = sensor(HDL)
    unit = miscalibrated(base, REAL_UNIT["elevation_sd"], REAL_UNIT["azimuth_sd"], seed=0)
    offsets = np.random.default_rng(0).normal(0.0, REAL_UNIT["beam_range_sd"], base.n_beams)  # sensor_noise's draw
    for i in range(2):
        a, b = real.read(i).points, truth.read(i).points
        rings = scan_order_beams(a, base.n_beams)  # written in KITTI's scan order: the beams are known
        assert rings is not None and np.array_equal(rings, scan_order_beams(b, base.n_beams))
        d = np.linalg.norm(a, axis=1) - np.linalg.norm(b, axis=1)
        per_ring = np.bincount(rings, d) / np.bincount(rings)
        # the unit's per-beam offsets, the same in every frame, then each point's own range noise
        assert np.abs(per_ring - offsets[unit.beam_of_row]).max() < 0.003
        assert abs(np.std(d - per_ring[rings]) - REAL_UNIT["range_sd"]) < 0.001
        # the same directions as the truth's: along the rays from the origin
        sin = np.linalg.norm(np.cross(a, b), axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        assert sin.max() < 1e-5  # the .bin's float32
    lost = 1 - len(real.read(0).points) / len(exact.read(0).points)
    assert abs(lost - REAL_UNIT["dropout"]) < 0.02


def test_the_rays_fit_recovers_the_units_miscalibration(drives):
    real = drives[0]
    base = sensor(HDL)
    unit = miscalibrated(base, REAL_UNIT["elevation_sd"], REAL_UNIT["azimuth_sd"], seed=0)
    frames, worlds = [], []
    for i in range(2):
        f = real.read(i)
        rings = scan_order_beams(f.points, base.n_beams)
        frames.append((f.points, rings, frame_motion(real.poses, i)))
        worlds.append((f.points @ real.poses[i][:3, :3].T + real.poses[i][:3, 3], rings, real.poses[i], frames[-1][2]))
    model = fit_range_bias(fit_ray_model(frames, base.n_beams, skews=(-0.5, 0.0, 0.5), stride=4), worlds)
    truth = np.sort(unit.elevation_deg)[::-1]  # ring 0: the highest beam
    nominal = np.sort(base.elevation_deg)[::-1]
    assert np.median(np.abs(nominal - truth)) > 0.03  # the unit is off its table...
    assert np.abs(np.degrees(model.elevation) - truth).max() < 0.001  # ... and the fit finds where
    assert np.abs(model.height).max() < 0.005 and model.skew == 0.0  # rays from the origin, no motion in a sweep
    offsets = np.random.default_rng(0).normal(0.0, REAL_UNIT["beam_range_sd"], base.n_beams)[unit.beam_of_row]
    assert np.median(np.abs(model.range_bias - offsets)) < 0.015 and np.corrcoef(model.range_bias, offsets)[0, 1] > 0.7


def test_the_unit_is_named_and_truth_needs_a_real_unit(tmp_path):
    with pytest.raises(InputValueError, match="unknown unit"):
        synthetic_drive(tmp_path / "a", n_frames=1, unit="ideal")
    with pytest.raises(InputValueError, match="truth"):
        synthetic_drive(tmp_path / "b", n_frames=1, truth=tmp_path / "t")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
