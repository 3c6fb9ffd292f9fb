"""The embree backend: discs in an Embree BVH, one ray per pulse centre."""

import numpy as np
import pytest

from slr_ray import InputValueError, ScanPattern, pulse_directions, simulate_scan
from slr_ray.backends.embree import DiscScene, disc_radii, estimate_normals


def plane_grid(x=5.0, half=3.0, step=0.02, offset=(0, 0, 0)):
    g = np.mgrid[-half:half:step, -half:half:step].reshape(2, -1).T
    return np.column_stack([np.full(len(g), x), g]) + np.asarray(offset)


def two_walls(step=0.02):
    front = plane_grid(5.0, 1.0, step)
    back = plane_grid(10.0, 4.0, step)
    return np.vstack([front, back]), len(front)


@pytest.mark.parametrize("orientation", ["billboard", "normal"])
def test_wall_in_front_of_wall_hides_the_back_wall(orientation):
    pts, n_front = two_walls()
    scan = simulate_scan(pts, [0, 0, 0], ScanPattern(0.5), backend="embree", orientation=orientation)
    back = pts[scan.indices[scan.indices >= n_front]]
    # the front wall (|y|, |z| < 1 at x = 5) covers |y|, |z| < 2 at x = 10
    hidden = (np.abs(back[:, 1]) < 1.9) & (np.abs(back[:, 2]) < 1.9)
    assert not hidden.any()
    assert (scan.indices < n_front).sum() > 100


def test_binning_sees_through_where_embree_does_not():
    # a sparse front wall: binning returns back-wall points through its gaps
    front = plane_grid(5.0, 1.0, 0.05)
    back = plane_grid(10.0, 4.0, 0.01)
    pts = np.vstack([front, back])
    p = ScanPattern(0.2)
    b = simulate_scan(pts, [0, 0, 0], p)
    e = simulate_scan(pts, [0, 0, 0], p, backend="embree", orientation="normal")
    behind = lambda s: ((s.indices >= len(front)) & (np.abs(pts[s.indices, 1]) < 1.8)  # noqa: E731
                        & (np.abs(pts[s.indices, 2]) < 1.8)).sum()
    assert behind(b) > 100 and behind(e) == 0


def test_one_point_per_pulse_both_backends_agree():
    # a point at every pulse centre on a plane: each pulse's ray hits its own point's disc
    p = ScanPattern(0.5, zenith_range=(70, 110))
    nv, nh = p.shape
    v, h = np.meshgrid(np.arange(nv), np.arange(nh), indexing="ij")
    pulses = np.column_stack([v.ravel(), h.ravel()])
    d = pulse_directions(pulses, p)
    d = d[np.abs(d[:, 0]) > 0.9]
    d = d[d[:, 0] > 0]
    pts = d * (5.0 / d[:, [0]])  # on the plane x = 5
    b = simulate_scan(pts, [0, 0, 0], p)
    e = simulate_scan(pts, [0, 0, 0], p, backend="embree", radius=0.02, orientation="billboard")
    assert len(b) == len(pts)
    np.testing.assert_array_equal(e.indices, b.indices)
    np.testing.assert_array_equal(e.pulses, b.pulses)


def test_dense_flat_grid_head_on_agreement_is_quantified():
    pts = plane_grid(5.0, 2.0, 0.01)
    p = ScanPattern(0.5)
    b = simulate_scan(pts, [0, 0, 0], p)
    e = simulate_scan(pts, [0, 0, 0], p, backend="embree", orientation="normal")
    # same pulses covered; the point chosen differs (nearest in pulse vs on the centre ray),
    # but embree's point always lies in the ray's own pulse or a neighbour
    bk = set(map(tuple, b.pulses.tolist()))
    ek = set(map(tuple, e.pulses.tolist()))
    assert len(ek ^ bk) <= 0.02 * len(bk)
    own = np.array([tuple(x) for x in b.pulses.tolist()])
    from slr_ray import pulse_bins
    v, h, _, _ = pulse_bins(pts[e.indices], [0, 0, 0], p)
    assert np.all(np.abs(v - e.pulses[:, 0]) <= 1) and np.all(np.abs(h - e.pulses[:, 1]) <= 1)
    assert len(own) > 100


