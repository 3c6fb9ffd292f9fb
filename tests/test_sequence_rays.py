"""The ``rays`` estimator (slr_ray.sequence.rays): the sensor's rays fitted from frames' own points,
each beam cast along its ray onto the union's planes; it must never read the held-out frame's points."""

import dataclasses
import math
import shutil

import numpy as np
import pytest

from slr_ray.io import PointCloud, read_cloud, write_cloud
from slr_ray.errors import InputValueError, SlrWarning
from slr_ray.sequence import convert_sequence, estimate, read_sequence
from slr_ray.sequence.holdout import evaluate_holdout, holdout_ray_model, mean_rows, simulate_holdout
from slr_ray.sequence.union import FrameCache
from slr_ray.sequence.rays import cast_rays, fit_range_bias, fit_ray_model, pattern_ray_model, sweep_offsets
from slr_ray.sequence.synthetic import synthetic_drive
from slr_ray.sensors import sensor


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("rays") / "seq"
    synthetic_drive(root, n_frames=3, sensor="velodyne_vlp16", step=0.8, moving=False)
    return root


@pytest.fixture(scope="module")
def rays_of_frame_1(drive):
    """``rays``' returns for the drive's frame 1 held out (±1 frame, the shipped table's grid)."""
    return simulate_holdout(read_sequence(drive), 1, "rays", sensor="velodyne_vlp16", half=1,
                            pattern=sensor("velodyne_vlp16"))


def test_the_held_out_frames_points_never_change_what_rays_return(drive, rays_of_frame_1, tmp_path):
    """Its points moved along their own rays (its table, beams and pose unchanged) must not move a
    single return: the sensor's rays come from the other frames only."""
    pat = sensor("velodyne_vlp16")
    before = rays_of_frame_1
    moved = tmp_path / "seq"
    shutil.copytree(drive, moved)
    f = moved / "velodyne" / "000001.bin"
    c = read_cloud(f)
    scale = np.random.default_rng(1).uniform(0.6, 1.4, len(c.points))[:, None]
    write_cloud(f, PointCloud(c.points * scale, c.attributes, c.origin))
    after = simulate_holdout(read_sequence(moved), 1, "rays", sensor="velodyne_vlp16", half=1, pattern=pat)
    assert len(before) > 1000
    assert np.array_equal(before.keys, after.keys) and np.array_equal(before.ranges, after.ranges)


def _scan(elev, z0, skew, motion, n_az=720, bias=None):
    """Lasers at ``elev`` crossing the axis at ``z0`` fired from a sensor moving ``motion`` a sweep
    onto a road 1.73 m below walled in 24 by 10 m, stored motion-compensated as KITTI's are."""
    pts, rings = [], []
    for j, (e, h) in enumerate(zip(elev, z0)):
        a = np.linspace(-math.pi, math.pi, n_az, endpoint=False)
        fire = (skew * ((a + math.pi) / (2 * math.pi) - 0.5))[:, None] * motion  # the origin when firing
        o = fire + [0.0, 0.0, h]
        d = np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.full(n_az, np.sin(e))])
        t = np.where(d[:, 2] < -1e-3, (-1.73 - o[:, 2]) / np.minimum(d[:, 2], -1e-3), np.inf)
        for axis, wall in ((0, 12.0), (1, 5.0)):  # a walled yard 24 by 10 m: ranges vary along each ring
            with np.errstate(divide="ignore", invalid="ignore"):
                tw = np.where(d[:, axis] != 0, (np.sign(d[:, axis]) * wall - o[:, axis]) / d[:, axis], np.inf)
            t = np.minimum(t, tw)
        t = t + (0.0 if bias is None else bias[j])  # the laser reads its ranges long or short
        pts.append(o + t[:, None] * d)
        rings.append(np.full(n_az, j))
    return np.vstack(pts), np.concatenate(rings)


def test_a_ray_model_recovers_heights_elevations_and_the_sweeps_skew():
    elev = np.radians([2.0, -1.0, -4.0, -7.0, -10.0, -14.0])
    z0 = np.array([0.21, 0.20, 0.19, 0.10, -0.05, -0.15])
    v = np.array([0.7, 0.02, 0.0])
    frames = [_scan(elev, z0, -1.2, v * s) + (v * s,) for s in (0.9, 1.0, 1.1)]
    m = fit_ray_model(frames, len(elev), stride=1)
    assert m.skew == pytest.approx(-1.2, abs=0.051) and m.source == "fitted"
    assert np.abs(m.height - z0).max() < 0.02 and np.degrees(np.abs(m.elevation - elev)).max() < 0.02
    still = fit_ray_model([f[:2] + (np.zeros(3),) for f in frames], len(elev), stride=1)
    assert still.residual_deg > 10 * m.residual_deg  # the skew not undone: lines no longer fit


