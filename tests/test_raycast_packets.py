"""Ray packets (rtcIntersect4/8/16) against the one-ray path (rtcIntersect1), answer for answer."""

import numpy as np
import pytest

from slr_ray import InputValueError
from slr_ray.raycast import RayScene, embree_library

WIDTHS = (4, 8, 16)


def _unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def assert_same_as_one_ray(scene, o, dirs, **kw):
    """Every packet width gives the one-ray answers; returns those."""
    ref = scene.intersect(o, dirs, packet=1, **kw)
    for w in WIDTHS:
        got = scene.intersect(o, dirs, packet=w, **kw)
        for field in ("primitives", "owners", "distances"):
            np.testing.assert_array_equal(getattr(got, field), getattr(ref, field), err_msg=f"{field}, packet={w}, {kw}")
    return ref


def _slab(seed, n=400, oriented=True):
    rng = np.random.default_rng(seed)
    c = rng.uniform(-3, 3, (n, 3)) * [1, 1, 0.3]
    r = rng.uniform(0.1, 1.0, n)
    nrm = _unit(rng, n) * [0.5, 0.5, 1] if oriented else None
    return rng, RayScene.discs(c, r, nrm)


@pytest.mark.parametrize("oriented", [True, False])
@pytest.mark.parametrize("n_rays", [1, 3, 15, 17, 33, 1001])
def test_packets_match_one_ray_at_their_tails(oriented, n_rays):
    # ray counts that leave a packet part full; half the rays miss the scene's box (no lane
    # for them), some meet it and miss every disc: lanes of a packet come from far apart
    rng, scene = _slab(n_rays, oriented=oriented)
    o = np.array([0.3, -0.2, 6.0])
    dirs = _unit(rng, n_rays)
    dirs[::2, 2] = -np.abs(dirs[::2, 2]) - 1.0
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for kw in ({}, {"ties": 1.0}, {"ties": 20.0}, {"ties": 1.0, "one_pass": False}, {"ties": 1.0, "pulse_aspect": 2.0}):
        ref = assert_same_as_one_ray(scene, o, dirs, **kw)
    if n_rays > 100:
        assert 0 < np.count_nonzero(ref.hit) < n_rays // 2 + 1


def test_packets_match_one_ray_on_a_segment_and_inside_the_discs():
    # tnear / tfar cut the rays; the origin stands among the discs (skip_containing)
    rng, scene = _slab(7, n=600)
    o = np.array([0.1, 0.2, 0.0])
    dirs = _unit(rng, 2000)
    for kw in ({"tnear": 0.5, "tfar": 2.5}, {"tnear": 0.5, "tfar": 2.5, "ties": 1.0},
               {"skip_containing": True}, {"skip_containing": True, "ties": 1.0, "pulse_aspect": 1.0},
               {"skip_containing": True, "ties": 3.0, "one_pass": False, "tfar": 4.0}):
        ref = assert_same_as_one_ray(scene, o, dirs, **kw)
        assert np.count_nonzero(ref.hit) > 200


def test_packets_match_one_ray_when_some_lanes_overflow_the_candidates():
    # 150 discs stacked 1 mm apart (more candidates than one pass holds: those rays are queried
    # again, a packet of only them) beside a single disc (rays of one pass), rays in turn
    rng = np.random.default_rng(5)
    n = 150
    c = np.column_stack([rng.uniform(-0.05, 0.05, (n, 2)), np.arange(n) * 1e-3])
    c = np.vstack([c, [[3.0, 0.0, 0.0]]])
    r = np.full(n + 1, 0.5)
    nrm = np.tile([0, 0, 1.0], (n + 1, 1))
    o = np.array([0.0, 0.0, 3.0])
    to_stack = _unit(rng, 300) * [0.05, 0.05, 1]
    to_stack[:, 2] = -np.abs(to_stack[:, 2]) - 1.0
    to_single = np.array([3.0, 0.0, 0.0]) + rng.uniform(-0.2, 0.2, (300, 3)) * [1, 1, 0] - o
    dirs = np.empty((600, 3))
    dirs[0::2], dirs[1::2] = to_stack, to_single
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    scene = RayScene.discs(c, r, nrm)
    for ties in (1.0, 0.019):
        ref = assert_same_as_one_ray(scene, o, dirs, ties=ties)
        assert ref.hit.all() and np.all(ref.owners[1::2] == n)


def test_packets_match_one_ray_on_triangles_that_stand_for_discs():
    rng = np.random.default_rng(11)
    m = 200
    c = rng.uniform(-2, 2, (m, 3)) * [1, 1, 0.2]
    rad = rng.uniform(0.1, 0.4, m)
    # each disc as a fan of 6 triangles in the plane z = const
    ang = np.linspace(0, 2 * np.pi, 7)[:-1]
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(6)], -1)
    verts = np.concatenate([np.vstack([ci, ci + ri * ring]) for ci, ri in zip(c, rad)])
    base = np.arange(m)[:, None] * 7
    fan = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    faces = (base[:, None, :] + fan[None]).reshape(-1, 3)
    nrm = np.tile([0, 0, 1.0], (m, 1))
    scene = RayScene.triangles(verts, faces, owners=(c, rad, 6, 1.0, nrm))
    o = np.array([0.2, 0.1, 4.0])
    dirs = _unit(rng, 1500)
    dirs[:, 2] = -np.abs(dirs[:, 2]) - 0.8
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for kw in ({}, {"exact": True}, {"ties": 1.0}, {"ties": 1.0, "one_pass": False}):
        ref = assert_same_as_one_ray(scene, o, dirs, **kw)
        assert np.count_nonzero(ref.hit) > 300


def test_default_packet_is_the_native_width_and_others_are_refused():
    assert embree_library().native_width in (1, 4, 8, 16)
    rng, scene = _slab(3)
    dirs = _unit(rng, 50)
    a, b = scene.intersect([0, 0, 6.0], dirs, ties=1.0), scene.intersect([0, 0, 6.0], dirs, ties=1.0, packet=1)
    np.testing.assert_array_equal(a.owners, b.owners)
    for bad in (0, 2, 32, 8.0):
        with pytest.raises(InputValueError, match="packet"):
            scene.intersect([0, 0, 6.0], dirs, packet=bad)
