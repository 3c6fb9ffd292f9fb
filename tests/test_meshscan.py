import numpy as np
import pytest
import trimesh

from slr_ray import InputValueError, ScanPattern, scan_mesh, simulate_scan
from slr_ray.scenes import dense_samples, rectangle_scene


def test_ground_only_centre_scan_is_exact():
    sc = rectangle_scene(0)
    pattern = ScanPattern(0.5)
    ms = scan_mesh(sc, [0, 0, 0], pattern)
    assert len(ms) > 0 and np.all(ms.labels == 0)
    assert np.abs(ms.points[:, 2] + 1.65).max() < 1e-6
    d_theta = np.radians(0.5)
    theta = (ms.pulses[:, 0] + 0.5) * d_theta
    np.testing.assert_allclose(ms.ranges, 1.65 / np.cos(np.pi - theta), rtol=1e-6)
    # every downward pulse whose centre meets the disc is returned
    th = (np.arange(pattern.n_zenith) + 0.5) * d_theta
    meets = (th > np.pi / 2) & (1.65 * np.tan(np.pi - th) < 100 * np.cos(np.pi / 1024) - 1e-3)
    assert len(ms) == meets.sum() * pattern.n_azimuth


def test_far_from_the_origin_stays_exact():
    sc = rectangle_scene(0)
    shift = np.array([5e5, 5e6, 100.0])
    moved = trimesh.Trimesh(sc.mesh.vertices + shift, sc.mesh.faces, process=False)
    ms = scan_mesh(moved, shift + [1, 2, 0], ScanPattern(1.0))
    assert np.abs(ms.points[:, 2] - (shift[2] - 1.65)).max() < 1e-6


def _two_walls():
    front = trimesh.creation.box([0.1, 4, 4])
    front.apply_translation([5, 0, 0])
    back = trimesh.creation.box([0.1, 10, 10])
    back.apply_translation([10, 0, 0])
    mesh = trimesh.util.concatenate([front, back])
    labels = np.r_[np.ones(len(front.faces), int), np.full(len(back.faces), 2)]
    return mesh, labels


@pytest.mark.parametrize("mode", ["center", "nearest"])
def test_wall_in_front_of_wall(mode):
    mesh, labels = _two_walls()
    ms = scan_mesh(mesh, [0, 0, 0], ScanPattern(0.5), mode=mode, face_labels=labels, supersample=3)
    front = ms.labels == 1
    assert front.any() and (~front).any()
    # nothing of the back wall where the front wall covers it (|y|, |z| < 2 seen from x=0 at x=5)
    back = ms.points[~front]
    hidden = (np.abs(back[:, 1]) < 2 * 10 / 5 - 0.2) & (np.abs(back[:, 2]) < 2 * 10 / 5 - 0.2)
    assert not hidden.any()
    np.testing.assert_allclose(ms.points[front, 0], 4.95, atol=1e-9)
    np.testing.assert_allclose(ms.points[~front, 0], 9.95, atol=1e-9)


def test_nearest_never_loses_pulses_that_centre_rays_hit_and_finds_more():
    sc = rectangle_scene(100, seed=5)
    p = ScanPattern(1.0)
    centre = scan_mesh(sc, [0, 0, 0], p)
    near = scan_mesh(sc, [0, 0, 0], p, mode="nearest", supersample=4)
    c_ids = set((centre.pulses[:, 0] * p.n_azimuth + centre.pulses[:, 1]).tolist())
    n_ids = set((near.pulses[:, 0] * p.n_azimuth + near.pulses[:, 1]).tolist())
    assert c_ids <= n_ids and len(n_ids) > len(c_ids)
    # per pulse the nearest-in-pulse range is never larger than the centre ray's
    cr = dict(zip(centre.pulses[:, 0] * p.n_azimuth + centre.pulses[:, 1], centre.ranges))
    nr = dict(zip(near.pulses[:, 0] * p.n_azimuth + near.pulses[:, 1], near.ranges))
    assert all(nr[k] <= cr[k] + 1e-9 for k in cr)


def test_nearest_converges_to_the_dense_truth():
    sc = rectangle_scene(15, seed=7, ground_radius=6.0, xy_range=(-6, 6), z_range=(-1, 2))
    p = ScanPattern(4.0)
    dense = scan_mesh(sc, [0.3, 0.2, 0], p, mode="dense", spacing=0.01)
    key = lambda ms: ms.pulses[:, 0] * p.n_azimuth + ms.pulses[:, 1]  # noqa: E731
    errs = []
    for k in (1, 4, 16):
        ms = scan_mesh(sc, [0.3, 0.2, 0], p, mode="nearest", supersample=k)
        common, a, b = np.intersect1d(key(ms), key(dense), return_indices=True)
        errs.append(np.abs(ms.ranges[a] - dense.ranges[b]).mean())
    assert errs[2] < errs[1] < errs[0]
    assert errs[2] < 0.01 * 3  # within a few sample spacings