def test_the_fit_shares_the_sweep_and_the_lasers_order_over_skews_and_stays_the_brute_force_fit():
    # #46: fit_ray_model makes each point's sweep share and the lasers' order once, not a skew: the same
    # model, bit for bit, as fitting each skew's undone points from scratch (sweep_offsets, _lines)
    from slr_ray.sequence.rays import _lines

    elev = np.radians([2.0, -1.0, -4.0, -7.0, -10.0, -14.0])
    z0 = np.array([0.21, 0.20, 0.19, 0.10, -0.05, -0.15])
    v = np.array([0.7, 0.02, 0.0])
    rng = np.random.default_rng(3)
    frames = []
    for s in (0.9, 1.1):
        p, r = _scan(elev, z0, -0.8, v * s, n_az=240)
        o = rng.permutation(len(p))  # lasers interleaved: the order is the fit's to make
        frames.append((p[o] + rng.normal(scale=0.01, size=p.shape), r[o], v * s))
    skews = [-1.0, -0.85, -0.8, -0.5, 0.0]
    m = fit_ray_model(frames, len(elev), skews=skews, stride=2)
    R = np.concatenate([r[::2] for _, r, _ in frames])
    fits = {k: _lines(np.concatenate([p[::2] - sweep_offsets(p[::2], w, k) for p, _, w in frames]), R, len(elev))
            for k in skews}
    k = min(fits, key=lambda s: (fits[s][2], abs(s)))
    assert m.skew == k
    np.testing.assert_array_equal(m.height, fits[k][0])
    np.testing.assert_array_equal(m.elevation, fits[k][1])
    assert m.residual_deg == round(fits[k][2], 5)


def test_a_laser_that_reads_long_or_short_is_found_against_the_other_frames():
    elev = np.radians(np.linspace(2.0, -14.0, 12))
    z0 = np.zeros(12)
    bias = np.zeros(12)
    bias[[2, 7]] = 0.04, -0.03
    frames = []
    for x in (0.0, 0.5, 1.0):
        pts, rings = _scan(elev, z0, 0.0, np.zeros(3), n_az=1440, bias=bias)
        pose = np.eye(4)
        pose[0, 3] = x
        frames.append((pts + [x, 0, 0], rings, pose, np.zeros(3)))
    model = fit_ray_model([(f[0] - f[2][:3, 3], f[1], f[3]) for f in frames], 12, skews=[0.0], stride=1)
    found = fit_range_bias(model, frames, stride=2).range_bias
    # against planes that hold its own points of the other frames too (as the union's do): a part of it
    assert np.argmax(found) == 2 and np.argmin(found) == 7 and found[2] > 0.01 and found[7] < -0.008, found
    assert fit_range_bias(model, frames[:1]).range_bias is None  # one frame: nothing to compare with


def test_rays_meet_the_plane_not_the_near_edge_of_a_pulse():
    """A dense flat road: each pulse's return lies where the beam's own ray meets the road."""
    pat = sensor("velodyne_vlp16")
    g = np.random.default_rng(0).uniform(-20, 20, (200_000, 2))
    road = np.column_stack([g, np.full(len(g), -1.73)])
    ret = cast_rays(road, pat)
    model = pattern_ray_model(pat)
    row = ret.keys // pat.columns
    exact = 1.73 / np.sin(-model.elevation[pat.beam_of_row[row]])  # lasers by beam id
    near = exact < 15  # well inside the road
    assert near.sum() > 1000 and np.median(np.abs(ret.ranges - exact)[near]) < 0.005
    fpa_err = np.abs(estimate(road, pat, "fpa").ranges - 1.73 / np.sin(-model.elevation[row]))
    assert np.median(fpa_err[near]) > 0.02  # the pulse's footprint averaged, not its ray
    assert np.allclose(sweep_offsets(road[:3], np.zeros(3), -1.2), 0)


