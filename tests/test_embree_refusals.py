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


def test_a_primary_origin_far_outside_the_cloud_is_refused_before_its_discs_are_cast(tmp_path, capsys):
    """#48: seen from 1 km, 8,000 points of a 40 m patch fell in 12 pulses of 0.2 deg; their discs, sized
    from those pulses, were 40-80 m wide and a scan took minutes (100,000 points: more than five). The
    primary holds about one point a pulse: a cloud crowding its pulses is no scan from there."""
    from slr_ray.backends.embree.pulsegrid import MAX_POINTS_PER_PULSE

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-20, 20, 8000), rng.uniform(-20, 20, 8000), rng.normal(-1.5, 0.02, 8000)])
    for far in ([1000.0, 0, 0], [0, 300.0, 50.0]):
        with pytest.raises(InputValueError, match=r"^primary_origin \(.*\): the cloud is no scan from there .* "
                                                  r"fall in \d+ pulses, \d+ a pulse"):
            prepare(pts, "embree", primary_origin=far, primary_resolution=0.2)
    near = prepare(pts, "embree", primary_origin=[0.0, 0, 0], primary_resolution=0.2)  # its own scanner: kept
    assert near.options.neighbours == "pulse-grid" and float(np.max(near.radii)) < 10
    assert MAX_POINTS_PER_PULSE <= 8
    src = tmp_path / "patch.npz"
    write_cloud(src, PointCloud(pts))
    out = tmp_path / "o.npz"
    assert main(["scan", str(src), "-o", str(out), "--backend", "embree", "--origin", "0", "0", "0",
                 "--primary-origin", "1000", "0", "0", "--primary-resolution", "0.2", "--resolution", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("slr-ray: error: --primary-origin (1000, 0, 0): the cloud is no scan") and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize("more", [{"orientation": "primary"}, {"neighbours": "knn"}])
def test_footprint_discs_from_a_primary_origin_far_outside_the_cloud_are_refused(more):
    """#48: the refusal above covered the pulse-grid path only; radius='footprint' without the grid
    (discs facing the primary, or kNN normals) sized 8,000 points' discs from 1 km: tan(0.2 deg) x 1 km,
    3.5 m each, every one under hundreds of others. The same crowding check refuses it; from the
    cloud's own scanner the footprint discs stay within the pulse's width at the farthest point."""
    import math

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-20, 20, 8000), rng.uniform(-20, 20, 8000), rng.normal(-1.5, 0.02, 8000)])
    for far in ([1000.0, 0, 0], [0, 300.0, 50.0]):
        with pytest.raises(InputValueError, match=r"^primary_origin \(.*\): the cloud is no scan from there"):
            prepare(pts, "embree", radius="footprint", primary_origin=far, primary_resolution=0.2, **more)
    near = prepare(pts, "embree", radius="footprint", primary_origin=[0.0, 0, 0], primary_resolution=0.2, **more)
    reach = float(np.max(np.linalg.norm(pts, axis=1)))
    assert float(np.max(near.radii)) <= reach * math.tan(math.radians(0.2)) * (1 + 1e-6)


def test_k_is_bounded_before_any_work_and_a_neighbour_chunk_within_its_memory_cap(monkeypatch, tmp_path, capsys):
    """#48: `--k 1000000` allocated 74 GiB before refusing. k is refused above MAX_K from the options
    alone, and the kd-tree's answers are taken a chunk at a time: distances and indices of at most
    ``_NEIGHBOUR_BYTES`` (1 GiB), whatever k and the cloud's size (here 8 MiB against 160 MB whole)."""
    import tracemalloc

    from slr_ray.backends.embree import discs
    from slr_ray.backends.embree.options import MAX_K

    src = tmp_path / "c.npz"
    write_cloud(src, PointCloud(P, {}, np.zeros(3)))
    for k in (1_000_000, MAX_K + 1, 0):
        assert main(["scan", str(src), "-o", str(tmp_path / "o.npz"), "--backend", "embree", "--resolution", "1",
                     "--k", str(k)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"[1, {MAX_K}]" in err
    cap = 8 << 20
    monkeypatch.setattr(discs, "_NEIGHBOUR_BYTES", cap)
    pts = np.random.default_rng(1).uniform(-10, 10, (20_000, 3))
    k = 500
    assert len(pts) * (k + 1) * 16 > 16 * cap  # the whole answer: 160 MB
    tracemalloc.start()
    try:
        seen = 0
        for s, d, i in discs.neighbourhoods(pts, k):
            assert d.shape[1] == k and d.base.nbytes + i.base.nbytes <= cap
            seen += len(d)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert seen == len(pts) and peak < 3 * cap, peak
    # at the largest k, the planned chunk on the default cap: its arrays within 1 GiB
    monkeypatch.undo()
    chunk = max(1, min(1 << 20, discs._NEIGHBOUR_BYTES // (16 * (MAX_K + 1))))
    assert chunk * (MAX_K + 1) * 16 <= 1 << 30


def test_a_disc_radius_of_zero_says_it_must_be_above_zero(tmp_path, capsys):
    """#48: `--radius 0` read "radius must be a number, an array or one of ('spacing', 'footprint')"."""
    src = tmp_path / "c.npz"
    write_cloud(src, PointCloud(P, {}, np.zeros(3)))
    for bad in ("0", "-1", "nan", "inf"):
        assert main(["scan", str(src), "-o", str(tmp_path / "o.npz"), "--backend", "embree", "--resolution", "1",
                     "--radius", bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--radius: a disc radius must be a finite number of metres > 0" in err
        assert f"got {bad!r}" in err and "must be a number" not in err
    assert main(["scan", str(src), "-o", str(tmp_path / "o.npz"), "--backend", "embree", "--resolution", "1",
                 "--radius", "sizes"]) == 2
    assert "one of ('spacing', 'footprint'), got 'sizes'" in capsys.readouterr().err  # a mode's name: its own message
