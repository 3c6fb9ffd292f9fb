"""The benchmarks find the real data from any checkout (benchmarks/common.py's data_dir): a git worktree
(/work/wt/NAME) lies a level further from shared/data than the main checkout; bench_effects.py and
bench_self_view.py looked one fixed number of levels up and missed it there. The tests find it by the same
rule (conftest.py's shared_data): several looked a fixed number of levels up and skipped in worktrees."""

import importlib.util
from pathlib import Path

import pytest

import conftest

ROOT = Path(__file__).resolve().parents[1]


def _module(name):
    spec = importlib.util.spec_from_file_location(f"_bench_{name}", ROOT / "benchmarks" / f"{name}.py")
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


@pytest.mark.parametrize("rule", ["benchmarks", "tests"])
def test_data_dir_walks_up_from_a_worktree_and_takes_the_environment_first(tmp_path, monkeypatch, rule):
    data_dir = _module("common").data_dir if rule == "benchmarks" else conftest.shared_data
    (tmp_path / "shared" / "data").mkdir(parents=True)
    worktree = tmp_path / "wt" / "branch"
    worktree.mkdir(parents=True)
    monkeypatch.delenv("SLR_RAY_DATA", raising=False)
    assert data_dir(worktree) == tmp_path / "shared" / "data"
    assert data_dir(tmp_path / "main") == tmp_path / "shared" / "data"
    monkeypatch.setenv("SLR_RAY_DATA", str(tmp_path / "elsewhere"))
    assert data_dir(worktree) == tmp_path / "elsewhere"


def test_no_test_file_finds_the_data_by_its_own_path():
    """Every test reads the real data through conftest.DATA (one rule, right in a worktree too)."""
    own = [p.name for p in sorted((ROOT / "tests").glob("test_*.py")) if p.name != Path(__file__).name
           and ('"shared" / "data"' in p.read_text() or "/work/shared" in p.read_text())]
    assert own == []


def test_both_benchmarks_take_data(tmp_path, monkeypatch, capsys):
    """--data names the directory; absent data is said naming the file, not a traceback."""
    monkeypatch.setenv("SLR_RAY_DATA", str(tmp_path))
    effects = _module("bench_effects")
    with pytest.raises(SystemExit, match="kitti_hdl64_000000.bin is absent"):
        effects.main(["--data", str(tmp_path / "none")])
    view = _module("bench_self_view")
    assert view.DATA == tmp_path