def test_mean_row_counts_points_in_whole_points():
    rows = mean_rows([[{"method": "a", "points": 3, "F": 0.5}], [{"method": "a", "points": 4, "F": 0.25}]])
    assert rows[0]["points"] == 4 and isinstance(rows[0]["points"], int) and rows[0]["F"] == 0.375


def test_convert_casts_the_target_tables_own_rays(drive, tmp_path):
    """``convert --estimator rays``: every return of a frame lies on its pulse's centre ray (a simulated
    target's rays), where nearest's lie anywhere in the pulse."""
    seq = read_sequence(drive)
    out = tmp_path / "out"
    out.mkdir()
    summary = convert_sequence(seq, out, "velodyne_vlp16", estimator="rays", half=0)
    assert summary["written"] == 3
    pat = sensor("velodyne_vlp16")
    p = read_cloud(out / "velodyne" / "000001.bin").points.astype(np.float64)
    keys, _ = pat.pulse_ids(p, np.zeros(3))
    dirs, _, _ = pat.rays()
    off = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", p / np.linalg.norm(p, axis=1)[:, None], dirs[keys]),
                                       -1, 1)))
    assert len(p) > 1000 and np.median(off) < 0.001  # float32 storage: a micro-degree
    with pytest.raises(InputValueError, match="unknown estimator"):
        convert_sequence(seq, tmp_path / "no", "velodyne_vlp16", estimator="ray")
    assert not (tmp_path / "no").exists()


def test_frames_that_never_moved_fit_no_skew():
    """No motion in the fitting frames: every skew fits as well, so none is taken (a skew fitted on
    still frames would be applied to a moving target's motion)."""
    elev, z0 = np.radians([2.0, -4.0, -10.0]), np.array([0.2, 0.1, -0.1])
    p, r = _scan(elev, z0, 0.0, np.zeros(3), n_az=180)
    assert fit_ray_model([(p, r, np.zeros(3))] * 2, len(elev), stride=1).skew == 0.0


def test_one_frame_of_unknown_beams_does_not_discard_the_others_fit(drive, tmp_path):
    """A window frame out of scan order (its beams not known) is left out of the ray fit, with a warning;
    the others' fit is kept. The held-out frame out of order: a warning that its grid is the shipped table."""
    moved = tmp_path / "seq"
    shutil.copytree(drive, moved)
    for i in (0, 1):
        f = moved / "velodyne" / f"00000{i}.bin"
        c = read_cloud(f)
        o = np.random.default_rng(i).permutation(len(c.points))
        write_cloud(f, PointCloud(c.points[o], {k: v[o] for k, v in c.attributes.items()}, c.origin))
    seq = read_sequence(moved)
    with pytest.warns(SlrWarning, match="000000.*not known.*left out"):
        model = holdout_ray_model(seq, [0, 2], sensor("velodyne_vlp16"), None, FrameCache(seq))
    assert model.source == "fitted"
    with pytest.warns(SlrWarning, match="000001.*not known.*shipped table"):
        simulate_holdout(seq, 1, "fpa", sensor="velodyne_vlp16", half=1)


def test_a_grid_from_the_other_frames_reads_nothing_of_the_held_out_frame(drive, tmp_path):
    """``grid_from="others"``: the held-out frame's rows tilted (its points' z scaled) leave its scoring
    grid as it was; the default grid (fitted to the frame) moves with them."""
    moved = tmp_path / "seq"
    shutil.copytree(drive, moved)
    f = moved / "velodyne" / "000001.bin"
    c = read_cloud(f)
    write_cloud(f, PointCloud(c.points * [1.0, 1.0, 1.1], c.attributes, c.origin))
    grids = {}
    for name, root in (("before", drive), ("after", moved)):
        for source in ("target", "others"):
            res = evaluate_holdout(read_sequence(root), 1, sensor="velodyne_vlp16", half=1, methods=("nearest",),
                                   grid_from=source)
            grids[name, source] = res["pattern"]["elevation_range_deg"]
    assert grids["before", "others"] == grids["after", "others"]
    assert grids["before", "target"] != grids["after", "target"]
    with pytest.raises(InputValueError, match="grid_from"):
        evaluate_holdout(read_sequence(drive), 1, sensor="velodyne_vlp16", grid_from="self")


