"""The benchmarks find the real data from any checkout (benchmarks/common.py's data_dir): a git worktree
(/work/wt/NAME) lies a level further from shared/data than the main checkout; bench_effects.py and
bench_self_view.py looked one fixed number of levels up and missed it there."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _module(name):
    spec = importlib.util.spec_from_file_location(f"_bench_{name}", ROOT / "benchmarks" / f"{name}.py")
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


def test_data_dir_walks_up_from_a_worktree_and_takes_the_environment_first(tmp_path, monkeypatch):
    common = _module("common")
    (tmp_path / "shared" / "data").mkdir(parents=True)
    worktree = tmp_path / "wt" / "branch"
    worktree.mkdir(parents=True)
    monkeypatch.delenv("SLR_RAY_DATA", raising=False)
    assert common.data_dir(worktree) == tmp_path / "shared" / "data"
    assert common.data_dir(tmp_path / "main") == tmp_path / "shared" / "data"
    monkeypatch.setenv("SLR_RAY_DATA", str(tmp_path / "elsewhere"))
    assert common.data_dir(worktree) == tmp_path / "elsewhere"


def test_both_benchmarks_take_data(tmp_path, monkeypatch, capsys):
    """--data names the directory; absent data is said naming the file, not a traceback."""
    import pytest

    monkeypatch.setenv("SLR_RAY_DATA", str(tmp_path))
    effects = _module("bench_effects")
    with pytest.raises(SystemExit, match="kitti_hdl64_000000.bin is absent"):
        effects.main(["--data", str(tmp_path / "none")])
    view = _module("bench_self_view")
    assert view.DATA == tmp_path