@pytest.mark.parametrize("segments", [3, 4, 5, 6, 7])
def test_no_ray_leaks_through_a_dense_grid(segments):
    pts = plane_grid(5.0, 3.0, 0.03)
    p = ScanPattern(0.25, zenith_range=(70, 110))
    scene = DiscScene(pts, radius="spacing", orientation="normal", segments=segments)
    pulses_hit, _, _ = scene.ray_hits([0, 0, 0], p)
    hit = set(map(tuple, pulses_hit.tolist()))
    nv, nh = p.shape
    v, h = np.meshgrid(np.arange(nv), np.arange(nh), indexing="ij")
    pulses = np.column_stack([v.ravel(), h.ravel()])
    d = pulse_directions(pulses, p)
    ok = d[:, 0] > 0
    at = d[ok] * (5.0 / d[ok][:, [0]])
    inside = (np.abs(at[:, 1]) < 2.8) & (np.abs(at[:, 2]) < 2.8)
    should = {tuple(x) for x in pulses[ok][inside].tolist()}
    assert should <= hit


@pytest.mark.parametrize("orientation", ["normal", "billboard"])
def test_far_from_the_origin_gives_the_same_hits(orientation):
    pts, _ = two_walls(0.04)
    shift = np.array([5e6, 5e6, 100.0])
    p = ScanPattern(0.5)
    a = DiscScene(pts, orientation=orientation).ray_hits([0, 0, 0], p)
    b = DiscScene(pts + shift, orientation=orientation).ray_hits(shift, p)
    np.testing.assert_array_equal(a[0], b[0])  # the same pulses hit
    np.testing.assert_allclose(a[2], b[2], atol=1e-4)  # at the same distances
    if orientation == "billboard":  # no coplanar overlaps: the same points too
        assert (a[1] == b[1]).mean() > 0.999


def test_no_self_hit_when_the_origin_is_on_a_disc():
    pts = plane_grid(0.0, 2.0, 0.02)  # the plane x = 0 through the origin
    pts = np.vstack([pts, plane_grid(5.0, 2.0, 0.02)])
    for orientation in ("normal", "billboard"):
        scan = simulate_scan(pts, pts[5000], ScanPattern(1.0), backend="embree", orientation=orientation)
        far = pts[scan.indices, 0] > 4
        assert far.sum() > 50  # the rays get past the disc they start on


def test_same_input_same_result_and_scene_reuse():
    pts, _ = two_walls(0.04)
    p = ScanPattern(0.5)
    scene = DiscScene(pts, orientation="normal")
    a = scene.scan([0, 0, 0], p)
    b = scene.scan([0, 0, 0], p)
    np.testing.assert_array_equal(a.indices, b.indices)
    assert a.info["build_seconds"] == 0 and b.info["cast_seconds"] > 0
    c = simulate_scan(pts, [0, 0, 0], p, backend="embree", orientation="normal")
    np.testing.assert_array_equal(a.indices, c.indices)


def test_range_and_field_of_view_limits_apply():
    pts, n_front = two_walls(0.04)
    p = ScanPattern(0.5, max_range=8)
    scan = simulate_scan(pts, [0, 0, 0], p, backend="embree")
    assert len(scan) and np.all(scan.indices < n_front) and np.all(scan.ranges <= 8)


