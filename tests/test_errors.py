"""Optional features fail on use, with the command that installs what they need."""

import sys

import numpy as np
import pytest

from slr_ray.errors import MissingDependencyError


@pytest.fixture
def without(monkeypatch):
    def hide(*names):
        for n in names:
            monkeypatch.setitem(sys.modules, n, None)  # "import n" now raises ImportError
    return hide


def test_e57_without_pye57(without, tmp_path):
    from slr_ray.io import PointCloud, write_cloud

    without("pye57")
    with pytest.raises(MissingDependencyError, match=r'pip install "slr_ray\[e57\]"'):
        write_cloud(tmp_path / "a.e57", PointCloud(np.zeros((2, 3))))
    assert not (tmp_path / "a.e57").exists()


def test_csf_without_its_package(without):
    from slr_ray.positions import label_ground

    without("CSF")
    with pytest.raises(MissingDependencyError, match=r"needs cloth-simulation-filter: pip install cloth-simulation-filter$"):
        label_ground(np.zeros((10, 3)))


def test_scheduler_without_dask(without, tmp_path):
    from slr_ray.augment import AugmentConfig, augment

    without("dask", "dask.distributed")
    with pytest.raises(MissingDependencyError, match=r'pip install "slr_ray\[dask\]"'):
        augment(tmp_path / "in.npz", tmp_path / "out", AugmentConfig(n=1, scheduler="tcp://127.0.0.1:1"))
    assert not (tmp_path / "out").exists()


def test_open3d_engine_without_open3d(without):
    from slr_ray.backends import prepare

    without("open3d")
    with pytest.raises(MissingDependencyError, match=r"needs open3d: pip install open3d \(and its system library"):
        prepare(np.random.default_rng(0).normal(size=(50, 3)), "embree", engine="open3d", radius=0.1)


def test_registration_without_open3d(without):
    from slr_ray.evaluate import register

    without("open3d")
    with pytest.raises(MissingDependencyError, match=r"^registration needs open3d: pip install open3d \("):
        register(np.zeros((10, 3)), np.zeros((10, 3)))


def test_the_design_cards_packages_are_core_dependencies():
    """open3d (evaluate's registration) and CSF (ground when a cloud has none) come with
    the README's `pip install -e .`; extras are for what is truly optional, and
    `test` and `all` still name only extras that exist."""
    import re
    from pathlib import Path

    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    core = {re.split(r"[<>=\[ ]", d)[0] for d in project["dependencies"]}
    assert {"open3d", "cloth-simulation-filter"} <= core
    extras = project["optional-dependencies"]
    assert set(extras) >= {"dask", "e57", "all", "test"} and not {"open3d", "csf"} & set(extras)
    named = {e for deps in (extras["all"], extras["test"]) for d in deps
             for e in re.findall(r"slr_ray\[([\w,]+)\]", d) for e in e.split(",")}
    assert named <= set(extras)
