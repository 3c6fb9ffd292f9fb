import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slr_ray.errors import InputValueError
from slr_ray.metrics import (LIDAR4D_CODE_THRESHOLD, nearest, point_metrics, range_bands, range_image_metrics,
                             seen_from)
from slr_ray.similarity import agreement


def brute_point_metrics(t, s, taus):
    """Every pair's distance by a plain double loop: the definitions, written the slow way."""
    # each distance as the definition: the root of the summed squared coordinate differences
    d = np.array([[math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b))) for b in s] for a in t]).reshape(len(t), len(s))
    d_t = d.min(axis=1) if len(s) else np.full(len(t), np.inf)
    d_s = d.min(axis=0) if len(t) else np.full(len(s), np.inf)
    out = {"to_target": sum(x * x for x in d_s) / len(s) if len(s) else math.nan,
           "to_simulated": sum(x * x for x in d_t) / len(t) if len(t) else math.nan,
           "to_target_distance": sum(d_s) / len(s) if len(s) else math.nan}
    for tau in taus:
        p = sum(x < tau for x in d_s) / len(s) if len(s) else math.nan
        r = sum(x < tau for x in d_t) / len(t) if len(t) else math.nan
        # one side empty: it recovered (or holds) nothing, F = 0; both empty: nothing to score
        f = (math.nan if math.isnan(p) and math.isnan(r) else 0.0 if math.isnan(p) or math.isnan(r) or p + r == 0
             else 2 * p * r / (p + r))
        out[tau] = (p, r, f)
    return out, d


def clouds(max_n=25):
    # a coarse lattice (many exact ties and points at exactly a threshold) or continuous values
    coord = st.one_of(st.integers(-8, 8).map(lambda i: i * 0.025), st.floats(-1, 1, allow_nan=False, width=32))
    return st.lists(st.tuples(coord, coord, coord), min_size=0, max_size=max_n).map(
        lambda xs: np.array(xs, dtype=np.float64).reshape(-1, 3))


def same(a, b):
    # the kd-tree works on recentred coordinates: its distances may differ in the last bits
    return (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, rel=1e-9, abs=1e-12)


@settings(max_examples=150, deadline=None)
@given(clouds(), clouds(), st.sampled_from([1e6, 0.0]))
def test_point_metrics_equal_brute_force(t, s, offset):
    """Chamfer terms, precision, recall and F-score at 5 cm, 10 cm and LiDAR4D's 22.4 cm equal a
    double loop over all pairs, far from the origin too (UTM-sized coordinates)."""
    t, s = t + offset, s + offset
    taus = (0.05, 0.1, LIDAR4D_CODE_THRESHOLD)
    ref, _ = brute_point_metrics(t, s, taus)
    m = point_metrics(t, s, thresholds=taus)
    assert same(m.to_target, ref["to_target"]) and same(m.to_simulated, ref["to_simulated"])
    assert same(m.to_target_distance, ref["to_target_distance"])
    cd = math.inf if (len(t) == 0) != (len(s) == 0) else ref["to_target"] + ref["to_simulated"]
    assert same(m.chamfer_sum, cd) and same(m.chamfer_mean, 0.5 * cd)
    for tau in taus:
        f = m.fscore[tau]
        for got, want in zip((f["precision"], f["recall"], f["fscore"]), ref[tau]):
            assert same(got, want)
    if len(t) and len(s):  # equal to agreement (cell grid) where both exist
        a = agreement(t, s, 0.1)
        assert (a.coverage, a.precision) == (m.fscore[0.1]["recall"], m.fscore[0.1]["precision"])


