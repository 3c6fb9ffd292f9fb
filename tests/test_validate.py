import csv
import json

import numpy as np
import pytest

from slr_ray import InputValueError
from slr_ray.cli import main
from slr_ray.validate import load_config, plot_validation, run_validation


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    cfg = load_config("quick")
    cfg.positions = 2
    cfg.backends = ["binning"]
    out = tmp_path_factory.mktemp("val")
    res = run_validation(cfg, out, progress=False)
    return cfg, out, res


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_quick_validation_writes_rows(quick):
    cfg, out, res = quick
    rows = _rows(out / "results.csv")
    assert len(rows) == res["rows"] == 2 * len(cfg.truths)
    for r in rows:
        assert 0 <= float(r["similarity"]) <= 1 and int(r["true_points"]) > 0
    assert set(res["headline"]) == {"binning/center", "binning/nearest"}


def test_resume_adds_only_missing_rows_and_same_seed_same_numbers(quick, tmp_path):
    cfg, out, _ = quick
    before = _rows(out / "results.csv")
    again = run_validation(cfg, out, progress=False)  # everything done: nothing new
    assert again["new_rows"] == 0 and _rows(out / "results.csv") == before
    cfg.positions = 3
    more = run_validation(cfg, out, progress=False)
    assert more["new_rows"] == len(cfg.truths)
    rows = _rows(out / "results.csv")
    assert rows[: len(before)] == before
    # a fresh run of the same config gives the same numbers
    fresh = run_validation(cfg, tmp_path / "fresh", progress=False)
    assert fresh["rows"] == len(rows)
    key = lambda r: (r["position"], r["truth"])  # noqa: E731
    a = {key(r): r["similarity"] for r in rows}
    b = {key(r): r["similarity"] for r in _rows(tmp_path / "fresh" / "results.csv")}
    assert a == b
    cfg.positions = 2


