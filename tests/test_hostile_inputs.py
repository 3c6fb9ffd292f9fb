"""Inputs that lied or were out of bounds (issue #48: items 9 and 16, and the crashes and hangs):
each refused with one line naming what is wrong, or read from what the file really holds."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from slr_ray.cli import main
from slr_ray.io import PointCloud, read_cloud, write_cloud


def _patch_header(path, offset, value):
    """Overwrite one double of a LAS 1.2 header in place (a test's own file)."""
    with open(path, "r+b") as f:
        f.seek(offset)
        f.write(struct.pack("<d", value))


# LAS 1.x public header: x, y, z scale at 131, 139, 147; max x 179, min x 187, max y 195, ...
_X_SCALE, _MAX_X = 131, 179


@pytest.fixture
def las(tmp_path):
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-5, 5, (4000, 2)), rng.uniform(-1, 1, 4000)]) + [1000.0, 2000.0, 50.0]
    path = tmp_path / "c.las"
    write_cloud(path, PointCloud(pts))
    return path, pts


@pytest.mark.parametrize("how", ["read", "streamed"])
def test_a_las_x_scale_of_zero_is_refused_with_one_line(las, tmp_path, capsys, how):
    path, _ = las
    _patch_header(path, _X_SCALE, 0.0)
    if how == "read":
        with pytest.raises(Exception, match="x scale 0.0"):
            read_cloud(path)
    args = ["scan", str(path), "--origin-relative", "centre", "--resolution", "2", "--quiet", "-o",
            str(tmp_path / "o.las")]
    assert main(args if how == "streamed" else args + ["--backend", "embree"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "x scale 0.0" in err and str(path) in err
    assert not (tmp_path / "o.las").exists()


def test_lying_las_bounds_do_not_move_the_centre_origin(las, tmp_path, capsys):
    path, pts = las
    _patch_header(path, _MAX_X, 2005.0)  # the header says x reaches 2,005 (the points: 1,005): centre +500 m
    assert main(["scan", str(path), "--origin-relative", "centre", "--resolution", "2", "--quiet",
                 "-o", str(tmp_path / "o.las")]) == 0
    out = capsys.readouterr()
    res = json.loads(out.out)
    centre = (pts.min(0) + pts.max(0)) / 2
    np.testing.assert_allclose(res["origin"], centre, atol=1e-3)
    assert res["points_out"] > 100
    assert "the LAS header's bounds" in out.err and "the points' are used" in out.err


def test_lying_las_bounds_do_not_fool_the_origin_range_check(las, tmp_path, capsys):
    path, _ = las
    _patch_header(path, _MAX_X, 5000.0)  # the header's box reaches the origin below; the points lie 2 km away
    assert main(["scan", str(path), "--origin", "3000", "2000", "50", "--max-range", "100", "--resolution", "2",
                 "--quiet", "-o", str(tmp_path / "o.las")]) == 2
    err = capsys.readouterr().err
    assert "beyond the pattern's max range (100 m)" in err and "x 995.0 to 1,005.0" in err
    assert not (tmp_path / "o.las").exists()
