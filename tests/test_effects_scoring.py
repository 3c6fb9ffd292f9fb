"""A scan with effects as images, and intensity errors (slr_ray.effects.scoring), against brute force."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slr_ray import InputValueError, ScanPattern, prepare
from slr_ray.effects import Effects, intensity_metrics, range_image, simulate


def fake_scan(seed, n, shape=(4, 6), with_intensity=True):
    rng = np.random.default_rng(seed)
    pulses = np.column_stack([rng.integers(0, shape[0], n), rng.integers(0, shape[1], n)])
    return SimpleNamespace(pattern=SimpleNamespace(shape=shape), pulses=pulses,
                           ranges=rng.choice([1.0, 2.0, 2.5, 7.0], n), indices=rng.integers(0, 50, n),
                           intensity=rng.uniform(0, 1, n) if with_intensity else None)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 40), inten=st.booleans())
def test_range_image_is_the_nearest_return_of_each_pulse(seed, n, inten):
    es = fake_scan(seed, n, with_intensity=inten)
    img = range_image(es)
    best = {}
    for i in range(n):  # brute force: nearest range per pulse, ties to the first row
        k = tuple(es.pulses[i])
        if k not in best or es.ranges[i] < es.ranges[best[k]]:
            best[k] = i
    for v in range(4):
        for h in range(6):
            i = best.get((v, h))
            if i is None:
                assert math.isnan(img["range"][v, h]) and img["index"][v, h] == -1 and img["row"][v, h] == -1
            else:
                assert img["range"][v, h] == es.ranges[i] and img["index"][v, h] == es.indices[i]
                assert img["row"][v, h] == i
                if inten:
                    assert img["intensity"][v, h] == es.intensity[i]
    assert (img["intensity"] is None) == (not inten)


def test_range_image_of_a_multi_return_scan_keeps_the_first_return():
    # a near plate in front of a far wall under a wide beam: pulses with two returns
    y, z = np.meshgrid(np.arange(-3, 3, 0.01), np.arange(-1, 1, 0.01), indexing="ij")
    far = np.column_stack([np.full(y.size, 20.0), y.ravel(), z.ravel()])
    near = far[(far[:, 1] > 0.2) & (far[:, 1] < 1.5)] * [0.5, 0.5, 0.5]
    pts = np.vstack([near, far])
    sc = prepare(pts, "embree", radius=0.012, normals=np.tile([-1.0, 0, 0], (len(pts), 1)))
    es = simulate(sc, [0, 0, 0], ScanPattern(1.0, zenith_range=(88, 92)),
                  Effects(divergence_mrad=30.0, returns="all", min_share=0.0), intensity=np.ones(len(pts)))
    assert np.any(es.number_of_returns > 1)
    img = range_image(es)
    for v, h in {tuple(p) for p in es.pulses}:
        mine = (es.pulses[:, 0] == v) & (es.pulses[:, 1] == h)
        assert img["range"][v, h] == es.ranges[mine].min()
        assert es.return_number[img["row"][v, h]] == 1


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 30))
def test_intensity_metrics_against_numpy(seed, n):
    rng = np.random.default_rng(seed)
    real = rng.uniform(0, 1, (3, n))
    sim = real + rng.normal(0, 0.1, (3, n))
    real[rng.uniform(size=real.shape) < 0.3] = np.nan
    sim[rng.uniform(size=sim.shape) < 0.3] = np.nan
    m = intensity_metrics(real, sim)
    both = np.isfinite(real) & np.isfinite(sim)
    e = sim[both] - real[both]
    assert m["pulses"] == both.sum()
    if both.sum() == 0:
        assert math.isnan(m["mae"])
        return
    assert m["mae"] == pytest.approx(np.abs(e).mean())
    assert m["medae"] == pytest.approx(np.median(np.abs(e)))
    assert m["rmse"] == pytest.approx(np.sqrt((e ** 2).mean()))
    assert m["bias"] == pytest.approx(e.mean())
    if both.sum() > 1:
        assert m["pearson"] == pytest.approx(np.corrcoef(real[both], sim[both])[0, 1], abs=1e-9)


def test_intensity_metrics_extremes():
    real = np.array([[0.1, 0.5, 0.9]])
    assert intensity_metrics(real, None)["pulses"] == 0  # nothing to score: nothing invented
    assert intensity_metrics(real, real)["rmse"] == 0 and intensity_metrics(real, real)["pearson"] == pytest.approx(1)
    assert math.isnan(intensity_metrics(real, np.full((1, 3), 0.5))["pearson"])  # no spread
    with pytest.raises(InputValueError, match="one shape"):
        intensity_metrics(real, np.ones((3, 1)))
