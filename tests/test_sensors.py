"""Beam tables: binning against a brute-force reference, scans of meshes with each
shipped sensor, idempotence, range images, readers of calibration files."""

import json
import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings, strategies as st

import slr_ray
from slr_ray import prepare, scan_mesh
from slr_ray.errors import InputValueError
from slr_ray.sensors import SENSORS, BeamPattern, read_ouster_metadata, read_velodyne_calibration, sensor


def brute_keys(points, origin, p: BeamPattern):
    """The documented definition, one point at a time in plain Python."""
    el = np.asarray(p.elevation_deg)
    rows = sorted(range(p.n_beams), key=lambda b: -el[b])
    zen = [math.radians(90 - el[b]) for b in rows]
    n = len(zen)
    edges = ([zen[0] - (zen[1] - zen[0]) / 2] + [(zen[i] + zen[i + 1]) / 2 for i in range(n - 1)]
             + [zen[-1] + (zen[-1] - zen[-2]) / 2]) if n > 1 else [zen[0] - math.radians(0.5),
                                                                     zen[0] + math.radians(0.5)]
    rmin, rmax = p.range_limits
    cos_e = [math.cos(e) for e in edges]
    out = []
    for x, y, z in np.asarray(points, float) - origin:
        r = math.sqrt(x * x + y * y + z * z)
        if not (r > 0) or r < rmin or r > rmax:
            out.append(-1)
            continue
        c = z / r  # zenith in [e_i, e_i+1)  <=>  cos(e_i+1) < c <= cos(e_i)
        hit = [i for i in range(n) if cos_e[i + 1] < c <= cos_e[i]]
        if not hit:
            out.append(-1)
            continue
        row = hit[0]
        a = math.atan2(y, x) - math.radians(p.azimuth_offset_deg[rows[row]])
        a -= 2 * math.pi * math.floor(a / (2 * math.pi))
        col = min(p.columns - 1, int(math.floor(a / (2 * math.pi / p.columns))))
        out.append(row * p.columns + col)
    return np.array(out)


def test_every_shipped_sensor_loads_with_its_source():
    assert len(SENSORS) == 16  # eight calibration tables, eight cards fitted from frames (#45)
    for name in SENSORS:
        p = sensor(name)
        fitted = "fit" in p.meta
        assert (p.n_beams in (16, 32, 64, 128) or fitted) and p.columns >= (600 if fitted else 1000)
        assert p.meta["source"] and (not fitted or "Apache-2.0" in p.meta["source"])
        assert np.all(np.diff(p.band_edges) > 0)
        el = np.asarray(p.elevation_deg)[p.beam_of_row]
        assert np.all(np.diff(el) < 0)  # rows: highest beam first
        assert slr_ray.as_pattern(name).shape == p.shape


@pytest.mark.parametrize("name", ["velodyne_hdl64e_s2", "ouster_os1_64", "velodyne_vlp16"])
@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_binning_matches_the_definition(name, seed):
    p = sensor(name, max_range=60.0, min_range=0.5)
    rng = np.random.default_rng(seed)
    origin = np.array([4.5e5, 5.2e6, 80.0])  # UTM-like: subtracted in float64 first
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # aim a third of the points at band edges and the azimuth wrap
    k = 1000
    edges = p.band_edges[rng.integers(0, len(p.band_edges), k)] + rng.normal(scale=1e-9, size=k)
    az = rng.choice([0.0, 2 * math.pi, math.pi], k) + rng.normal(scale=1e-9, size=k)
    d[:k] = np.column_stack([np.sin(edges) * np.cos(az), np.sin(edges) * np.sin(az), np.cos(edges)])
    pts = origin + d * rng.uniform(0.1, 80, (3000, 1))
    keys, _ = p.pulse_ids(pts, origin)
    np.testing.assert_array_equal(keys, brute_keys(pts, origin, p))
    scan = prepare(pts).scan(origin, p)
    # nearest per key, ties to the lowest index
    want = {}
    r = np.linalg.norm(pts - origin, axis=1)
    for i in np.flatnonzero(keys >= 0):
        if keys[i] not in want or r[i] < r[want[keys[i]]]:
            want[keys[i]] = i
    assert scan.indices.tolist() == sorted(want.values())
    assert np.all(scan.rings == p.beam_of_row[scan.pulses[:, 0]])


