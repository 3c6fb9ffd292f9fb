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
    with pytest.raises(MissingDependencyError, match=r'pip install "slr_ray\[csf\]"'):
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
    with pytest.raises(MissingDependencyError, match=r"slr_ray\[open3d\]"):
        prepare(np.random.default_rng(0).normal(size=(50, 3)), "embree", engine="open3d", radius=0.1)
