import csv
import json

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