def _plane():
    return trimesh.Trimesh([[-60, -60, -1.7], [60, -60, -1.7], [60, 60, -1.7], [-60, 60, -1.7]],
                           [[0, 1, 2], [0, 2, 3]])


def _cylinder():
    c = trimesh.creation.cylinder(radius=6.0, height=40.0, sections=128)
    c.invert()  # seen from inside
    return c


def _room():
    box = trimesh.creation.box(extents=[16, 12, 6])
    box.invert()  # inside faces
    cyl = trimesh.creation.cylinder(radius=0.8, height=6.0)
    cyl.apply_translation([3.0, 2.0, 0.0])
    return trimesh.util.concatenate([box, cyl])


@pytest.mark.parametrize("name", SENSORS)
@pytest.mark.parametrize("shape", ["plane", "cylinder", "room"])
def test_a_sensors_own_frame_comes_back_whole(name, shape):
    """A plane, a cylinder and a room with a pillar scanned with the sensor (one
    ray per beam and column): every point lies in its ring's elevation band and
    its column; binning the frame from the same origin returns all of it."""
    p = sensor(name)
    origin = np.array([-1.0, 0.5, 0.3])
    mesh = {"plane": _plane, "cylinder": _cylinder, "room": _room}[shape]()
    frame = scan_mesh(mesh, origin, p)
    if shape != "plane":
        assert len(frame) > 0.9 * p.n_pulses  # closed: (almost) every ray hits
    else:
        assert len(frame) > 0
    keys, _ = p.pulse_ids(frame.points, origin)
    np.testing.assert_array_equal(keys, p.ravel(frame.pulses))
    scan = prepare(frame.points).scan(origin, p)
    assert len(scan) == len(frame)
    np.testing.assert_array_equal(scan.pulses, frame.pulses[scan.indices])


def test_embree_casts_the_beams_true_directions():
    p = sensor("velodyne_vlp16")
    origin = np.zeros(3)
    frame = scan_mesh(_room(), origin, p)
    emb = prepare(frame.points, "embree").scan(origin, p)
    assert len(emb) >= 0.95 * len(frame)
    np.testing.assert_array_equal(emb.pulses, frame.pulses[emb.indices])


def test_range_image_round_trips_to_the_scan():
    p = sensor("ouster_os1_64")
    frame = scan_mesh(_room(), [0, 0, 0], p)
    scan = prepare(frame.points).scan([0, 0, 0], p)
    img = scan.range_image({"label": frame.labels})
    assert img["range"].shape == p.shape and img["index"].shape == p.shape
    filled = img["index"] >= 0
    assert filled.sum() == len(scan)
    assert sorted(img["index"][filled].tolist()) == scan.indices.tolist()
    r, c = scan.pulses.T
    np.testing.assert_array_equal(img["index"][r, c], scan.indices)
    np.testing.assert_allclose(img["range"][r, c], scan.ranges.astype(np.float32))
    np.testing.assert_array_equal(img["label"][r, c], frame.labels[scan.indices])
    np.testing.assert_array_equal(img["ring"], p.beam_of_row)