def test_dense_mode_equals_binning_the_samples(table_kind):
    sc = rectangle_scene(5, seed=1, ground_radius=4.0, xy_range=(-4, 4), z_range=(-1, 1))
    p = ScanPattern(3.0)
    ms = scan_mesh(sc, [0, 0, 0], p, mode="dense", spacing=0.02)
    pts = np.vstack([c[0] for c in dense_samples(sc, 0.02)])
    lab = np.concatenate([c[1] for c in dense_samples(sc, 0.02)])
    ref = simulate_scan(pts, [0, 0, 0], p)
    np.testing.assert_array_equal(ms.points, pts[ref.indices])
    np.testing.assert_array_equal(ms.labels, lab[ref.indices])
    np.testing.assert_array_equal(ms.ranges, ref.ranges)
    np.testing.assert_array_equal(ms.pulses, ref.pulses)


@pytest.fixture(scope="module")
def dense_whole():
    """The dense scan of a scene in one band, and the scene and pattern it was made with
    (computed once: each band size compares its banded scan of the same inputs with it)."""
    sc = rectangle_scene(5, seed=1, ground_radius=4.0, xy_range=(-4, 4), z_range=(-1, 1))
    p = ScanPattern(3.0)  # 60 x 120 pulses
    return sc, p, scan_mesh(sc, [0.3, -0.2, 0.1], p, mode="dense", spacing=0.04)


@pytest.mark.parametrize("band_pulses", [1, 120 * 7, 120 * 60 - 1])
def test_dense_mode_in_zenith_bands_is_the_same_scan(dense_whole, band_pulses):
    # a row per band, 7 rows a band, and bands not dividing the rows: the same arrays
    sc, p, whole = dense_whole
    banded = scan_mesh(sc, [0.3, -0.2, 0.1], p, mode="dense", spacing=0.04, band_pulses=band_pulses)
    for name in ("points", "labels", "ranges", "pulses"):
        np.testing.assert_array_equal(getattr(banded, name), getattr(whole, name))


def test_bin_tables_keep_only_their_key_range():
    from slr_ray.core import BinTables

    rng = np.random.default_rng(2)
    pts = rng.normal(size=(20000, 3))
    p = ScanPattern(2.0)
    full = BinTables(np.zeros(3), p)
    full.add(pts)
    keys, _, idx = full.winners(pts)
    lo, hi = 30 * p.n_azimuth, 60 * p.n_azimuth
    band = BinTables(np.zeros(3), p, key_range=(lo, hi))
    band.add(pts)
    bk, _, bi = band.winners(pts)
    inside = (keys >= lo) & (keys < hi)
    np.testing.assert_array_equal(bk, keys[inside])
    np.testing.assert_array_equal(bi, idx[inside])


def test_grazing_tiny_and_inside_do_not_misbehave():
    # a rectangle seen edge-on, one far smaller than a pulse, and the scanner inside a box's bounds
    edge = trimesh.Trimesh([[3, -1, 0], [3, 1, 0], [6, 1, 0], [6, -1, 0]], [[0, 1, 2], [0, 2, 3]])
    tiny = trimesh.Trimesh(np.array([[0, 0, 0], [1e-4, 0, 0], [0, 1e-4, 0]]) + [0, 5, 0], [[0, 1, 2]])
    box = trimesh.creation.box([2, 2, 2])
    mesh = trimesh.util.concatenate([edge, tiny, box])
    ms = scan_mesh(mesh, [0.1, -0.2, 0.0], ScanPattern(2.0))
    assert len(ms) > 0 and np.isfinite(ms.points).all()
    # every hit lies on the plane of its face
    tri = mesh.triangles[ms.labels]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ij,ij->i", ms.points - tri[:, 0], n), 0, atol=1e-9)
    # inside the box every direction hits it: the full sphere of pulses
    assert len(ms) == ScanPattern(2.0).n_pulses


def test_bad_arguments():
    sc = rectangle_scene(0)
    with pytest.raises(InputValueError, match="mode"):
        scan_mesh(sc, [0, 0, 0], 1.0, mode="exact")
    with pytest.raises(InputValueError, match="supersample"):
        scan_mesh(sc, [0, 0, 0], 1.0, mode="nearest", supersample=0)
    with pytest.raises(InputValueError, match="RectangleScene"):
        scan_mesh(sc.mesh, [0, 0, 0], 1.0, mode="dense")
    with pytest.raises(InputValueError, match="face_labels"):
        scan_mesh(sc.mesh, [0, 0, 0], 1.0, face_labels=[1, 2])