def test_rays_are_the_same_a_thousand_kilometres_away(drive, rays_of_frame_1):
    """The poses translated by 1e6 m (a projected CRS): the same returns to float tolerance."""
    seq = read_sequence(drive)
    far = seq.poses.copy()
    far[:, :3, 3] += [1e6, -2e6, 300.0]
    pat = sensor("velodyne_vlp16")
    a = rays_of_frame_1
    b = simulate_holdout(dataclasses.replace(seq, poses=far), 1, "rays", sensor="velodyne_vlp16", half=1, pattern=pat)
    assert len(a) > 1000 and np.array_equal(a.keys, b.keys) and np.allclose(a.ranges, b.ranges, atol=1e-6)


def test_each_lasers_firing_phase_in_its_column_is_fitted_where_its_points_agree():
    # failed before (#45): rays cast every laser through its column's centre; an Ouster's beams fire at the
    # column's edge (0.17 deg off on an OS1-128: 3 cm at 10 m), a Hesai's at its centre
    import math
    from slr_ray.sequence.rays import fit_azimuth_phases
    rng = np.random.default_rng(0)
    columns, D = 1024, 2 * math.pi / 1024
    want = np.array([0.45, -0.45, 0.0, 0.2]) * D
    frames = []
    for _ in range(2):
        pts, beams = [], []
        for laser in range(4):
            h = rng.choice(columns, 500, replace=False)
            az = want[laser] + (h + 0.5) * D + rng.normal(0, 0.01 * D, 500)
            if laser == 3:
                az = rng.uniform(0, 2 * math.pi, 500)  # azimuths spread (a motion-compensated frame): no phase
            r = rng.uniform(2, 30, 500)
            pts.append(np.column_stack([r * np.cos(az), r * np.sin(az), np.zeros(500)]))
            beams.append(np.full(500, laser))
        frames.append((np.concatenate(pts), np.concatenate(beams)))
    got, coherence = fit_azimuth_phases(frames, 4, columns)
    assert np.allclose(got[:3], want[:3], atol=0.02 * D) and got[3] == 0.0
    assert coherence[:3].min() > 0.99 and coherence[3] < 0.2


@pytest.mark.parametrize("stored", ["ring field", "scan order"])
def test_a_laser_too_sparse_to_fit_keeps_its_tables_elevation_in_rays(stored):
    """#46: ``rays``' fit gave a laser with too few points the others' mean elevation (the middle of the
    fan; a Pandar64's 5 deg laser, 8 points a frame, took its neighbour's pulses); it keeps its table's,
    as ``embree-rays``' does (:func:`~slr_ray.sequence.embree_rays.table_unfitted`). The fitted lasers'
    elevations are the fit's own. A frame in scan order (no ring field) gives its beams as the table's
    rows (a VLP-16's table is not top first): the table is read by row there (it was read by id: row 7,
    1 deg, was cast at beam 7's 7 deg); the model's lasers are the table's ids either way (RayModel)."""
    from types import SimpleNamespace

    base = sensor("velodyne_vlp16")
    el = np.radians(np.asarray(base.elevation_deg))
    if stored == "scan order":  # ring after ring, highest first, each a turn from the front
        el = el[base.beam_of_row]
    az = np.radians(np.arange(0, 360, 0.5))
    pts, beams = [], []
    for b, e in enumerate(el):
        a = az[::60] if b == 7 else az  # laser 7: 12 points, 6 at the fit's stride 2, too few for its line
        r = 8.0 + 2.0 * np.sin(3 * a)
        pts.append(np.column_stack([r * np.cos(e) * np.cos(a), r * np.cos(e) * np.sin(a), r * np.sin(e)]))
        beams.append(np.full(len(a), b))
    pts, ring = np.concatenate(pts), np.concatenate(beams)
    frame = SimpleNamespace(points=pts, attributes={"ring": ring.astype(np.uint16)} if stored == "ring field" else {})
    poses = np.repeat(np.eye(4)[None], 3, 0)
    seq = SimpleNamespace(names=["0", "1", "2"], paths=["a", "b", "c"], poses=poses)
    cache = SimpleNamespace(get=lambda i: (frame, pts))
    model = holdout_ray_model(seq, [0, 2], base, None, cache)
    ids = ring if stored == "ring field" else base.beam_of_row[ring]
    sparse = 7 if stored == "ring field" else base.beam_of_row[7]
    fitted = fit_ray_model([(pts, ids, np.zeros(3))] * 2, base.n_beams)
    np.testing.assert_allclose(model.elevation, np.radians(np.asarray(base.elevation_deg)), atol=1e-6)  # by id
    assert np.array_equal(np.delete(model.elevation, sparse), np.delete(fitted.elevation, sparse))
    assert np.abs(np.delete(model.elevation, sparse) - model.elevation[sparse]).min() > np.radians(0.5)


