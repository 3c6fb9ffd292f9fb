"""The embree backend's inputs checked before any work (issue #40): per-point arrays of another
length or of no direction, and casts that would run for hours."""

import warnings

import numpy as np
import pytest

from slr_ray import InputValueError, prepare
from slr_ray.cli import main
from slr_ray.io import PointCloud, write_cloud

P = np.random.default_rng(0).uniform(-5, 5, (300, 3))


@pytest.mark.parametrize("options, says", [
    ({"normals": np.zeros((300, 3))}, "zero length"),  # every disc edge-on to nothing: empty scans, silently
    ({"normals": np.r_[np.ones((299, 3)), [[0.0, 0, 0]]]}, "1 of 300 rows"),
    ({"normals": np.full((300, 3), np.nan)}, "NaN"),
    ({"normals": np.ones((299, 3))}, "299 rows for 300 points"),
    ({"radius": np.full(299, 0.1)}, "radius has 299 values for 300 points"),  # was numpy's broadcast error
    ({"radius": np.full(301, 0.1)}, "radius has 301 values"),
    ({"radius": np.r_[np.full(299, 0.1), 0.0]}, "finite and > 0"),
    ({"radius": np.full((300, 1), 0.1)}, "one number a point"),
    ({"radius": True}, "boolean"),
    ({"radius_scale": 1e300}, "at most"),  # float32 radii overflowed with numpy's warning
    ({"min_radius": 1e300}, "at most"),
    ({"radius": np.full(300, 1e300)}, "at most"),
    ({"n_threads": -5}, "n_threads"),  # was ignored
])
def test_prepare_refuses_per_point_arrays_that_do_not_fit(options, says):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputValueError, match=says):
            prepare(P, "embree", **options)


def test_an_embree_cast_that_would_take_hours_is_refused_before_it_starts(tmp_path, capsys):
    with pytest.raises(InputValueError, match="hours"):
        prepare(P, "embree").scan([0.0, 0, 0], 0.00001)
    src = tmp_path / "c.npz"
    write_cloud(src, PointCloud(P, {}, np.zeros(3)))
    out = tmp_path / "o.npz"
    assert main(["scan", str(src), "-o", str(out), "--backend", "embree", "--resolution", "0.00001"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "6.48e+14 rays" in err and "hours" in err and not out.exists()
    assert main(["scan", str(src), "-o", str(out), "--backend", "binning", "--resolution", "0.00001"]) == 0