def test_figure(quick, tmp_path):
    _, out, _ = quick
    plot_validation(out / "results.csv", tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 5000


def test_configs_and_cli(tmp_path, capsys):
    for name in ("quick", "distance", "occlusion", "resolution"):
        assert load_config(name).positions >= 1
    assert main(["validate", "distance", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert cfg["scenes"][0] == "distance-1" and cfg["primary_resolutions"] == [0.0144]
    bad = tmp_path / "bad.toml"
    bad.write_text("[validate]\nbackends = ['magic']\n")
    with pytest.raises(InputValueError, match="magic"):
        load_config(bad)
    assert main(["validate", str(tmp_path / "missing.toml")]) == 2


@pytest.fixture(scope="module")
def two_primaries(tmp_path_factory):
    """One scene, two primaries; the nearest truth at every other position."""
    cfg = load_config("quick")
    cfg.scenes = [{"scene": "rect-0500", "primary_resolutions": [0.2, 0.1]}]
    cfg.positions = 3
    cfg.backends = ["binning"]
    cfg.nearest_every = 2
    out = tmp_path_factory.mktemp("two")
    run_validation(cfg, out, progress=False)
    return cfg, out


def test_primaries_of_a_scene_share_positions_and_true_scans(two_primaries):
    cfg, out = two_primaries
    rows = _rows(out / "results.csv")
    by = {}
    for r in rows:
        by.setdefault((r["position"], r["truth"]), {})[float(r["primary_resolution"])] = r
    assert {k for k, _ in by} == {"0", "1", "2"}
    # the nearest truth only at positions 0, 2; centre truth everywhere
    assert sorted(k for k in by if k[1] == "nearest") == [("0", "nearest"), ("2", "nearest")]
    for pair in by.values():
        a, b = pair[0.2], pair[0.1]
        assert (a["x"], a["y"], a["z"]) == (b["x"], b["y"], b["z"])  # drawn once, on the 0.2 primary
        assert a["true_points"] == b["true_points"]  # the same true scan
        assert a["slr_points"] != b["slr_points"]  # from different primaries
    pos = np.loadtxt(out / "positions" / "rect-0500.csv", delimiter=",", ndmin=2)
    assert pos.shape == (3, 3) and float(by[("1", "center")][0.1]["x"]) == pytest.approx(pos[1, 0])
    stages = _rows(out / "stages.csv")
    assert [s["stage"] for s in stages] == ["primary scan", "positions", "pairs", "primary scan", "pairs"]
    assert all(float(s["peak_rss_gib"]) > 0 for s in stages)


def test_resume_reads_positions_and_skips_their_primary(two_primaries, tmp_path):
    import shutil

    cfg, out = two_primaries
    shutil.copytree(out, tmp_path / "r")
    rows = _rows(tmp_path / "r" / "results.csv")
    kept = [r for r in rows if float(r["primary_resolution"]) == 0.2]
    with open(tmp_path / "r" / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, list(rows[0]))
        w.writeheader()
        w.writerows(kept)
    res = run_validation(cfg, tmp_path / "r", progress=False)
    assert res["new_rows"] == len(rows) - len(kept)
    new_stages = _rows(tmp_path / "r" / "stages.csv")[5:]
    assert [(s["stage"], float(s["primary_resolution"])) for s in new_stages] == [("primary scan", 0.1),
                                                                                   ("pairs", 0.1)]
    key = lambda r: (r["primary_resolution"], r["position"], r["truth"])  # noqa: E731
    assert {key(r): r["similarity"] for r in rows} == \
        {key(r): r["similarity"] for r in _rows(tmp_path / "r" / "results.csv")}


def test_positions_resolution_outside_the_rows(two_primaries, tmp_path):
    cfg, out = two_primaries
    cfg2 = load_config("quick")
    cfg2.scenes = [{"scene": "rect-0500", "primary_resolutions": [0.1]}]
    cfg2.positions_resolution = 0.2
    cfg2.positions, cfg2.backends, cfg2.truths = 3, ["binning"], ["center"]
    run_validation(cfg2, tmp_path, progress=False)
    rows = _rows(tmp_path / "results.csv")
    assert {float(r["primary_resolution"]) for r in rows} == {0.1}
    np.testing.assert_array_equal(np.loadtxt(tmp_path / "positions" / "rect-0500.csv", delimiter=","),
                                  np.loadtxt(out / "positions" / "rect-0500.csv", delimiter=","))
    ref = {r["position"]: r["similarity"] for r in _rows(out / "results.csv")
           if float(r["primary_resolution"]) == 0.1 and r["truth"] == "center"}
    assert {r["position"]: r["similarity"] for r in rows} == ref


def test_wanted_rows_and_bad_entries():
    cfg = load_config("quick")
    cfg.backends, cfg.truths = ["binning", "embree"], ["center", "nearest"]
    cfg.nearest_every, cfg.embree_every, cfg.embree_primary_resolutions = 3, 2, [0.0144]
    assert cfg.wanted(0.0144, 0) == [("binning", "center"), ("binning", "nearest"),
                                     ("embree", "center"), ("embree", "nearest")]
    assert cfg.wanted(0.0144, 2) == [("binning", "center"), ("embree", "center")]
    assert cfg.wanted(0.0144, 3) == [("binning", "center"), ("binning", "nearest")]
    assert cfg.wanted(0.00576, 0) == [("binning", "center"), ("binning", "nearest")]
    for bad, msg in (([{"scene": "rect-0500", "resolution": [1]}], "scenes entry"), ([3], "scenes entry"),
                     ([{"scene": "rect-0500", "primary_resolutions": [-1]}], "positive"),
                     ([{"scene": "rect-0500", "primary_resolutions": ["x"]}], "numbers")):
        cfg.scenes = bad
        with pytest.raises(InputValueError, match=msg):
            cfg.check()
    cfg.scenes, cfg.nearest_every = ["rect-0500"], 0
    with pytest.raises(InputValueError, match="nearest_every"):
        cfg.check()
