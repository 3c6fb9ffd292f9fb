"""Ray drop (slr_ray.effects.raydrop): fit recovers its generating parameters; frame extraction is exact."""

import json

import numpy as np
import pytest

from slr_ray import InputValueError, ScanPattern, prepare
from slr_ray.effects import Effects, RayDropModel, fit_ray_drop, frame_pulses, rings_from_scan_order, simulate

from conftest import DATA

TRUE = (-4.0, 1.5, 0.5, -1.0, 3.0, -2.0)
KITTI = DATA / "kitti_hdl64_000000.bin"


@pytest.mark.parametrize("seed", [0, 1])
def test_fit_recovers_the_generating_parameters(seed):
    rng = np.random.default_rng(seed)
    n = 200_000
    r, inc, inten = rng.uniform(1, 90, n), rng.uniform(0, 89, n), rng.uniform(0, 1, n)
    model = RayDropModel(TRUE, uses_intensity=True)
    dropped = model.sample(r, inc, inten, rng=rng)
    fit = fit_ray_drop(r, inc, dropped, inten)
    z = (np.array(fit.coef) - TRUE) / np.array(fit.stderr)
    assert np.all(np.abs(z) < 4.5), z
    # the fitted probabilities, not only the weights
    assert np.max(np.abs(fit.probability(r, inc, inten) - model.probability(r, inc, inten))) < 0.02


def test_fit_without_intensity_and_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    r, inc = rng.uniform(1, 90, 50_000), rng.uniform(0, 89, 50_000)
    m = RayDropModel(TRUE[:5])
    fit = fit_ray_drop(r, inc, m.sample(r, inc, rng=rng))
    assert not fit.uses_intensity and len(fit.coef) == 5
    path = tmp_path / "drop.json"
    path.write_text(json.dumps(fit.to_dict()))
    assert Effects(ray_drop=str(path)).ray_drop == fit
    with pytest.raises(InputValueError, match="intensity"):
        RayDropModel(TRUE, uses_intensity=True).probability(r, inc)
    with pytest.raises(InputValueError, match="both"):
        fit_ray_drop(r, inc, np.zeros(len(r), bool))


def ring_frame(n_rings=6, n_cols=720, drop=0.1, seed=0):
    """A frame on a cylinder (radius 10 m) stored ring after ring, azimuth increasing: the pulses
    dropped are known; runs of 1-3 missing pulses only (longer runs are not counted)."""
    rng = np.random.default_rng(seed)
    step = 360.0 / n_cols
    keep = rng.random((n_rings, n_cols)) >= drop
    keep[:, 0] = keep[:, -1] = True
    pts, truth = [], 0
    for k in range(n_rings):
        phi = np.radians((np.flatnonzero(keep[k]) + 0.5) * step)
        el = np.radians(2.0 - k)
        pts.append(np.column_stack([10 * np.cos(phi), 10 * np.sin(phi), np.full(len(phi), 10 * np.tan(el))]))
        truth += n_cols - keep[k].sum()
    return np.vstack(pts), truth, step


def test_frame_pulses_counts_exactly_the_dropped_pulses():
    pts, truth, step = ring_frame()
    assert rings_from_scan_order(pts).max() == 5
    fp = frame_pulses(pts, max_gap=50)
    assert fp["column_step_deg"] == pytest.approx(step)
    assert fp["dropped"].sum() == truth and (~fp["dropped"]).sum() == len(pts)
    assert np.allclose(fp["range"], 10 / np.cos(np.radians(2.0 - fp["ring"])), rtol=1e-9)


def test_drop_applied_to_a_resimulated_scan_is_seeded_and_at_its_rate():
    y, z = np.meshgrid(np.arange(-8, 8, 0.02), np.arange(-3, 3, 0.02), indexing="ij")
    pts = np.column_stack([np.full(y.size, 10.0), y.ravel(), z.ravel()])
    sc = prepare(pts)
    pat = ScanPattern(0.3, zenith_range=(72, 108))
    model = RayDropModel((np.log(0.25 / 0.75), 0, 0, 0, 0))  # 25 % everywhere
    ideal = simulate(sc, [0, 0, 0], pat)
    a = simulate(sc, [0, 0, 0], pat, Effects(ray_drop=model, seed=4), normals=np.tile([1.0, 0, 0], (len(pts), 1)))
    b = simulate(sc, [0, 0, 0], pat, Effects(ray_drop=model, seed=4), normals=np.tile([1.0, 0, 0], (len(pts), 1)))
    assert np.array_equal(a.indices, b.indices)
    assert 1 - len(a) / len(ideal) == pytest.approx(0.25, abs=0.02)
    assert set(a.indices) <= set(ideal.indices)


@pytest.mark.skipif(not KITTI.exists(), reason="../shared/data/kitti_hdl64_000000.bin is absent")
def test_kitti_frame_rings_and_fit():
    a = np.fromfile(KITTI, np.float32).reshape(-1, 4).astype(np.float64)
    rings = rings_from_scan_order(a[:, :3])
    assert rings.max() == 63  # 64 beams
    fp = frame_pulses(a[:, :3], intensity=a[:, 3], rings=rings)
    fit = fit_ray_drop(fp["range"], fp["incidence"], fp["dropped"], fp["intensity"])
    far, near = fp["range"] > 40, fp["range"] < 20
    p = fit.probability(fp["range"], fp["incidence"], fp["intensity"])
    # the frame drops more far away, and the model says so
    assert fp["dropped"][far].mean() > 2 * fp["dropped"][near].mean()
    assert p[far].mean() > 2 * p[near].mean()
    assert p.mean() == pytest.approx(fp["dropped"].mean(), rel=0.01)  # a logistic fit matches the mean rate


def test_a_fit_refuses_features_no_sensor_has_without_a_numpy_warning():
    """A point 1e200 m away, an intensity scale of 1e-300: the fit's logit overflowed with numpy's warning."""
    import warnings

    rng = np.random.default_rng(0)
    r, inc, inten = rng.uniform(1, 50, 500), rng.uniform(0, 80, 500), rng.uniform(0, 1, 500)
    drop = rng.random(500) < 0.3
    for kw, says in (({"ranges": r * 1e200}, "non-finite features"), ({"ranges": r * 1e150}, "beyond a sensor's"),
                     ({"intensity_scale": 1e-300}, "intensity_scale must lie")):
        args = {"ranges": r, "incidence": inc, "dropped": drop, "intensity": inten} | kw
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(InputValueError, match=says):
                fit_ray_drop(**args)
