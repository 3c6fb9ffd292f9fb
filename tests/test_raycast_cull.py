"""The direction map (slr_ray.raycast.cull): it never answers a ray that Embree would hit."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import slr_ray.raycast.scene as scene_module
from slr_ray.raycast import RayScene
from slr_ray.raycast.cull import FACE, GRID, _chunks, could_hit, direction_map, voxel_boxes
from slr_ray.raycast.scene import _CULL_RAYS

#: directions on the cube's edges and corners, the axes, and nearly so (face ties, u or v at +-1)
_SPECIAL = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                     [1, 1, 0], [1, -1, 0], [-1, 1, 0], [0, 1, 1], [0, -1, -1], [1, 0, -1],
                     [1, 1, 1], [-1, -1, -1], [1, -1, 1], [-1, 1, -1],
                     [1, 1 - 1e-12, 0], [1, 1e-300, 0], [1e-300, 1e-300, -1]], float)


def _unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _rays(rng, n=_CULL_RAYS + 500, at=None, o=None):
    """Random unit directions and the special ones; with ``at`` (points) and ``o``, half of
    them aimed from ``o`` at points of ``at``."""
    special = _SPECIAL / np.linalg.norm(_SPECIAL, axis=1, keepdims=True)
    dirs = np.concatenate([_unit(rng, n), special])
    if at is not None:
        towards = at[rng.integers(0, len(at), len(dirs) // 2)] - o
        dirs[: len(towards)] = towards / np.linalg.norm(towards, axis=1, keepdims=True)
    return dirs


def assert_same_with_and_without(scene, o, dirs, **kw):
    assert len(dirs) >= max(_CULL_RAYS, len(scene._cull_boxes))  # the map is made
    ref = scene.intersect(o, dirs, cull=False, **kw)
    got = scene.intersect(o, dirs, **kw)
    for field in ("primitives", "owners", "distances"):
        np.testing.assert_array_equal(getattr(got, field), getattr(ref, field), err_msg=f"{field}, {kw}")
    return ref


def _clumps(rng, n=3000, oriented=True, offset=0.0):
    """Discs in a few clumps with empty space between (most directions from outside miss)."""
    heads = rng.uniform(-20, 20, (6, 3))
    c = heads[rng.integers(0, 6, n)] + rng.normal(scale=0.7, size=(n, 3)) + offset
    r = rng.uniform(0.05, 0.4, n)
    return c, r, (_unit(rng, n) if oriented else None)


@pytest.mark.parametrize("oriented", [True, False])
@pytest.mark.parametrize("where", ["outside", "inside", "far", "corner"])
def test_the_map_changes_no_answer_of_discs(oriented, where):
    rng = np.random.default_rng(["outside", "inside", "far", "corner"].index(where) + 10 * oriented)
    c, r, nrm = _clumps(rng, oriented=oriented)
    scene = RayScene.discs(c, r, nrm)
    o = {"outside": np.array([35.0, -3.0, 2.0]), "inside": c[17] + [0.01, 0.0, 0.0],
         "far": np.array([4000.0, 3000.0, -2500.0]), "corner": c.max(axis=0) + 0.4}[where]
    dirs = _rays(rng, at=c, o=o)  # from far away the scene is a speck
    for kw in ({}, {"ties": 1.0}, {"ties": 1.0, "skip_containing": True}, {"tnear": 1.0, "tfar": 30.0},
               {"ties": 2.0, "pulse_aspect": 1.5}):
        ref = assert_same_with_and_without(scene, o, dirs, **kw)
    assert np.count_nonzero(ref.hit) > 500


def test_the_map_changes_no_answer_of_triangles():
    # triangles of all sizes: a ground of two, slivers, a fan standing for discs
    rng = np.random.default_rng(5)
    v = np.concatenate([[[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], rng.uniform(-10, 10, (600, 3))])
    f = np.concatenate([[[0, 1, 2], [0, 2, 3]], 4 + rng.integers(0, 600, (800, 3))])
    scene = RayScene.triangles(v, f)
    for o in ([0.0, 0.0, 5.0], [200.0, 10.0, 30.0], [0.0, 0.0, -3.0]):
        ref = assert_same_with_and_without(scene, np.array(o), _rays(rng), exact=True)
        assert np.count_nonzero(ref.hit) >= 10


def test_the_map_holds_far_from_the_origin_of_coordinates():
    # the same scene moved by 10^6 m: the boxes live in the scene's recentred frame
    rng = np.random.default_rng(11)
    c, r, nrm = _clumps(rng, offset=1e6)
    scene = RayScene.discs(c, r, nrm)
    o = np.array([1e6 + 30.0, 1e6, 1e6 + 3.0])
    ref = assert_same_with_and_without(scene, o, _rays(rng, at=c, o=o), ties=1.0)
    assert np.count_nonzero(ref.hit) > 500


def test_one_disc_a_flat_scene_and_no_disc():
    rng = np.random.default_rng(2)
    one = RayScene.discs(np.array([[1.0, 2.0, 3.0]]), np.array([0.5]), np.array([[0.0, 0.0, 1.0]]))
    o = np.array([1.0, 2.0, 10.0])
    dirs = _rays(rng)
    dirs[:50] = [0.0, 0.0, -1.0]
    assert np.count_nonzero(assert_same_with_and_without(one, o, dirs).hit) >= 50
    flat = rng.uniform(-5, 5, (2000, 3))
    flat[:, 2] = 0.0
    ground = RayScene.discs(flat, np.full(2000, 0.2), np.tile([0.0, 0.0, 1.0], (2000, 1)))
    assert np.count_nonzero(assert_same_with_and_without(ground, o, dirs, ties=1.0).hit) > 100
    empty = RayScene.discs(np.zeros((0, 3)), np.zeros(0))
    assert not empty.intersect(o, dirs).hit.any()


def test_degenerate_directions_go_to_embree():
    # zero and non-finite directions are never answered by the map (Embree's answer either way)
    rng = np.random.default_rng(4)
    c, r, nrm = _clumps(rng)
    scene = RayScene.discs(c, r, nrm)
    dirs = _rays(rng)
    dirs[:3] = [[0.0, 0.0, 0.0], [np.nan, 0.0, 1.0], [np.inf, 0.0, 0.0]]
    assert_same_with_and_without(scene, np.array([35.0, 0.0, 0.0]), dirs)
    dmap = np.zeros(6 * FACE * FACE, np.uint8)
    assert could_hit(dmap, FACE, 0.0, 0.0, 0.0) and could_hit(dmap, FACE, np.nan, 1.0, 0.0)
    assert not could_hit(dmap, FACE, 0.0, 0.0, 1.0)


def test_voxel_boxes_hold_every_disc_and_every_triangle():
    rng = np.random.default_rng(8)
    c, r, _ = _clumps(rng, n=5000)
    vbuf = np.empty((len(c), 4), np.float32)
    vbuf[:, :3], vbuf[:, 3] = c, r
    boxes = voxel_boxes(vbuf, None, len(c), grid=16)
    assert 1 < len(boxes) <= 16 ** 3
    lo = vbuf[:, :3].astype(float) - vbuf[:, 3:].astype(float)
    hi = vbuf[:, :3].astype(float) + vbuf[:, 3:].astype(float)
    inside = ((boxes[None, :, :3] <= lo[:, None]) & (hi[:, None] <= boxes[None, :, 3:])).all(axis=2)
    assert inside.any(axis=1).all()
    v = rng.uniform(-3, 3, (300, 3)).astype(np.float32)
    f = rng.integers(0, 300, (400, 3)).astype(np.uint32)
    boxes = voxel_boxes(v, f, len(f), grid=8)
    tlo, thi = v[f].min(axis=1).astype(float), v[f].max(axis=1).astype(float)
    inside = ((boxes[None, :, :3] <= tlo[:, None]) & (thi[:, None] <= boxes[None, :, 3:])).all(axis=2)
    assert inside.any(axis=1).all()


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-3, 1.0, 1e3]),
       face=st.sampled_from([1, 2, 7, 128]))
def test_every_direction_into_a_box_is_marked(seed, scale, face):
    # the map is an over-estimate: points drawn inside the boxes (their corners and faces too) are
    # in marked cells, from origins outside, on a face of and inside a box
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-1, 1, (4, 3)) * scale
    boxes = np.concatenate([lo, lo + rng.uniform(0, 0.5, (4, 3)) * scale], axis=1)
    origins = [rng.uniform(-2, 2, 3) * scale, boxes[0, :3].copy(), 0.5 * (boxes[1, :3] + boxes[1, 3:])]
    origins[1][0] = boxes[0, 3]  # on the box's face
    for o in origins:
        dmap = direction_map(boxes, o, face)
        for b in boxes:
            p = b[:3] + rng.uniform(0, 1, (200, 3)) * (b[3:] - b[:3])
            p[:8] = [[b[3 * (k >> i & 1) + i] for i in range(3)] for k in range(8)]  # the corners
            for d in p - o:
                assert could_hit(dmap, face, *d), (o, b, d)


def test_the_map_of_a_far_speck_is_mostly_empty():
    # what it is for: from outside a cloud, most directions are answered without Embree
    rng = np.random.default_rng(3)
    c, r, nrm = _clumps(rng)
    scene = RayScene.discs(c, r, nrm)
    dmap = direction_map(scene._cull_boxes, np.array([300.0, 0.0, 0.0]) - scene.centre, FACE)
    assert 0 < dmap.mean() < 0.01


def test_overlapping_large_boxes_give_up_the_map_not_the_answers():
    # long random triangles from all over the scene: every voxel's box is nearly the scene's, and
    # marking them all would cost minutes; past its budget the map is empty (no culling)
    rng = np.random.default_rng(9)
    v = rng.uniform(-10, 10, (3000, 3))
    f = rng.integers(0, len(v), (20000, 3))
    scene = RayScene.triangles(v, f)
    o = np.array([30.0, 1.0, 2.0])
    assert len(direction_map(scene._cull_boxes, o - scene.centre, FACE)) == 0
    assert len(direction_map(scene._cull_boxes, o - scene.centre, FACE, budget=10**6)) == 6 * FACE * FACE
    ref = assert_same_with_and_without(scene, o, _rays(rng, n=len(scene._cull_boxes) + 500, at=v, o=o))
    assert np.count_nonzero(ref.hit) > 500


def test_directions_float32_holds_only_coarsely_go_to_embree():
    # Embree traces float32 directions: components of 1e-45..1e-37 are denormal there (a few
    # significant bits: the direction it traces is not the one the map was asked about) and
    # it answers them with hits at NaN distances the map cannot foresee; the map leaves
    # such rays (and any outside 1e-30..1e30) to Embree, like zero and non-finite ones
    rng = np.random.default_rng(0)
    c = rng.normal(size=(3000, 3)) * 2.2e-4 + 1e6
    v = (c[:, None] + rng.normal(size=(3000, 3, 3)) * 6.7e-5).reshape(-1, 3)
    scene = RayScene.triangles(v, np.arange(9000).reshape(-1, 3))
    o = c[0] + rng.normal(size=3) * 6.7e-4
    dirs = rng.choice([-1, 1], (8192, 3)) * 10.0 ** rng.uniform(-45, -37, (8192, 3))
    axis = rng.integers(0, 4, 8192)
    dirs[axis < 3, axis[axis < 3]] = 0.0
    ref = assert_same_with_and_without(scene, o, dirs)
    assert np.count_nonzero(ref.hit) > 0
    dmap = np.zeros(6 * FACE * FACE, np.uint8)  # nothing to meet
    for d in ([1e-40, 1e-41, 0.0], [0.0, 1e-31, 0.0], [1e31, 0.0, 1.0], [1e39, 1.0, 0.0]):
        assert could_hit(dmap, FACE, *d), d
    assert not could_hit(dmap, FACE, 0.0, 1e-29, 0.0) and not could_hit(dmap, FACE, 1e29, 0.0, 1.0)


def test_voxel_boxes_accumulators_stay_small_on_many_threads():
    # one accumulator of 48 B a voxel a chunk: a full 64^3 grid is 12.6 MB a thread, so a chunk a
    # thread on a 64-thread machine would hold 0.8 GB while a 20 M-point scene is built
    for threads in (1, 2, 16, 64, 256):
        for n_cells in (1, 1000, GRID ** 3, 256 ** 3):
            k = _chunks(20_000_000, n_cells, threads)
            assert 1 <= k <= threads and (k == 1 or k * n_cells * 48 <= 64 << 20), (threads, n_cells, k)
    assert _chunks(20_000_000, 1000, 16) == 16 and _chunks(1000, GRID ** 3, 16) == 1


def test_no_map_for_a_cast_of_fewer_rays_than_boxes(monkeypatch):
    # a map costs 25-50 ns a box and saves at most ~40 ns a ray: a cast of fewer rays than the
    # scene has boxes (a column of a moving scanner's sweep: 14,000 rays against 49 k boxes took
    # 12.5 ms a cast instead of 9.0) makes none; the answers are the same either way
    rng = np.random.default_rng(12)
    c = rng.uniform(-10, 10, (20000, 3))
    scene = RayScene.discs(c, np.full(len(c), 0.05))
    made = []
    monkeypatch.setattr(scene_module, "direction_map", lambda *a: made.append(1) or direction_map(*a))
    n_boxes = len(scene._cull_boxes)
    assert n_boxes > _CULL_RAYS + 1000
    o = np.array([30.0, 2.0, 1.0])
    for m in (_CULL_RAYS + 1000, n_boxes - 1, n_boxes):
        dirs = _rays(rng, n=m - len(_SPECIAL), at=c, o=o)
        ref = scene.intersect(o, dirs, cull=False)
        got = scene.intersect(o, dirs)
        np.testing.assert_array_equal(got.primitives, ref.primitives)
        np.testing.assert_array_equal(got.distances, ref.distances)
    assert len(made) == 1