@settings(max_examples=80, deadline=None)
@given(clouds(), clouds(), st.integers(1, 3), st.integers(0, 2**31))
def test_groups_partition_the_totals(t, s, k, seed):
    """Each group's figures are the brute-force figures of its target points and of the simulated
    points whose nearest target point is in it; the group sizes add up to the totals."""
    labels = np.random.default_rng(seed).integers(0, k, len(t))
    m = point_metrics(t, s, thresholds=(0.1,), groups={"g": labels})
    _, d = brute_point_metrics(t, s, ())
    assert sum(b["target_points"] for b in m.groups["g"].values()) == len(t)
    if len(t):
        assert sum(b["simulated_points"] for b in m.groups["g"].values()) == len(s)
    for lab, b in m.groups["g"].items():
        rows = labels == lab
        d_t = d[rows].min(axis=1) if len(s) else np.full(rows.sum(), np.inf)
        assert same(b["to_simulated"], float(np.mean(d_t ** 2)))
        assert same(b["fscore"][0.1]["recall"], float(np.mean(d_t < 0.1)))
        if len(s):
            # simulated points whose nearest target is in the group (distinct distances: no tie to break)
            mine = [j for j in range(len(s)) if labels[int(np.argmin(d[:, j]))] == lab]
            if len(np.unique(d.round(15))) == d.size:
                assert b["simulated_points"] == len(mine)
                if mine:
                    assert same(b["to_target"], float(np.mean(d[:, mine].min(axis=0) ** 2)))


def test_known_values_and_empty():
    t = np.array([[0.0, 0, 0], [1, 0, 0]])
    s = np.array([[0.0, 0, 0.03], [3, 0, 0]])
    m = point_metrics(t, s, thresholds=(0.05,))
    assert m.to_target == pytest.approx((0.03 ** 2 + 4) / 2)
    assert m.to_simulated == pytest.approx((0.03 ** 2 + 1 + 0.03 ** 2) / 2)  # (1, 0, 0) is nearest (0, 0, 0.03)
    assert m.fscore[0.05] == {"precision": 0.5, "recall": 0.5, "fscore": 0.5}
    e = point_metrics(t, np.empty((0, 3)))
    assert math.isinf(e.to_simulated) and math.isnan(e.to_target) and e.fscore[0.05]["recall"] == 0.0
    assert e.fscore[0.05]["fscore"] == 0.0 and math.isinf(e.chamfer_sum)
    z = point_metrics(np.empty((0, 3)), np.empty((0, 3)))
    assert math.isnan(z.chamfer_sum) and z.target_points == 0
    d, i = nearest(t, np.empty((0, 3)))
    assert np.all(np.isinf(d)) and np.all(i == 0)
    with pytest.raises(InputValueError):
        point_metrics(t, s, thresholds=(0.0,))
    with pytest.raises(InputValueError):
        point_metrics(t, s, groups={"g": [1, 2, 3]})
    assert set(m.to_dict()["fscore"]) == {"5cm"}


@settings(max_examples=100, deadline=None)
@given(clouds(), clouds(), st.sampled_from([0.05, 0.1, 0.3]))
def test_seen_from_is_strictly_within(t, p, tau):
    ref = np.array([any(math.dist(a, b) < tau for b in p) for a in t], dtype=bool)
    np.testing.assert_array_equal(seen_from(t, p, tau), ref)


def test_seen_from_far_apart_clouds_use_the_tree():
    """A cloud spanning more cells than the grid holds falls back to the kd-tree: same answer."""
    t = np.array([[0.0, 0, 0], [1e5, 0, 0], [2e5, 0, 0.2]])
    p = np.array([[0.0, 0, 0.05], [2e5, 0, 0]])
    assert seen_from(t, p, 0.01).tolist() == [False, False, False]
    assert seen_from(t, p, 0.1).tolist() == [True, False, False]
    assert seen_from(t, p, 0.21).tolist() == [True, False, True]


def images(max_side=6):
    val = st.one_of(st.just(math.nan), st.floats(0.5, 90, allow_nan=False))
    return st.integers(1, max_side).flatmap(lambda r: st.integers(1, max_side).flatmap(
        lambda c: st.tuples(st.lists(val, min_size=r * c, max_size=r * c), st.lists(val, min_size=r * c,
                                                                                      max_size=r * c)).map(
            lambda ab: (np.array(ab[0]).reshape(r, c), np.array(ab[1]).reshape(r, c)))))