def test_offsets_and_outer_beams_at_their_extremes():
    p = BeamPattern([10.0, -30.0, 0.0], columns=4, azimuth_offset_deg=[179.9, -180.0, 90.0])
    # rows by elevation: 10 (beam 0), 0 (beam 2), -30 (beam 1); the outer bands reach half a gap
    assert p.beam_of_row.tolist() == [0, 2, 1]
    np.testing.assert_allclose(np.degrees(p.band_edges), [75, 85, 105, 135])
    pts = np.array([[math.cos(math.radians(e)) * math.cos(math.radians(a)),
                     math.cos(math.radians(e)) * math.sin(math.radians(a)), math.sin(math.radians(e))]
                    for e, a in ((14.9, 180.0), (15.1, 0.0), (-44.9, 0.0), (-45.1, 0.0), (0.0, 89.9))])
    keys, _ = p.pulse_ids(pts, np.zeros(3))
    np.testing.assert_array_equal(keys, brute_keys(pts, np.zeros(3), p))
    assert keys[1] == -1 and keys[3] == -1 and keys[0] >= 0 and keys[2] >= 0
    one = BeamPattern([0.0], columns=1)
    assert one.pulse_ids(np.array([[1.0, 0, 0], [-1.0, 0.0, 0.0]]), np.zeros(3))[0].tolist() == [0, 0]
    with pytest.raises(InputValueError):
        BeamPattern([1.0, 1.0], columns=10)
    with pytest.raises(InputValueError):
        BeamPattern([1.0, 2.0], columns=0)
    with pytest.raises(InputValueError):
        slr_ray.ScanAccumulator([0, 0, 0], p)


def test_readers_of_user_calibrations(tmp_path):
    vel = {"lasers": [{"laser_id": 1, "vert_correction": math.radians(-15.0), "rot_correction": 0.01},
                      {"laser_id": 0, "vert_correction": math.radians(1.0), "rot_correction": -0.02}]}
    import yaml

    (tmp_path / "v.yaml").write_text(yaml.safe_dump(vel))
    p = read_velodyne_calibration(tmp_path / "v.yaml", columns=900)
    assert p.elevation_deg == pytest.approx((1.0, -15.0)) and p.columns == 900
    assert p.azimuth_offset_deg == pytest.approx((math.degrees(-0.02), math.degrees(0.01)))
    ous = {"beam_intrinsics": {"beam_altitude_angles": [2.0, -1.0], "beam_azimuth_angles": [3.1, -3.1]},
           "data_format": {"columns_per_frame": 512}}
    (tmp_path / "o.json").write_text(json.dumps(ous))
    q = read_ouster_metadata(tmp_path / "o.json")
    assert q.elevation_deg == (2.0, -1.0) and q.azimuth_offset_deg == (3.1, -3.1) and q.columns == 512
    with pytest.raises(InputValueError):
        read_velodyne_calibration(tmp_path / "o.json")  # JSON is YAML, but has no lasers
    with pytest.raises(InputValueError):
        read_ouster_metadata(_write(tmp_path / "bad.json", "{}"))


def _write(path, text):
    path.write_text(text)
    return path