def test_compact_storage_round_trip(tmp_path):
    from slr_ray.meshscan import load_meshscan

    sc = rectangle_scene(30, seed=2)
    ms = scan_mesh(sc, [3.0, -2.0, 0.5], ScanPattern(1.0))
    path = ms.save(tmp_path / "primary.npz")
    back = load_meshscan(path)
    np.testing.assert_allclose(back.points, ms.points, atol=2e-5)  # float32 offsets: ~8 um at 100 m
    np.testing.assert_array_equal(back.labels, ms.labels)
    np.testing.assert_array_equal(back.pulses, ms.pulses)
    np.testing.assert_allclose(back.ranges, ms.ranges, atol=2e-5)
    assert back.pattern == ms.pattern and back.mode == "center"
    assert path.stat().st_size < len(ms) * 20 + 4096  # 12 + 4 + 4 bytes a point


@pytest.mark.parametrize("mode", ["center", "dense"])
def test_streamed_file_equals_the_in_memory_scan(tmp_path, mode):
    from slr_ray.meshscan import load_meshscan, scan_mesh_to_file

    sc = rectangle_scene(10, seed=4, ground_radius=8.0, xy_range=(-8, 8), z_range=(-1, 2))
    p = ScanPattern(2.0)
    ms = scan_mesh(sc, [1.0, 0.5, 0.2], p, mode=mode, spacing=0.02)
    info = scan_mesh_to_file(sc, [1.0, 0.5, 0.2], p, tmp_path / "s.npz", mode=mode, spacing=0.02,
                             rays_per_batch=5000)
    assert info["points_out"] == len(ms) and info["bytes"] < 20 * len(ms) + 4096
    back = load_meshscan(tmp_path / "s.npz")
    np.testing.assert_array_equal(back.labels, ms.labels)
    np.testing.assert_array_equal(back.pulses, ms.pulses)
    np.testing.assert_allclose(back.points, ms.points, atol=1e-5)
    assert [p.name for p in tmp_path.iterdir()] == ["s.npz"]  # temporary files removed


def test_ray_cast_primaries_see_no_further_than_the_first_wall_where_a_5mm_grid_does():
    # the fine primary of question 3: at 30 m a 0.00576 deg pulse is 3 mm tall,
    # narrower than the paper's 5 mm dense grid, so binning that grid keeps
    # back-wall points in pulses through the front wall (see-through); the
    # ray-cast primary (mode='center') returns the front wall in every such pulse
    front = trimesh.creation.box([0.01, 1.0, 1.0])
    front.apply_translation([30, 0, 0])
    back = trimesh.creation.box([0.01, 4.0, 4.0])
    back.apply_translation([35, 0, 0])
    mesh = trimesh.util.concatenate([front, back])
    labels = np.r_[np.ones(len(front.faces), int), np.full(len(back.faces), 2)]
    pattern = ScanPattern(azimuth_resolution=0.2, zenith_resolution=0.00576, zenith_range=(89.0, 91.0))
    ms = scan_mesh(mesh, [0, 0, 0], pattern, face_labels=labels)
    p = ms.points
    # inside the front wall's angular extent (a margin of a pulse): only front-wall points
    shadow = (np.abs(p[:, 1] / p[:, 0]) < 0.5 / 30 - 4e-3) & (np.abs(p[:, 2] / p[:, 0]) < 0.5 / 30 - 1e-4)
    assert shadow.sum() > 1000 and np.all(ms.labels[shadow] == 1)
    # the same walls as a 5 mm grid, binned: back-wall points inside that extent
    g = np.arange(-0.4975, 0.5, 0.005)
    gb = np.arange(-1.9975, 2.0, 0.005)
    yy, zz = np.meshgrid(g, g)
    yb, zb = np.meshgrid(gb, gb)
    dense = np.vstack([np.column_stack([np.full(yy.size, 29.995), yy.ravel(), zz.ravel()]),
                       np.column_stack([np.full(yb.size, 34.995), yb.ravel(), zb.ravel()])])
    q = dense[simulate_scan(dense, [0, 0, 0], pattern).indices]
    see_through = (q[:, 0] > 32) & (np.abs(q[:, 1] / q[:, 0]) < 0.5 / 30 - 4e-3) \
        & (np.abs(q[:, 2] / q[:, 0]) < 0.5 / 30 - 1e-4)
    assert see_through.sum() > 100


def test_settings_that_would_exhaust_memory_are_refused_with_the_figure():
    scene = rectangle_scene(3, seed=0)
    with pytest.raises(InputValueError, match="would need about .* GiB"):  # was a MemoryError traceback
        scan_mesh(scene, [0, 0, 0], 1.0, mode="nearest", supersample=1_000_000)
    with pytest.raises(InputValueError, match="would need about .* GiB"):
        next(dense_samples(scene, spacing=1e-9))