def test_a_tables_ideal_rays_are_by_beam_id_and_cast_as_the_same_rays_by_row():
    """#46: :func:`pattern_ray_model`'s lasers are the table's beam ids (a Pandar64's ids are not in
    elevation order), as a fitted model's (RayModel: one order, whatever the source); cast, the same rays
    listed by row (highest first) return the same pulses."""
    import dataclasses

    pat = sensor("hesai_pandar64_pjlab").with_(columns=360)
    assert not np.array_equal(pat.beam_of_row, np.arange(pat.n_beams))  # ids not in elevation order
    m = pattern_ray_model(pat)
    np.testing.assert_allclose(np.degrees(m.elevation), np.asarray(pat.elevation_deg))
    np.testing.assert_allclose(np.degrees(m.azimuth_offset), np.asarray(pat.azimuth_offset_deg))
    assert not m.height.any() and m.range_bias is None
    by_id = dataclasses.replace(m, elevation=m.elevation[pat.beam_of_row], azimuth_offset=m.azimuth_offset[pat.beam_of_row])
    rng = np.random.default_rng(0)
    xy = rng.uniform(-30, 30, (15_000, 2))
    road = np.column_stack([xy, np.full(len(xy), -1.8)])
    a = rng.uniform(-np.pi, np.pi, 8_000)
    wall = np.column_stack([20 * np.cos(a), 20 * np.sin(a), rng.uniform(-1.8, 6, len(a))])
    u = np.concatenate([road, wall])
    got, want = cast_rays(u, pat, m), cast_rays(u, pat, by_id)
    assert len(got) > 1000
    assert np.array_equal(got.keys, want.keys) and np.allclose(got.ranges, want.ranges)


@pytest.mark.parametrize("name", ["velodyne_vlp16", "hesai_pandar64_pjlab"])
def test_a_ray_models_dict_is_by_beam_id_whatever_gave_the_beams_and_reads_back(name):
    """A sensor's ``ray_model`` (RayModel.to_dict, in ``sequence evaluate``'s results) listed its lasers by
    the table's ids where the frames had a ring field, by its rows where they were in scan order: the same
    unit gave two dicts (a VLP-16's and a Pandar64's ids are not in elevation order). The lists are by id
    whatever the source (a table's ideal rays too), and :meth:`RayModel.from_dict` reads them back."""
    from types import SimpleNamespace

    from slr_ray.sequence.methods.rays import holdout_ray_model
    from slr_ray.sequence.rays import RayModel

    base = sensor(name)
    az = np.radians(np.arange(0, 360, 1.0))
    dicts = []
    for stored in ("ring field", "scan order"):
        ids = np.arange(base.n_beams) if stored == "ring field" else base.beam_of_row  # scan order: top first
        pts = np.concatenate([np.column_stack([(8 + 2 * np.sin(3 * az)) * np.cos(e) * np.cos(az),
                                               (8 + 2 * np.sin(3 * az)) * np.cos(e) * np.sin(az),
                                               (8 + 2 * np.sin(3 * az)) * np.sin(e)])
                              for e in np.radians(np.asarray(base.elevation_deg))[ids]])
        ring = np.repeat(ids, len(az)).astype(np.uint16)
        frame = SimpleNamespace(points=pts, attributes={"ring": ring} if stored == "ring field" else {})
        seq = SimpleNamespace(names=["0", "1", "2"], paths=["a", "b", "c"], poses=np.repeat(np.eye(4)[None], 3, 0))
        model = holdout_ray_model(seq, [0, 2], base, None, SimpleNamespace(get=lambda i, f=frame: (f, f.points)))
        dicts.append(model.to_dict())
    assert dicts[0] == dicts[1]
    np.testing.assert_allclose(dicts[0]["elevation_deg"], base.elevation_deg, atol=1e-3)
    for d in (dicts[0], pattern_ray_model(base).to_dict()):
        back = RayModel.from_dict(d)
        assert back.to_dict() == d
    np.testing.assert_allclose(pattern_ray_model(base).to_dict()["elevation_deg"], base.elevation_deg, atol=1e-4)
    with pytest.raises(ValueError, match="per-laser"):
        RayModel.from_dict({**dicts[0], "lasers": base.n_beams + 1})
