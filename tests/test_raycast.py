"""The ray-casting module against brute-force ray-disc and ray-triangle intersection."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slr_ray import InputValueError, ScanPattern, pulse_directions, pulse_rays
from slr_ray.raycast import RayScene, embree_available


def _unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def brute_discs(o, dirs, c, r, normals):
    """First disc hit by each ray (index, t); -1 / inf on a miss."""
    idx = np.full(len(dirs), -1)
    tt = np.full(len(dirs), np.inf)
    for i, d in enumerate(dirs):
        if normals is None:  # discs facing the ray
            t = (c - o) @ d
        else:
            den = normals @ d
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.einsum("ij,ij->i", c - o, normals) / den
        x = o + t[:, None] * d
        ok = (np.linalg.norm(x - c, axis=1) <= r) & (t > 0)
        j = np.flatnonzero(ok)
        if len(j):
            k = j[np.argmin(t[j])]
            idx[i], tt[i] = k, t[k]
    return idx, tt


def test_library_is_found():
    assert embree_available()


@pytest.mark.parametrize("oriented", [True, False])
@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_discs_match_brute_force(oriented, seed):
    rng = np.random.default_rng(seed)
    n = 200
    c = rng.uniform(-5, 5, (n, 3))
    r = rng.uniform(0.05, 0.8, n)
    nrm = _unit(rng, n) if oriented else None
    o = rng.uniform(-1, 1, 3)
    # a ray origin inside a disc's reach is skip_containing's case (tested below)
    keep = np.linalg.norm(c - o, axis=1) > r
    c, r, nrm = c[keep], r[keep], (nrm[keep] if oriented else None)
    dirs = _unit(rng, 1500)
    hits = RayScene.discs(c, r, nrm).intersect(o, dirs)
    idx, t = brute_discs(o, dirs, c, r, nrm)
    # float32 inside Embree: a ray grazing a disc's rim may go either way
    rim = hits.owners != idx
    assert rim.mean() <= 0.005
    same = ~rim & (idx >= 0)
    # Embree holds normals in float32: a disc met at a grazing angle has its t known
    # to about t * 1e-7 / |cos| (float32 rounding of the normal)
    cos = np.abs(np.einsum("ij,ij->i", nrm[np.maximum(idx, 0)], dirs)) if oriented else np.ones(len(dirs))
    tol = 2e-5 + 2e-7 * np.abs(t) / np.maximum(cos, 1e-3)
    assert np.all(np.abs(hits.distances[same] - t[same]) <= tol[same])
    assert np.all(np.isinf(hits.distances[~rim & (idx < 0)]))


@pytest.mark.parametrize("oriented", [True, False])
@pytest.mark.parametrize("offset", [0.0, 4e6])
def test_rays_from_outside_the_bounds_graze_the_outermost_discs(oriented, offset):
    """Rays that miss the scene's padded bounds are answered without a call into
    Embree: rays aimed just inside the rim of every disc, on the side facing
    each axis (the rims that make the bounds), still hit, from a scanner
    outside the bounds, also at UTM-size coordinates."""
    rng = np.random.default_rng(5)
    n = 300
    c = rng.uniform(-2, 2, (n, 3)) + offset
    r = rng.uniform(0.05, 0.3, n)
    nrm = _unit(rng, n) if oriented else None
    o = np.array([-30.0, 7.0, 3.0]) + offset
    targets = []
    for e in np.vstack([np.eye(3), -np.eye(3)]):
        # the disc's rim point furthest along e: in the disc's plane, or across the ray for billboards
        axis = nrm if oriented else (c - o) / np.linalg.norm(c - o, axis=1, keepdims=True)
        u = e - np.einsum("ij,j->i", axis, e)[:, None] * axis
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        targets.append(c + 0.98 * r[:, None] * u)
    targets = np.vstack(targets)
    dirs = targets - o
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = RayScene.discs(c, r, nrm).intersect(o, dirs)
    idx, t = brute_discs(o, dirs, c, r, nrm)
    assert (idx >= 0).all()  # every ray meets its own disc at least
    # except a disc seen edge-on (|cos| < 1e-3), where its float32 normal decides
    own = np.tile(np.arange(n), 6)
    cos = np.abs(np.einsum("ij,ij->i", nrm[own], dirs)) if oriented else np.ones(len(dirs))
    assert (hits.owners[cos > 1e-3] >= 0).all()
    assert (hits.owners != idx).mean() <= 0.005  # another disc's rim, in float32
    # the scanner is outside the bounds, and rays that leave them at once miss
    assert o[0] < (c[:, 0] - r).min()
    away = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
    assert (RayScene.discs(c, r, nrm).intersect(o, away).owners == -1).all()


def test_triangles_exact_distances_far_from_the_origin():
    import trimesh

    m = trimesh.creation.icosphere(3, radius=2.0)
    shift = np.array([5e6, -5e6, 250.0])
    rng = np.random.default_rng(0)
    dirs = _unit(rng, 4000)
    o = shift + [0.1, -0.2, 0.05]
    hits = RayScene.triangles(m.vertices + shift, m.faces).intersect(o, dirs, exact=True)
    assert hits.hit.all()
    x = o + hits.distances[:, None] * dirs - shift
    # every hit lies on the plane of the face it hit, to float64 precision
    f = hits.primitives
    a = m.vertices[m.faces[f, 0]]
    dist_to_plane = np.einsum("ij,ij->i", x - a, m.face_normals[f])
    assert np.abs(dist_to_plane).max() < 1e-6
    # brute force (Moller-Trumbore, float64, near the origin)
    ol = o - shift
    a, b, c = (m.vertices[m.faces[:, j]] for j in range(3))
    e1, e2 = b - a, c - a
    p = np.cross(dirs[:, None, :], e2[None])
    det = np.einsum("fk,rfk->rf", e1, p)
    tv = ol - a
    u = np.einsum("fk,rfk->rf", tv, p) / det
    q = np.cross(tv, e1)
    v = np.einsum("rk,fk->rf", dirs, q) / det
    t = np.einsum("fk,fk->f", e2, q)[None] / det
    ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    t_ref = np.where(ok, t, np.inf).min(axis=1)
    np.testing.assert_allclose(hits.distances, t_ref, atol=1e-6)


def test_tie_rule_returns_the_centre_nearest_the_ray_then_the_lowest_index():
    # coplanar overlapping discs on z = 0: all candidates meet a ray at the same t
    g = np.stack(np.meshgrid(np.arange(30) * 0.1, np.arange(30) * 0.1), -1).reshape(-1, 2)
    c = np.column_stack([g, np.zeros(len(g))])
    c = np.vstack([c, c[:50]])  # duplicates: the lower index must win
    r = np.full(len(c), 0.15)
    nrm = np.tile([0, 0, 1.0], (len(c), 1))
    rng = np.random.default_rng(3)
    o = np.array([1.45, 1.45, 2.0])
    dirs = _unit(rng, 3000)
    dirs[:, 2] = -np.abs(dirs[:, 2]) - 0.5
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = RayScene.discs(c, r, nrm).intersect(o, dirs, ties=1.0)
    for i in np.flatnonzero(hits.hit)[:500]:
        d = dirs[i]
        t = (0 - o[2]) / d[2]
        x = o + t * d
        cand = np.flatnonzero(np.linalg.norm(c - x, axis=1) <= r)
        perp = np.linalg.norm(np.cross(c[cand] - o, d), axis=1)
        best = cand[np.lexsort((cand, np.round(perp, 12)))[0]]
        assert hits.owners[i] == best


def test_discs_holding_the_origin_are_skipped():
    c = np.array([[0.0, 0, 0], [5.0, 0, 0]])
    hits = RayScene.discs(c, np.array([0.5, 0.5]), np.array([[1.0, 0, 0], [1.0, 0, 0]])).intersect(
        [0.1, 0, 0], np.array([[1.0, 0, 0], [-1.0, 0, 0]]), skip_containing=True)
    assert hits.owners.tolist() == [1, -1]
    np.testing.assert_allclose(hits.distances[0], 4.9)


def test_open3d_scene_meets_the_triangles_embree_meets():
    """The engine='open3d' cross-check casts through this package too: the same
    triangles hit at the same distances as RayScene's, owners by triangle
    count, and owners holding the origin skipped."""
    pytest.importorskip("open3d")
    import trimesh

    from slr_ray.raycast import Open3DScene

    m = trimesh.creation.icosphere(2, radius=2.0)
    shift = np.array([3e5, -2e5, 40.0])
    rng = np.random.default_rng(1)
    dirs = _unit(rng, 2000)
    o = shift + [0.1, -0.2, 0.05]
    ref = RayScene.triangles(m.vertices + shift, m.faces).intersect(o, dirs, exact=True)
    centres = np.zeros((len(m.faces) // 4, 3)) + shift + [9.0, 0, 0]  # owners far from the origin
    got = Open3DScene(m.vertices + shift, m.faces, centres, np.full(len(centres), 0.1), prims_per_owner=4).intersect(
        o, dirs)
    assert got.hit.all() and ref.hit.all()
    assert (got.primitives == ref.primitives).mean() > 0.99  # shared edges may go either way
    np.testing.assert_allclose(got.distances, ref.distances, atol=1e-4)
    np.testing.assert_array_equal(got.owners, got.primitives // 4)
    # an owner whose reach holds the origin: rays start beyond it, and far limits are kept
    holding = Open3DScene(m.vertices + shift, m.faces, np.array([o]), np.array([3.0]), prims_per_owner=len(m.faces))
    assert not holding.intersect(o, dirs).hit.any()
    assert not Open3DScene(m.vertices + shift, m.faces, centres, np.full(len(centres), 0.1), 4).intersect(
        o, dirs, tfar=1.0).hit.any()


def test_bad_input():
    with pytest.raises(InputValueError, match="radii"):
        RayScene.discs(np.zeros((2, 3)), np.array([0.1, 0.0]))
    with pytest.raises(InputValueError, match="faces"):
        RayScene.triangles(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    s = RayScene.triangles(np.eye(3), np.array([[0, 1, 2]]))
    with pytest.raises(InputValueError, match="ties"):
        s.intersect([0, 0, 0], np.array([[1.0, 0, 0]]), ties=1.0)
    empty = RayScene.discs(np.zeros((0, 3)), np.zeros(0)).intersect([0, 0, 0], np.array([[1.0, 0, 0]]))
    assert empty.owners.tolist() == [-1]


def test_pulse_rays_one_rule_for_the_narrower_last_bin():
    p = ScanPattern(0.7, zenith_range=(10, 100))  # 90 / 0.7 is not whole: the last row is narrower
    d, v, h = pulse_rays(p, k=1)
    theta = np.degrees(np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2]))
    last = v == p.n_zenith - 1
    lo = 10 + (p.n_zenith - 1) * 0.7
    np.testing.assert_allclose(theta[last], (lo + 100) / 2)  # the middle of the clipped bin
    np.testing.assert_allclose(d, pulse_directions(np.column_stack([v, h]), p))
    d2, v2, _ = pulse_rays(p, k=3)
    th2 = np.degrees(np.arctan2(np.hypot(d2[:, 0], d2[:, 1]), d2[:, 2]))
    assert th2[v2 == p.n_zenith - 1].max() < 100 and th2.min() > 10


def test_pulse_aspect_ranks_ties_in_pulse_units_near_the_pole():
    # a ray 1 deg from the zenith: a disc 0.4 pulse away in zenith (its own pulse of a
    # 1 deg pattern) and one 1.2 pulses away in azimuth, which near the pole lies far
    # closer to the ray in metres; nearest-to-the-ray takes the latter, pulse units the former
    def direction(zen, az):
        z, a = np.radians(zen), np.radians(az)
        return np.array([np.sin(z) * np.cos(a), np.sin(z) * np.sin(a), np.cos(z)])

    ray = direction(1.0, 0.0)
    centres = np.array([10 * direction(1.4, 0.0), 10 * direction(1.0, 1.2)])
    assert np.linalg.norm(np.cross(centres[1], ray)) < np.linalg.norm(np.cross(centres[0], ray))
    scene = RayScene.discs(centres, np.full(2, 0.2), np.tile(-ray, (2, 1)))
    near = scene.intersect(np.zeros(3), ray[None], ties=1.0)
    pulse = scene.intersect(np.zeros(3), ray[None], ties=1.0, pulse_aspect=1.0)
    assert near.owners.tolist() == [1] and pulse.owners.tolist() == [0]
    # away from the pole the two rules agree
    ray = direction(90.0, 0.0)
    centres = np.array([10 * direction(90.4, 0.0), 10 * direction(90.0, 0.6)])
    scene = RayScene.discs(centres, np.full(2, 0.2), np.tile(-ray, (2, 1)))
    for aspect in (None, 1.0):
        assert scene.intersect(np.zeros(3), ray[None], ties=1.0, pulse_aspect=aspect).owners.tolist() == [0]
    with pytest.raises(InputValueError):
        scene.intersect(np.zeros(3), ray[None], ties=1.0, pulse_aspect=0.0)


def brute_ties(o, dirs, c, r, normals, ties):
    """The tie rule in float64, one ray at a time: every disc met, the nearest, its
    window (``ties`` r / max(|cos|, 0.05)), then the candidate in it whose centre lies
    nearest the ray, then the lowest index. Also whether the ray is stable under
    float32 rounding (no disc met near its rim, no candidate near the window's end,
    no second disc at the nearest distance)."""
    owner = np.full(len(dirs), -1)
    stable = np.ones(len(dirs), bool)
    for i, d in enumerate(dirs):
        if normals is None:
            t = (c - o) @ d
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.einsum("ij,ij->i", c - o, normals) / (normals @ d)
        rim = np.linalg.norm(o + t[:, None] * d - c, axis=1) / r
        met = np.flatnonzero((rim <= 1) & (t > 0))
        if np.any((np.abs(rim - 1) < 1e-3) & (t > 0)):
            stable[i] = False
        if not len(met):
            continue
        order = met[np.argsort(t[met])]
        first = order[0]
        cos = abs(normals[first] @ d) / np.linalg.norm(normals[first]) if normals is not None else 1.0
        hi = t[first] + ties * r[first] / max(cos, 0.05)
        tol = 1e-4 * (1 + t[first])
        if (len(order) > 1 and t[order[1]] - t[first] < tol) or np.any(np.abs(t[met] - hi) < tol):
            stable[i] = False
        cand = met[t[met] <= hi]
        perp = np.linalg.norm(np.cross(c[cand] - o, d), axis=1)
        owner[i] = cand[np.lexsort((cand, perp))[0]]
    return owner, stable


@pytest.mark.parametrize("oriented", [True, False])
@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 10_000), ties=st.sampled_from([0.5, 1.0, 3.0, 20.0]))
def test_one_pass_ties_match_the_brute_force_rule_and_the_two_query_rule(oriented, seed, ties):
    rng = np.random.default_rng(seed)
    n = 300
    # a slab of overlapping discs of mixed sizes: many rays meet several within a window
    c = rng.uniform(-3, 3, (n, 3)) * [1, 1, 0.3]
    r = rng.uniform(0.1, 1.0, n)
    nrm = _unit(rng, n) * [0.5, 0.5, 1] if oriented else None
    o = np.array([0.3, -0.2, 6.0])
    dirs = _unit(rng, 1500)
    dirs[:, 2] = -np.abs(dirs[:, 2]) - 1.0
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    scene = RayScene.discs(c, r, nrm)
    one = scene.intersect(o, dirs, ties=ties)
    two = scene.intersect(o, dirs, ties=ties, one_pass=False)
    for field in ("primitives", "owners", "distances"):
        np.testing.assert_array_equal(getattr(one, field), getattr(two, field))
    np.testing.assert_array_equal(one.primitives, one.owners)  # discs: the answer's own primitive
    owner, stable = brute_ties(o, dirs, c, r, nrm, ties)
    assert stable.mean() > 0.8 and np.count_nonzero(stable & (owner >= 0)) > 100
    np.testing.assert_array_equal(one.owners[stable], owner[stable])
    # the rule matters here: without it, other answers
    assert np.any(scene.intersect(o, dirs).owners[stable] != owner[stable])


@pytest.mark.parametrize("cells", [0.0, 1.0])
@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 10_000), ties=st.sampled_from([1.0, 3.0]))
def test_one_pass_ties_with_the_silhouette_rule_match_the_two_query_rule(cells, seed, ties):
    # the silhouette rule cuts hits inside the one-pass filter (candidates and the nearest hit
    # alike): the answers are those of the two-query rule, which tests every hit of the window
    import math

    rng = np.random.default_rng(seed)
    n = 300
    c = rng.uniform(-3, 3, (n, 3)) * [1, 1, 0.3]
    r = rng.uniform(0.1, 1.0, n)
    nrm = _unit(rng, n) * [0.5, 0.5, 1]
    o = np.array([0.3, -0.2, 6.0])
    dirs = _unit(rng, 1500)
    dirs[:, 2] = -np.abs(dirs[:, 2]) - 1.0
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    scene = RayScene.discs(c, r, nrm)
    # a primary 0.2 m from the rays' origin (the rule holds from 0.8 m on), pulses of 4 deg
    step = math.radians(4.0)
    geo = np.array([*(o + [0.2, 0.0, 0.0]), 0.0, step, step, 45, 90, cells])
    bits = (rng.random(n) < 0.5).astype(np.uint8) * rng.integers(0, 256, n).astype(np.uint8)
    clip = (bits, geo, np.zeros(0))
    one = scene.intersect(o, dirs, ties=ties, clip=clip)
    two = scene.intersect(o, dirs, ties=ties, clip=clip, one_pass=False)
    for field in ("primitives", "owners", "distances"):
        np.testing.assert_array_equal(getattr(one, field), getattr(two, field))
    # the rule cuts hits here, and the tie rule changes answers
    assert np.count_nonzero(one.owners != scene.intersect(o, dirs, ties=ties).owners) > 20
    assert np.count_nonzero(one.owners != scene.intersect(o, dirs, clip=clip).owners) > 20


def test_one_pass_ties_with_more_candidates_than_one_pass_holds():
    # 150 discs stacked 1 mm apart: more candidates than the filter keeps (64), so the
    # window is queried again; the answer is still the disc whose centre is nearest the ray
    rng = np.random.default_rng(5)
    n = 150
    c = np.column_stack([rng.uniform(-0.05, 0.05, (n, 2)), np.arange(n) * 1e-3])
    r = np.full(n, 0.5)
    nrm = np.tile([0, 0, 1.0], (n, 1))
    o = np.array([0.0, 0.0, 3.0])
    dirs = _unit(rng, 400) * [0.05, 0.05, 1]
    dirs[:, 2] = -np.abs(dirs[:, 2]) - 1.0
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    scene = RayScene.discs(c, r, nrm)
    one = scene.intersect(o, dirs, ties=1.0)
    two = scene.intersect(o, dirs, ties=1.0, one_pass=False)
    np.testing.assert_array_equal(one.owners, two.owners)
    np.testing.assert_array_equal(one.distances, two.distances)
    owner, stable = brute_ties(o, dirs, c, r, nrm, 1.0)
    assert stable.all() and (owner >= 0).all()
    np.testing.assert_array_equal(one.owners, owner)
    # a window of about ten of them: one pass
    few, stable = brute_ties(o, dirs, c, r, nrm, 0.019)
    assert stable.all()
    np.testing.assert_array_equal(scene.intersect(o, dirs, ties=0.019).owners, few)


def test_radii_in_a_vertex_column_are_shared_not_copied():
    from slr_ray.raycast import disc_vertices

    rng = np.random.default_rng(2)
    c = rng.uniform(-2, 2, (400, 3))
    r = disc_vertices(len(c))
    r[:] = rng.uniform(0.05, 0.3, len(c))
    nrm = _unit(rng, len(c))
    shared = RayScene.discs(c, r, nrm)
    copied = RayScene.discs(c, np.array(r), nrm)
    assert np.shares_memory(shared.owner_radii, r) and not np.shares_memory(copied.owner_radii, r)
    assert shared.nbytes == copied.nbytes
    dirs = _unit(rng, 2000)
    a, b = shared.intersect([0, 0, 5.0], dirs, ties=1.0), copied.intersect([0, 0, 5.0], dirs, ties=1.0)
    np.testing.assert_array_equal(a.owners, b.owners)
    np.testing.assert_array_equal(a.distances, b.distances)


@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_discs_skipped_exactly_at_the_reach(offset):
    # a disc just inside or just outside its own radius from the ray origin, far from
    # the scene's centre: the filter's float32 quick test must leave it to float64
    rng = np.random.default_rng(4)
    o = np.array([offset, -offset, 3.0])
    far = o + [40.0, 40.0, 40.0]  # a second disc: the scene's centre is not near the origin
    for k in range(60):
        d = _unit(rng, 1)[0]
        r = float(np.float32(rng.uniform(0.01, 0.5)))  # Embree's radii are float32
        inside = k % 2 == 0
        c = o + d * r * (1 - 1e-9 if inside else 1 + 1e-9)
        assert (np.linalg.norm(c - o) <= r) == inside  # the float64 rule
        scene = RayScene.discs(np.array([c, far]), np.array([r, 0.1]), np.array([d, [1.0, 0, 0]]))
        hits = scene.intersect(o, d[None], skip_containing=True)
        assert hits.owners.tolist() == ([-1] if inside else [0])


@pytest.mark.parametrize("aspect", [None, 2.0])
def test_ties_decided_in_float64_where_the_float32_vertices_disagree(aspect):
    # two coplanar discs 1e-4 m apart, 10 km from the scene's centre (float32 steps of ~1 mm
    # there): the one whose float64 centre is nearest the ray must win, also where the
    # float32 vertices Embree holds rank them the other way round
    a, b = 1e4 + 4.0e-4, 1e4 + 5.0e-4  # float32: 1e4 and 1e4 + 2^-10
    c = np.array([[a, 0.0, 0.0], [b, 0.0, 0.0], [-1e4, 0.0, 0.0]])
    scene = RayScene.discs(c, np.full(3, 0.5), np.tile([0, 0, 1.0], (3, 1)), centre=np.zeros(3))
    v = (c - scene.centre).astype(np.float32).astype(np.float64)
    assert v[0, 0] != v[1, 0]
    d = np.array([0.3, 0.2, -1.0]) if aspect else np.array([0.0, 0.0, -1.0])
    d /= np.linalg.norm(d)
    for x in np.linspace(a - 1e-4, b + 1e-4, 41):
        o = np.array([x, 0.0, 0.0]) - 5.0 * d
        one = scene.intersect(o, d[None], ties=1.0, pulse_aspect=aspect)
        two = scene.intersect(o, d[None], ties=1.0, pulse_aspect=aspect, one_pass=False)
        assert one.owners[0] == two.owners[0] and one.distances[0] == two.distances[0]
        if aspect is None:
            perp = np.linalg.norm(np.cross(c[:2] - o, d), axis=1)
            perp32 = np.linalg.norm(np.cross(v[:2] - (o - scene.centre), d), axis=1)
            assert one.owners[0] == np.argmin(perp)
            if a + 5.5e-5 < x < a + 8.5e-5:  # float32 would take the other one
                assert np.argmin(perp32) != np.argmin(perp)


def test_owners_is_primitives_where_each_primitive_is_its_own_owner():
    # RayHits' documented contract: one array for discs and plain triangles, two for fans
    rng = np.random.default_rng(1)
    c = rng.uniform(-1, 1, (50, 3))
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = RayScene.discs(c, np.full(50, 0.3)).intersect([0.0, 0.0, 5.0], dirs)
    assert hits.owners is hits.primitives
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    f = np.array([[0, 1, 2], [1, 3, 2]])
    plain = RayScene.triangles(v, f).intersect([0.3, 0.3, 1.0], [[0.0, 0.0, -1.0]])
    assert plain.owners is plain.primitives and plain.owners[0] == 0
    fan = RayScene.triangles(v, f, owners=(np.array([[0.5, 0.5, 0.0]]), np.ones(1), 2, 1.0, None))
    h = fan.intersect([0.7, 0.7, 1.0], [[0.0, 0.0, -1.0]])
    assert h.owners is not h.primitives and h.primitives[0] == 1 and h.owners[0] == 0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e39])
def test_non_finite_geometry_is_refused_not_answered_with_misses(bad):
    # a NaN or infinite coordinate, or one float32 cannot hold around the scene's centre, made
    # Embree answer every ray with a miss (the scene's box was NaN): now a clear error
    rng = np.random.default_rng(2)
    c = rng.normal(size=(100, 3))
    c[7, 2] = bad
    with pytest.raises(InputValueError, match="finite"):
        RayScene.discs(c, np.full(100, 0.1))
    with pytest.raises(InputValueError, match="finite"):
        RayScene.triangles(c, np.array([[0, 1, 2], [5, 6, 7]]))
    c[7, 2] = 0.0
    c[3] = [3e38, 0.0, 0.0]  # finite in float64, beyond float32 from the centre it sets
    with pytest.raises(InputValueError, match="float32"):
        RayScene.discs(c, np.full(100, 0.1), centre=[-3e38, 0.0, 0.0])


def test_small_and_large_scenes_count_non_finite_rows_alike():
    # a scene under SERIAL_ROWS rows is checked on one thread: the same count as the parallel pass
    from slr_ray.raycast.scene import _nonfinite_rows, _nonfinite_rows_serial

    rng = np.random.default_rng(5)
    v = rng.normal(size=(5000, 3)).astype(np.float32)
    v[rng.choice(5000, 37, replace=False), rng.integers(0, 3, 37)] = np.inf
    v[11, 0] = np.nan
    assert _nonfinite_rows(v, 5000) == _nonfinite_rows_serial(v, 5000) == np.count_nonzero(~np.isfinite(v).all(axis=1))
    assert _nonfinite_rows_serial(v, 10) == 0


@pytest.mark.parametrize("seed", [0, 1])
def test_quick_build_meets_what_the_default_build_meets(seed):
    # Embree's quick (Morton) build is another BVH over the same triangles: the same first hits, and
    # the brute-force nearest triangle's distance
    rng = np.random.default_rng(seed)
    v = rng.uniform(-5, 5, size=(600, 3))
    f = rng.integers(0, 600, size=(400, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    o = rng.uniform(-1, 1, size=(3000, 3))
    d = _unit(rng, 3000)
    a = RayScene.triangles(v, f).intersect_each(o, d)
    b = RayScene.triangles(v, f, quick=True).intersect_each(o, d)
    np.testing.assert_array_equal(a.primitives, b.primitives)
    np.testing.assert_array_equal(a.distances, b.distances)
    assert (b.primitives >= 0).sum() > 300
    # brute force (Moller-Trumbore in float64) on the hits
    hit = np.flatnonzero(b.primitives >= 0)
    p0, p1, p2 = (v[f[b.primitives[hit], k]] for k in range(3))
    e1, e2 = p1 - p0, p2 - p0
    pv = np.cross(d[hit], e2)
    t = np.einsum("ij,ij->i", np.cross(o[hit] - p0, e1), e2) / np.einsum("ij,ij->i", e1, pv)
    np.testing.assert_allclose(b.distances[hit], t, rtol=1e-4, atol=1e-4)


def test_every_scene_hands_cast_packets_one_argument_type(monkeypatch):
    """numba compiles cast_packets (about 8 s, a cold cache) once for each tuple of argument
    types it meets: discs, one disc, oriented discs, bare triangles, triangles with owners and
    read-only inputs all hand it the same types (they handed it five)."""
    import numba

    from slr_ray.raycast import scene as scene_module

    seen = set()
    real = scene_module.cast_packets
    monkeypatch.setattr(scene_module, "cast_packets",
                        lambda *a: seen.add(tuple(numba.typeof(x) for x in a)) or real(*a))
    rng = np.random.default_rng(0)
    c = rng.normal(size=(20, 3)) + [10.0, 0.0, 0.0]
    frozen = c.copy()
    frozen.flags.writeable = False
    v = np.concatenate([c + [0.0, -0.1, -0.1], c + [0.0, 0.1, -0.1], c + [0.0, 0.0, 0.1]])
    f = np.arange(60).reshape(3, 20).T
    scenes = [RayScene.discs(c, np.full(20, 0.3)), RayScene.discs(frozen, np.full(20, 0.3, np.float32)),
              RayScene.discs(c[:1], [0.3]),
              RayScene.discs(c, np.full(20, 0.3), normals=_unit(rng, 20).astype(np.float32)),
              RayScene.triangles(v, f), RayScene.triangles(v, f, owners=(frozen, np.full(20, 0.3), 1, 1.0, None))]
    for s in scenes:
        s.intersect(np.zeros(3), _unit(rng, 4))
    assert len(seen) == 1, seen