def test_cli_sensor_scan_with_range_image_and_labels(tmp_path, capsys):
    from slr_ray.cli import main
    from slr_ray.io import PointCloud, read_cloud, write_cloud

    frame = scan_mesh(_room(), [0, 0, 0], sensor("velodyne_hdl64e_s2"))
    src = tmp_path / "velodyne" / "000000.bin"
    src.parent.mkdir()
    write_cloud(src, PointCloud(frame.points, {"intensity": np.ones(len(frame), np.float32),
                                               "semantic": frame.labels.astype(np.uint16),
                                               "instance": np.zeros(len(frame), np.uint16)}))
    assert (tmp_path / "velodyne" / "000000.label").exists()
    out = tmp_path / "vlp16.bin"
    assert main(["scan", str(src), "--sensor", "velodyne_vlp16", "--origin", "0.5", "0", "0", "-o", str(out),
                 "--range-image", str(tmp_path / "ri.npz"), "--png", str(tmp_path / "ri.png")]) == 0
    res = json.loads(capsys.readouterr().out)
    back = read_cloud(out)
    assert len(back) == res["points_out"] > 0
    assert set(np.unique(back.attributes["semantic"])) <= set(np.unique(frame.labels))
    ri = np.load(tmp_path / "ri.npz")
    assert ri["range"].shape == (16, 1800) and (ri["index"] >= 0).sum() == len(back)
    assert "semantic" in ri.files
    # an output that cannot be written is refused before the scan: nothing is left behind
    assert main(["scan", str(src), "--sensor", "velodyne_vlp16", "--origin", "0", "0", "0", "-o",
                 str(tmp_path / "none.bin"), "--range-image", str(tmp_path / "missing" / "ri.npz")]) == 2
    assert not (tmp_path / "none.bin").exists() and not (tmp_path / "none.label").exists()
    capsys.readouterr()
    ply = tmp_path / "rings.ply"
    assert main(["scan", str(src), "--sensor", "velodyne_vlp16", "--origin", "0.5", "0", "0", "-o", str(ply),
                 "--keep-ring"]) == 0
    capsys.readouterr()
    rings = read_cloud(ply)
    p16 = sensor("velodyne_vlp16")
    keys, _ = p16.pulse_ids(rings.points, np.array([0.5, 0, 0]))
    np.testing.assert_array_equal(p16.beam_of_row[keys // p16.columns], rings.attributes["ring"])
    np.testing.assert_array_equal(keys % p16.columns, rings.attributes["column"])
    assert main(["scan", str(src), "--sensor", "velodyne_vlp16", "--resolution", "1", "--origin", "0", "0", "0",
                 "-o", str(tmp_path / "x.bin")]) == 2


def test_compare_backends_with_a_sensor():
    from slr_ray.compare import compare_backends

    frame = scan_mesh(_room(), [0, 0, 0], sensor("velodyne_vlp16"))
    res = compare_backends(frame.points, [[0.5, 0.2, 0.0]], sensor("velodyne_vlp16"))
    assert res["positions"][0]["binning"] > 0 and res["positions"][0]["embree"] > 0


def test_miscalibrated_moves_every_beam_by_the_given_spread_and_repeats():
    from slr_ray.sensors import miscalibrated

    nominal = sensor("velodyne_hdl64e_s2")
    a = miscalibrated(nominal, elevation_sd=0.2, azimuth_sd=0.5, seed=3)
    b = miscalibrated(nominal, elevation_sd=0.2, azimuth_sd=0.5, seed=3)
    # the same draws for the same seed
    assert (a.elevation_deg, a.azimuth_offset_deg) == (b.elevation_deg, b.azimuth_offset_deg)
    de = np.array(a.elevation_deg) - np.array(nominal.elevation_deg)
    da = np.array(a.azimuth_offset_deg) - np.array(nominal.azimuth_offset_deg)
    assert 0.1 < de.std() < 0.3 and 0.3 < da.std() < 0.7
    assert a.columns == nominal.columns and a.shape == nominal.shape
    same = miscalibrated(nominal, 0.0, 0.0)
    assert (same.elevation_deg, same.azimuth_offset_deg) == (nominal.elevation_deg, nominal.azimuth_offset_deg)
    with pytest.raises(InputValueError, match="BeamPattern"):
        miscalibrated(slr_ray.ScanPattern(1.0))
    with pytest.raises(InputValueError, match="elevation_sd"):
        miscalibrated(nominal, elevation_sd=-1)


def test_sensor_noise_moves_points_along_their_rays_and_drops_a_share():
    from slr_ray.sensors import sensor_noise

    rng = np.random.default_rng(0)
    o = np.array([1e6, -2e6, 10.0])
    d = rng.normal(size=(20000, 3))
    pts = o + d / np.linalg.norm(d, axis=1)[:, None] * rng.uniform(2, 50, (20000, 1))
    beams = rng.integers(0, 16, 20000)
    before = pts.copy()
    out, kept = sensor_noise(pts, o, beams, range_sd=0.01, beam_range_sd=0.05, dropout=0.25, seed=1)
    np.testing.assert_array_equal(pts, before)  # the input is not changed
    assert abs(len(kept) / len(pts) - 0.75) < 0.02
    u = (pts[kept] - o) / np.linalg.norm(pts[kept] - o, axis=1)[:, None]
    step = ((out - pts[kept]) * u).sum(1)
    np.testing.assert_allclose(out - pts[kept], step[:, None] * u, atol=1e-8)  # along the ray
    # one offset per beam: the within-beam spread is the range noise
    within = [step[beams[kept] == b].std() for b in range(16)]
    assert 0.008 < np.mean(within) < 0.012
    assert np.std([step[beams[kept] == b].mean() for b in range(16)]) > 0.02
    out2, kept2 = sensor_noise(pts, o, beams, range_sd=0.01, beam_range_sd=0.05, dropout=0.25, seed=1)
    np.testing.assert_array_equal(out, out2)
    with pytest.raises(InputValueError, match="dropout"):
        sensor_noise(pts, o, beams, dropout=1.0)
    with pytest.raises(InputValueError, match="beams"):
        sensor_noise(pts, o, beams[:-1])
    with pytest.raises(InputValueError, match="beams must be integers"):
        sensor_noise(pts, o, beams - 1)
    with pytest.raises(InputValueError, match="range_sd"):
        sensor_noise(pts, o, beams, range_sd=-0.01)


@pytest.mark.parametrize("content", [
    {"beam_altitude_angles": [-10.0, 0.0, 1e400], "beam_azimuth_angles": [0.0] * 3, "columns_per_frame": 512},
    {"beam_altitude_angles": [-10.0, 0.0, 10.0], "beam_azimuth_angles": [0.0] * 2, "columns_per_frame": 512},
    {"beam_altitude_angles": [0.0, 0.0], "beam_azimuth_angles": [0.0] * 2, "columns_per_frame": 512},
    {"beam_altitude_angles": [-10.0, 10.0], "beam_azimuth_angles": [0.0] * 2, "columns_per_frame": 10**12}])
def test_a_sensor_file_of_impossible_values_is_named_in_the_error(tmp_path, content):
    path = tmp_path / "meta.json"
    path.write_text(json.dumps(content))
    with pytest.raises(InputValueError, match=f"^{path}: "):  # was: "elevation_deg must be ..." of no file
        read_ouster_metadata(path)


def test_a_fitted_pattern_takes_its_columns_from_azimuth_not_from_the_files_order():
    # failed before (#45): the step was taken between points next in the file; a Hesai PCD lists a beam's
    # points out of firing order (steps -0.2, +0.8, -0.4 ...), which halved its 1800 columns to 900
    from slr_ray.sensors import fitted_pattern
    rng = np.random.default_rng(0)
    base = BeamPattern((5.0, 0.0, -5.0), 100, name="toy")
    az = np.radians((np.arange(1800) + 0.5) * 0.2)
    pts, beams = [], []
    for b, e in enumerate(np.radians([5.0, 0.0, -5.0])):
        pts.append(10 * np.stack([np.cos(e) * np.cos(az), np.cos(e) * np.sin(az), np.full_like(az, np.sin(e))], 1))
        beams.append(np.full(len(az), b))
    order = rng.permutation(3 * len(az))
    p, b = np.concatenate(pts)[order], np.concatenate(beams)[order]
    assert fitted_pattern(p, b, base).columns == 1800


@pytest.mark.parametrize("field, value, said", [
    ("drop_rate", [1.5] * 16, "its drop_rate must be a list of 16 values, one a beam, each a rate in [0, 1]; got 1.5"),
    ("drop_rate", [0.1] * 3, "its drop_rate must be a list of 16 values, one a beam; got list of 3"),
    ("points", [-1] * 16, "its points must be a list of 16 values, one a beam, each a count >= 0"),
    ("height_m", [float("nan")] * 16, "its height_m must be a list of 16 values"),
    ("beams", 17, "its beams (17) is not the number of its elevation_deg (16)"),
    ("range_accuracy_m", -0.03, "its range_accuracy_m must be a finite number >= 0"),
])
def test_a_cards_fields_out_of_range_are_refused_on_load_naming_the_field(tmp_path, capsys, field, value, said):
    """A sensor card's own fields are checked when it is read (a drop rate of 1.5 was read as it was): one line
    naming the field, in the library and on the command line (exit 2)."""
    import json

    from slr_ray.cli import main
    from slr_ray.errors import SlrError
    from slr_ray.sensors import card_dict, read_card

    d = card_dict(sensor("velodyne_vlp16")) | {"drop_rate": [0.0] * 16, field: value}
    path = tmp_path / "card.json"
    path.write_text(json.dumps(d))
    with pytest.raises(SlrError) as err:
        read_card(path)
    assert said in str(err.value) and "\n" not in str(err.value)
    assert main(["sequence", "convert", str(tmp_path / "nowhere"), "--target-sensor", str(path), "-o",
                 str(tmp_path / "o")]) == 2
    e = capsys.readouterr().err
    assert e.count("\n") == 1 and e.startswith("slr-ray: error:") and said in e, e


@pytest.mark.parametrize("name", ["velodyne_vlp16", "hesai_pandar64_pjlab"])
def test_a_fitted_pattern_is_by_beam_id_whether_its_beams_came_as_ids_or_rows(name):
    """``fitted_pattern`` took its beams for the table's ids; given a frame's scan order (rows, a KITTI
    ``.bin``'s: ``slr_ray.evaluate``'s 'scan-order' beams) it gave row ``i``'s median to beam ``i`` and a row
    with no point another beam's elevation (a VLP-16's and a Pandar64's ids are not in elevation order).
    Beam ``i`` of the fit is the table's beam ``i`` whichever way its beams came (``rows=True``, and
    'scan-order' beams are ids)."""
    from slr_ray.evaluate import frame_beams
    from slr_ray.sensors import fitted_pattern

    base = sensor(name).with_(columns=360)
    unit = base.with_(elevation_deg=tuple(np.asarray(base.elevation_deg) + 0.2), azimuth_offset_deg=None)
    dirs, rows, _ = unit.rays()  # row after row, each a turn from the front: a scan order
    pts = dirs * 10.0
    assert not np.array_equal(base.beam_of_row, np.arange(base.n_beams))
    ids = base.beam_of_row[rows]
    want = np.asarray(unit.elevation_deg)
    by_id, by_row = fitted_pattern(pts, ids, base), fitted_pattern(pts, rows, base, rows=True)
    np.testing.assert_allclose(by_id.elevation_deg, want, atol=1e-6)
    assert by_row.elevation_deg == by_id.elevation_deg and by_row.columns == by_id.columns == 360
    beams, how = frame_beams(pts, "scan-order", base)
    assert how == "scan order" and np.array_equal(beams, ids)
    np.testing.assert_allclose(fitted_pattern(pts, beams, base).elevation_deg, want, atol=1e-6)
    gone = rows != 3  # a row with no point keeps its own beam's table elevation
    part = fitted_pattern(pts[gone], rows[gone], base, rows=True)
    lost = base.beam_of_row[3]
    assert part.elevation_deg[lost] == base.elevation_deg[lost]
    np.testing.assert_allclose(np.delete(part.elevation_deg, lost), np.delete(want, lost), atol=1e-6)
    with pytest.raises(ValueError, match="rows=True"):
        fitted_pattern(pts, rows + base.n_beams, base, rows=True)


def test_a_card_whose_elevations_look_like_radians_is_warned_of(tmp_path):
    # (hostile2 pass) a beam table written with radians under elevation_deg (a VLP-16's -15..+15 deg as
    # -0.26..+0.26) was taken as a 16-beam unit 0.5 deg tall: scans and conversions of a few hundred
    # points and no word; every shipped unit spans 10 deg or more
    import warnings
    from slr_ray.errors import SlrWarning
    from slr_ray.sensors import _shipped_table, read_card, read_sensor_file
    for name in SENSORS:
        table = _shipped_table(name)
        for radians in (False, True):
            d = dict(table, elevation_deg=[math.radians(e) if radians else e for e in table["elevation_deg"]])
            for reader in (read_card, read_sensor_file):
                path = tmp_path / f"{name}_{radians}_{reader.__name__}.json"
                path.write_text(json.dumps(d))
                with warnings.catch_warnings(record=True) as w:
                    warnings.simplefilter("always")
                    reader(path)
                    reader(path)  # a command reads a card more than once: said once
                said = [str(x.message) for x in w if issubclass(x.category, SlrWarning) and "radians" in str(x.message)]
                assert len(said) == radians, (name, reader.__name__, said)
                assert all(str(path) in s for s in said)