def brute_image(real, sim):
    pairs = list(zip(real.ravel().tolist(), sim.ravel().tolist()))
    e = [b - a for a, b in pairs if not math.isnan(a) and not math.isnan(b)]
    agree = sum(math.isnan(a) == math.isnan(b) for a, b in pairs)
    rd = [p for p in pairs if math.isnan(p[0])]
    sd = [p for p in pairs if math.isnan(p[1])]
    both = sum(math.isnan(a) and math.isnan(b) for a, b in pairs)
    med = sorted(abs(x) for x in e)
    medae = math.nan if not e else (med[len(med) // 2] if len(med) % 2 else 0.5 * (med[len(med) // 2 - 1]
                                                                                  + med[len(med) // 2]))
    return {"rmse": math.sqrt(sum(x * x for x in e) / len(e)) if e else math.nan, "medae": medae,
            "accuracy": agree / len(pairs), "drop_recall": both / len(rd) if rd else math.nan,
            "drop_precision": both / len(sd) if sd else math.nan, "both_return": len(e)}


@settings(max_examples=150, deadline=None)
@given(images(), st.integers(0, 2**31))
def test_range_image_metrics_equal_brute_force(pair, seed):
    real, sim = pair
    ref = brute_image(real, sim)
    m = range_image_metrics(real, sim)
    for k, v in ref.items():
        assert same(getattr(m, k), v), k
    # split by row and by a random per-pulse label: each part is the brute force of its pulses
    lab = np.random.default_rng(seed).integers(0, 3, real.shape)
    g = range_image_metrics(real, sim, groups={"row": np.arange(real.shape[0]), "lab": lab}).groups
    for r in range(real.shape[0]):
        part = brute_image(real[r:r + 1], sim[r:r + 1])
        assert all(same(g["row"][r][k], v) for k, v in part.items())
    for u in np.unique(lab):
        part = brute_image(real[lab == u][None], sim[lab == u][None])
        assert all(same(g["lab"][int(u)][k], v) for k, v in part.items())
    assert sum(b["sse"] for b in g["lab"].values()) == pytest.approx(m.sse)


def test_range_image_inf_is_no_return_and_shapes_are_checked():
    real = np.array([[1.0, np.inf, np.nan]])
    sim = np.array([[1.5, np.nan, 2.0]])
    m = range_image_metrics(real, sim)
    assert (m.both_return, m.rmse, m.accuracy, m.drop_recall, m.drop_precision) == (1, 0.5, 2 / 3, 0.5, 1.0)
    with pytest.raises(InputValueError):
        range_image_metrics(real, sim[:, :2])
    with pytest.raises(InputValueError):
        range_image_metrics(real, sim, groups={"g": np.zeros(2)})


def test_range_bands():
    lab = range_bands([0.0, 9.99, 10.0, 85.0, np.nan, -1.0], edges=(0, 10, 80, np.inf))
    assert lab.tolist() == ["0-10 m", "0-10 m", "10-80 m", "80-inf m", "none", "none"]
    with pytest.raises(InputValueError):
        range_bands([1.0], edges=(0, 0))


@settings(max_examples=60, deadline=None)
@given(clouds(12).filter(len), st.floats(1e-300, 1e3), st.sampled_from([0.0, 4.5e5, 5.4e6, 1e7]))
def test_identical_clouds_score_perfectly_at_any_threshold(t, tau, offset):
    """A cloud against a copy of itself: Chamfer 0 and P = R = F = 1 at every threshold > 0, at UTM
    offsets too (a 1e-30 m threshold once overflowed the cell grid's cell count and scored 0)."""
    t = t + offset
    m = point_metrics(t, t.copy(), thresholds=(tau,))
    assert m.chamfer_sum == 0.0 and m.to_target_distance == 0.0
    assert m.fscore[tau] == {"precision": 1.0, "recall": 1.0, "fscore": 1.0}
    assert seen_from(t, t.copy(), tau).all()
    img = np.where(np.arange(12).reshape(3, 4) % 5 == 0, np.nan, np.arange(12.0).reshape(3, 4) + 1)
    r = range_image_metrics(img, img.copy())
    assert (r.rmse, r.medae, r.accuracy, r.drop_recall, r.drop_precision) == (0.0, 0.0, 1.0, 1.0, 1.0)


def test_thresholds_may_be_one_number_and_are_checked():
    t = np.array([[0.0, 0, 0], [1, 0, 0]])
    s = np.array([[0.0, 0, 0.03], [3, 0, 0]])
    assert point_metrics(t, s, thresholds=0.05).fscore == point_metrics(t, s, thresholds=(0.05,)).fscore
    for bad in ("0.05", ["a"], [None], (0.05, -1.0), (0.0,), (math.nan,), (math.inf,)):
        with pytest.raises(InputValueError, match="thresholds"):
            point_metrics(t, s, thresholds=bad)


def test_group_labels_nan_and_unsortable():
    """NaN labels form one group (not one per NaN, nor none: every point is counted once);
    labels numpy cannot order are refused by name."""
    t = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    m = point_metrics(t, t, groups={"g": np.array([np.nan, 1.0, np.nan])})
    assert sum(b["target_points"] for b in m.groups["g"].values()) == 3
    assert sum(b["simulated_points"] for b in m.groups["g"].values()) == 3
    assert len(m.groups["g"]) == 2
    r = range_image_metrics(np.ones((1, 3)), np.ones((1, 3)), groups={"g": np.array([[np.nan, 1.0, np.nan]])})
    assert sorted(b["pulses"] for b in r.groups["g"].values()) == [1, 2]
    with pytest.raises(InputValueError, match="groups"):
        point_metrics(t, t, groups={"g": np.array(["a", None, "b"], dtype=object)})


def test_range_images_refuse_non_positive_ranges_and_non_numbers():
    """0 is 'no return' in LiDAR-NeRF's panoramas: read as a range it would score 0 m returns;
    a negative range is garbage. Both are refused (NaN or inf is 'no return' here)."""
    ok = np.array([[1.0, np.nan]])
    for bad in (np.array([[0.0, np.nan]]), np.array([[-1.0, 2.0]])):
        with pytest.raises(InputValueError, match="NaN"):
            range_image_metrics(bad, ok)
        with pytest.raises(InputValueError, match="NaN"):
            range_image_metrics(ok, bad)
    with pytest.raises(InputValueError):
        range_image_metrics(np.array([["a", "b"]]), ok)


def test_one_empty_side_scores_zero_f_and_infinite_chamfer():
    """An empty simulation against a real scan recovered nothing: F = 0 and CD = inf (as
    LiDAR-NeRF's and LiDAR4D's fscore turn their 0/0 into 0), precision undefined (nan); the
    reverse alike; both empty: nothing to compare, all nan."""
    t = np.array([[0.0, 0, 0], [1, 0, 0]])
    e = np.empty((0, 3))
    for m, side in ((point_metrics(t, e), "precision"), (point_metrics(e, t), "recall")):
        f = m.fscore[0.05]
        assert f["fscore"] == 0.0 and math.isnan(f[side])
        assert math.isinf(m.chamfer_sum) and math.isinf(m.chamfer_mean)
    z = point_metrics(e, e)
    assert math.isnan(z.chamfer_sum) and math.isnan(z.fscore[0.05]["fscore"])
    g = point_metrics(t, e, groups={"g": np.array([0, 1])}).groups["g"]
    assert all(b["fscore"][0.05]["fscore"] == 0.0 for b in g.values())