def test_radii_options():
    pts = plane_grid(5.0, 1.0, 0.02)
    r = disc_radii(pts, "spacing", k=4)
    assert 0.015 < np.median(r) < 0.03
    f = disc_radii(pts, "footprint", primary_origin=[0, 0, 0], primary_resolution=0.1)
    np.testing.assert_allclose(f, np.linalg.norm(pts, axis=1) * np.tan(np.radians(0.1)))
    np.testing.assert_allclose(disc_radii(pts, 0.05, radius_scale=2), 0.1)
    with pytest.raises(InputValueError):
        disc_radii(pts, "footprint")
    with pytest.raises(InputValueError):
        disc_radii(pts, "big")
    with pytest.raises(InputValueError):
        disc_radii(pts, -1.0)
    n = estimate_normals(pts)
    np.testing.assert_allclose(np.abs(n[:, 0]), 1, atol=1e-6)


def test_bad_options_and_empty_input():
    pts = plane_grid(5.0, 0.5, 0.1)
    with pytest.raises(InputValueError, match="orientation"):
        DiscScene(pts, orientation="sideways")
    with pytest.raises(InputValueError, match="segments"):
        DiscScene(pts, segments=2)
    empty = simulate_scan(np.empty((0, 3)), [0, 0, 0], 1.0, backend="embree", radius=0.1)
    assert len(empty) == 0 and empty.pulses.shape == (0, 2)


def test_compare_backends_reports_see_through_and_bands(tmp_path):
    from slr_ray.compare import compare_backends, plot_comparison

    front = plane_grid(5.0, 1.0, 0.05)
    back = plane_grid(10.0, 4.0, 0.01)
    pts = np.vstack([front, back])
    res = compare_backends(pts, [[0, 0, 0], [0, 0.5, 0]], ScanPattern(0.2), tolerance=0.1,
                           embree_options={"orientation": "normal"})
    assert len(res["positions"]) == 2
    pos = res["positions"][0]
    assert pos["see_through"] > 100 and 0 < pos["jaccard"] < 1
    bands = {tuple(b["band_m"]): b for b in pos["bands"]}
    assert bands[(5.0, 10.0)]["see_through"] == 0  # the front wall itself is never behind anything
    assert bands[(10.0, 20.0)]["see_through"] == pos["see_through"]
    assert sum(b["binning"] for b in pos["bands"]) == pos["binning"]
    plot_comparison(res, tmp_path / "c.png")
    assert (tmp_path / "c.png").stat().st_size > 1000


def test_compare_cli(tmp_path, capsys):
    import json

    from slr_ray.cli import main
    from slr_ray.io import PointCloud, write_cloud

    pts, _ = two_walls(0.04)
    write_cloud(tmp_path / "w.ply", PointCloud(pts))
    assert main(["compare", str(tmp_path / "w.ply"), "--origin", "0", "0", "0", "--origin", "0", "1", "0",
                 "--resolution", "0.5", "--png", str(tmp_path / "c.png")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert len(res["positions"]) == 2 and (tmp_path / "c.png").exists()


@pytest.mark.parametrize("orientation", ["normal", "billboard"])
def test_open3d_engine_agrees_with_embreex(orientation):
    pytest.importorskip("open3d")
    pts, n_front = two_walls(0.04)
    p = ScanPattern(0.5)
    ea = DiscScene(pts, orientation=orientation)
    eb = DiscScene(pts, orientation=orientation, engine="open3d")
    (pa, _, ta), (pb, _, tb) = ea.ray_hits([0, 0, 0], p), eb.ray_hits([0, 0, 0], p)
    # the same rays hit, at the same distances (coplanar overlapping discs may
    # resolve to different points: a tie the engines break differently)
    ka, kb = pa[:, 0] * p.n_azimuth + pa[:, 1], pb[:, 0] * p.n_azimuth + pb[:, 1]
    common, ia, ib = np.intersect1d(ka, kb, return_indices=True)
    assert len(common) >= 0.995 * max(len(ka), len(kb))
    np.testing.assert_allclose(ta[ia], tb[ib], atol=1e-4)
    assert eb.scan([0, 0, 0], p).info["engine"] == "open3d"
    with pytest.raises(InputValueError, match="engine"):
        DiscScene(pts, engine="optix")
