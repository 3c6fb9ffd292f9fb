import numpy as np
import pytest

from slr_ray import InputValueError
from slr_ray.scenes import (SCENES_DIR, dense_samples, load_scene_spec, rectangle_scene,
                            scene_from_spec)


def test_same_seed_same_scene_other_seed_other_scene():
    a, b, c = rectangle_scene(50, seed=3), rectangle_scene(50, seed=3), rectangle_scene(50, seed=4)
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    np.testing.assert_array_equal(a.face_labels, b.face_labels)
    assert not np.array_equal(a.mesh.vertices[-4:], c.mesh.vertices[-4:])


def test_clipped_on_the_geometry():
    sc = rectangle_scene(300, seed=1)
    v = sc.mesh.vertices
    assert v[:, 2].min() >= -1.65 - 1e-9
    assert np.hypot(v[:, 0], v[:, 1]).max() <= 100 + 1e-6
    # rectangles crossing the ground keep their upper part: some polygon has a vertex on z = -1.65
    on_ground = [p for p in sc.polygons if np.isclose(p[:, 2].min(), -1.65) and p[:, 2].max() > -1.6]
    assert len(on_ground) > 10
    # and clipped polygons are not all rectangles any more
    assert any(len(p) != 4 for p in sc.polygons)
    labels = set(np.unique(sc.face_labels).tolist())
    assert labels == {0} | set(sc.polygon_labels.tolist())
    assert sc.n_present == len(sc.polygons) < sc.n_rectangles


def test_n_present_is_near_the_papers():
    # paper: 754 of 1000 on average over five scenes (749 in one), 388 of 500, 1500 of 2000
    present = [rectangle_scene(1000, seed=s).n_present for s in range(5)]
    assert 730 <= np.mean(present) <= 780
    assert 350 <= rectangle_scene(500, seed=0).n_present <= 410
    assert 1450 <= rectangle_scene(2000, seed=0).n_present <= 1550


def test_ground_is_a_disc_of_the_right_area():
    sc = rectangle_scene(0)
    assert sc.n_present == 0 and np.all(sc.face_labels == 0)
    assert sc.mesh.area == pytest.approx(np.pi * 100**2, rel=1e-4)


@pytest.mark.parametrize("kwargs", [dict(n_rectangles=-1), dict(n_rectangles=2.5),
                                    dict(ground_radius=0), dict(side_range=(0, 1)),
                                    dict(ground_segments=3)])
def test_bad_parameters(kwargs):
    with pytest.raises(InputValueError):
        rectangle_scene(**{"n_rectangles": 10, **kwargs})


def test_shipped_specs_load_by_name_and_path():
    names = sorted(p.stem for p in SCENES_DIR.glob("*.toml"))
    assert {"ground-only", "rect-0500", "rect-1000", "rect-2000", "distance-1", "distance-5"} <= set(names)
    spec = load_scene_spec("rect-0500")
    assert spec["scene"]["n_rectangles"] == 500
    a = scene_from_spec("distance-2")
    b = scene_from_spec(SCENES_DIR / "distance-2.toml")
    assert a.n_present == b.n_present and a.n_rectangles == 1000


def test_bad_specs(tmp_path):
    with pytest.raises(InputValueError, match="no scene spec"):
        load_scene_spec("nope")
    bad = tmp_path / "bad.toml"
    bad.write_text("[scene\n")
    with pytest.raises(InputValueError, match="TOML"):
        load_scene_spec(bad)
    np.save(tmp_path / "cloud.npy", np.zeros((3, 3)))  # a cloud given for a config: binary, not UTF-8
    with pytest.raises(InputValueError, match="cloud.npy: not valid TOML"):
        load_scene_spec(tmp_path / "cloud.npy")
    bad.write_text("[scene]\nn_rectangles = 3\ncolour = 'red'\n")
    with pytest.raises(InputValueError, match="colour"):
        scene_from_spec(bad)


def test_dense_samples_cover_surfaces_at_the_spacing():
    sc = rectangle_scene(20, seed=2, ground_radius=5.0)
    spacing = 0.05
    chunks = list(dense_samples(sc, spacing, chunk=5000))
    pts = np.vstack([c[0] for c in chunks])
    lab = np.concatenate([c[1] for c in chunks])
    ground = pts[lab == 0]
    assert len(ground) == pytest.approx(np.pi * 5**2 / spacing**2, rel=0.02)
    assert np.all(ground[:, 2] == -1.65)
    for poly, label in zip(sc.polygons, sc.polygon_labels):
        p = pts[lab == label]
        area = 0.5 * np.linalg.norm(np.cross(poly[1:-1] - poly[0], poly[2:] - poly[0]).sum(axis=0))
        assert len(p) == pytest.approx(area / spacing**2, rel=0.3, abs=40)
        n = np.cross(poly[1] - poly[0], poly[2] - poly[0])
        n /= np.linalg.norm(n)
        np.testing.assert_allclose((p - poly[0]) @ n, 0, atol=1e-9)  # on the plane
    # the same stream every time
    again = np.vstack([c[0] for c in dense_samples(sc, spacing, chunk=5000)])
    np.testing.assert_array_equal(pts, again)
