"""Cross-sensor scoring (#45 item 3): frame B of another unit re-simulated from frame A at B's pose."""

import json
import math

import numpy as np
import pytest

from slr_ray.errors import InputValueError, SlrWarning
from slr_ray.evaluate import REACH, evaluate_pair, reach_table, rig_extrinsic
from slr_ray.sensors import sensor

from conftest import DATA as SHARED_DATA, CliRun
from test_evaluate import room

DATA = SHARED_DATA / "hesai_p64_qt64"
SOURCE = sensor("velodyne_hdl64e_s2", columns=720, max_range=120.0)
TARGET = sensor("velodyne_vlp16", columns=720, max_range=100.0)
YAW = math.radians(30.0)
POSE_B = np.array([[math.cos(YAW), -math.sin(YAW), 0, 0.6], [math.sin(YAW), math.cos(YAW), 0, 0.3],
                   [0, 0, 1, -0.4], [0, 0, 0, 1.0]])


@pytest.fixture(scope="module")
def rig():
    """A room scanned by an HDL-64E at the origin (A, with its beams) and by a VLP-16 at POSE_B (B, in its
    own turned frame, no beams): two shipped cards at two poses."""
    from slr_ray import scan_mesh

    mesh = room()
    a = scan_mesh(mesh, [0.0, 0, 0], SOURCE)
    b = scan_mesh(mesh, POSE_B[:3, 3], TARGET)
    b_local = (b.points - POSE_B[:3, 3]) @ POSE_B[:3, :3]  # R^T (p - t): B's own axes
    return a.points, SOURCE.beam_of_row[a.pulses[:, 0]], b_local


def _pair(rig, **kw):
    a, a_beams, b = rig
    kw = {"source_sensor": SOURCE, "target_sensor": TARGET, "methods": ("zbuffer", "binning")} | kw
    return evaluate_pair(a, b, a_beams=a_beams, b_beams=None, **kw)


def test_a_second_sensor_is_scored_split_by_what_the_source_could_see(rig):
    res = _pair(rig, transform=POSE_B, methods=("zbuffer", "binning", "embree-knn"))
    assert res["cross_sensor"] and res["patterns"]["b"]["beams"] == "none"
    zb, em = ({r["method"]: r for r in res["rows"]}[m]["points"] for m in ("zbuffer", "embree-knn"))
    # the VLP-16's own rays cast onto A's discs land on its beam lines: far more precise than every A point
    # in its view (binning's nearest point of a 2 deg band is not on the line: its image is the z-buffer's)
    assert em["fscore"]["5cm"]["precision"] > zb["fscore"]["5cm"]["precision"] + 0.1
    assert em["fscore"]["5cm"]["fscore"] > zb["fscore"]["5cm"]["fscore"]
    assert res["images_identical"]["zbuffer vs binning"]
    reach = res["source_reach"]
    # every real point in view and every pulse has one part; none is dropped
    assert sum(reach["points"].values()) == res["frames"]["b_points_in_view"] == zb["target_points"]
    assert sum(reach["pulses"].values()) == TARGET.n_pulses
    # the VLP-16 looks up to +15 deg, the HDL-64E to +2: the ceiling beyond is outside the source's view
    assert reach["points"]["outside source FOV"] > 100 and reach["points"]["seen by source"] > 100
    for r in res["rows"]:
        groups = r["points"]["groups"]["source"]
        assert sum(g["target_points"] for g in groups.values()) == r["points"]["target_points"]
        assert sum(g["simulated_points"] for g in groups.values()) == r["points"]["simulated_points"]
        assert sum(g["pulses"] for g in r["image"]["groups"]["source"].values()) == TARGET.n_pulses
    rows = reach_table(res)
    assert len(rows) == 3 * (len(REACH) + 1) and {r["part"] for r in rows} == {*REACH, "no return"}


def test_an_extrinsic_is_the_inverse_of_the_pose(rig):
    one = {"methods": ("binning",)}
    by_pose, by_extrinsic = _pair(rig, transform=POSE_B, **one), _pair(rig, extrinsic=np.linalg.inv(POSE_B), **one)
    assert np.allclose(by_pose["registration"]["transform"], by_extrinsic["registration"]["transform"], atol=1e-12)
    assert [r["points"]["fscore"] for r in by_pose["rows"]] == [r["points"]["fscore"] for r in by_extrinsic["rows"]]


def test_cross_sensor_refusals(rig):
    with pytest.raises(InputValueError, match="give B's pose"):  # another unit: no registration from identity
        _pair(rig)
    with pytest.raises(InputValueError, match="transform and extrinsic"):
        _pair(rig, transform=POSE_B, extrinsic=np.linalg.inv(POSE_B))
    with pytest.raises(InputValueError, match="no such sensor card"):
        _pair(rig, target_sensor="no_such_card.json", transform=POSE_B)
    skewed = POSE_B.copy()
    skewed[:3, :3] *= 1.2
    with pytest.raises(InputValueError, match="extrinsic"):  # a scale, not a hand calibration's rounding
        _pair(rig, extrinsic=skewed)


def test_a_hand_calibrations_extrinsic_is_taken_as_its_nearest_rotation():
    E = np.linalg.inv(POSE_B)
    E[:3, :3] *= 1.01
    with pytest.warns(SlrWarning, match="nearest rotation"):
        fixed = rig_extrinsic(E)
    assert np.allclose(fixed, np.linalg.inv(POSE_B), atol=1e-9)


def test_cli_cross_sensor_flags(tmp_path, capsys):
    run = CliRun(capsys)
    a, b = tmp_path / "a.xyz", tmp_path / "b.xyz"
    a.write_text("1 0 0\n")
    b.write_text("1 0 0\n")
    r = run("evaluate", a, b, "-o", tmp_path / "o", "--target-sensor", "velodyne_vlp16")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--transform" in r.stderr and "--extrinsic" in r.stderr
    r = run("evaluate", a, b, "-o", tmp_path / "o", "--target-sensor", "nope")
    assert r.returncode == 2 and "neither a shipped sensor" in r.stderr
    pose = tmp_path / "pose.txt"
    np.savetxt(pose, np.eye(4))
    r = run("evaluate", a, b, "-o", tmp_path / "o", "--target-sensor", tmp_path / "missing.json", "--transform", pose)
    assert r.returncode == 2 and "--target-sensor: " in r.stderr and "missing.json" in r.stderr
    assert r.stderr.count("\n") == 1
    (tmp_path / "card.json").write_text('{"name": "not a card"}')
    r = run("evaluate", a, b, "-o", tmp_path / "o", "--target-sensor", tmp_path / "card.json", "--transform", pose)
    assert r.returncode == 2 and "not a sensor card" in r.stderr and r.stderr.count("\n") == 1
    r = run("evaluate", a, b, "-o", tmp_path / "o", "--sensor", "velodyne_vlp16", "--source-sensor", "velodyne_vlp16")
    assert r.returncode == 2 and "--sensor is its old name" in r.stderr
    r = run("evaluate", a, b, "-o", tmp_path / "o", "--sensor", "velodyne_vlp16")  # the old name still works
    assert "warning: evaluate --sensor is --source-sensor now" in r.stderr and r.returncode == 2  # tiny frames


def test_cli_reads_a_rigs_extrinsic_json(tmp_path):
    from slr_ray.cli.evaluate_command import read_extrinsic

    E = np.linalg.inv(POSE_B)
    p = tmp_path / "rig.json"
    p.write_text(json.dumps({"a-to-b": {"param": {"sensor_calib": {"data": E.tolist(), "rows": 4}}}}))
    assert np.array_equal(read_extrinsic(p), E)
    p.write_text(json.dumps({"one": E.tolist(), "two": E.tolist()}))
    with pytest.raises(InputValueError, match="2 4 x 4 matrices"):
        read_extrinsic(p)
    p.write_text(json.dumps({"transform": E.ravel().tolist()}))  # ROS style: order not known, said
    with pytest.raises(InputValueError, match=r"0 4 x 4 matrices .*a flat list of 16 numbers is not read"):
        read_extrinsic(p)


@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data/hesai_p64_qt64 (the Pandar64 + QT64 rig) is absent")
def test_pandar64_to_qt64_against_the_real_qt64():
    from slr_ray.cli.evaluate_command import read_extrinsic
    from slr_ray.io import read_cloud

    a, b = read_cloud(DATA / "p64.pcd"), read_cloud(DATA / "qt.pcd")
    E = read_extrinsic(DATA / "p64-to-qt-extrinsic.json")
    kw = {"source_sensor": "hesai_pandar64", "target_sensor": "hesai_pandarqt64_pjlab", "methods": ("zbuffer",
          "binning")}
    with pytest.warns(SlrWarning, match="nearest rotation"):
        res = evaluate_pair(a.points, b.points, a.attributes["ring"], None, extrinsic=E, **kw)
    reach = res["source_reach"]
    assert sum(reach["points"].values()) == res["frames"]["b_points_in_view"] > 12000
    assert sum(reach["pulses"].values()) == sensor("hesai_pandarqt64_pjlab").n_pulses
    # the QT64 looks down to -40 deg beside the car: half its points lie below what the roof Pandar64 sees
    assert reach["points"]["outside source FOV"] > 0.3 * res["frames"]["b_points_in_view"]
    zb, bn = ({r["method"]: r for r in res["rows"]}[m]["points"] for m in ("zbuffer", "binning"))
    assert bn["fscore"]["10cm"]["precision"] > zb["fscore"]["10cm"]["precision"]
    # the file maps the Pandar64's coordinates into the QT64's frame: read the other way, nothing meets
    with pytest.warns(SlrWarning):
        wrong = evaluate_pair(a.points, b.points, a.attributes["ring"], None, transform=rig_extrinsic(E),
                              **kw | {"methods": ("zbuffer",)})
    assert wrong["source_reach"]["points"]["seen by source"] < reach["points"]["seen by source"] / 5


def test_a_posed_scan_is_the_scan_in_bs_frame(rig):
    """B's rays turned into A's frame and cast on discs prepared there meet what a scan in B's frame of the
    same discs moved there meets (kNN discs do not depend on the frame): the cast the methods told of A's
    pulse grid use when B is tilted (MAX_GRID_TILT_DEG)."""
    from slr_ray import prepare
    from slr_ray.evaluate import MAX_GRID_TILT_DEG, posed_scan, tilt_deg

    a = rig[0]
    c, s = math.cos(math.radians(12.0)), math.sin(math.radians(12.0))
    T = np.array([[1, 0, 0, 0.5], [0, c, -s, -0.2], [0, s, c, 0.3], [0, 0, 0, 1.0]])
    assert tilt_deg(T) > MAX_GRID_TILT_DEG
    a_in_b = (a - T[:3, 3]) @ T[:3, :3]
    posed = posed_scan(prepare(a, "embree"), T, TARGET, a_in_b)
    moved = prepare(a_in_b, "embree").scan(np.zeros(3), TARGET)
    # the tie rule may take a neighbouring disc of a dense cloud (cast() ranks by distance from the ray, a
    # scan by the pulse's aspect too): the same surface, another point; the ranges agree
    im_posed, im_moved = posed.range_image()["range"], moved.range_image()["range"]
    both = np.isfinite(im_posed) & np.isfinite(im_moved)
    assert len(posed) > 5000 and abs(len(posed) - len(moved)) < 0.02 * len(moved)
    assert np.count_nonzero(both) > 0.97 * np.count_nonzero(np.isfinite(im_moved))
    diff = np.abs(im_posed[both] - im_moved[both])
    assert np.median(diff) < 1e-3 and np.mean(diff < 0.05) > 0.9  # 94 %: the rest at silhouettes
    assert np.allclose(np.linalg.norm(a_in_b[posed.indices], axis=1), posed.ranges)


def test_cli_cross_sensor_end_to_end(rig, tmp_path, capsys):
    """--source-sensor and --target-sensor as cards, B's pose as a rig's JSON extrinsic: the tables hold
    the source split, in table.md's second table and the printed JSON."""
    from slr_ray.io import PointCloud, write_cloud
    from slr_ray.sensors import write_card

    a, a_beams, b = rig
    write_cloud(tmp_path / "a.ply", PointCloud(a, {"ring": a_beams.astype(np.int32)}))
    write_cloud(tmp_path / "b.ply", PointCloud(b, {}))
    write_card(tmp_path / "source.json", SOURCE)
    write_card(tmp_path / "target.json", TARGET)
    (tmp_path / "rig.json").write_text(json.dumps({"a-to-b": {"param": {"sensor_calib": {
        "data": np.linalg.inv(POSE_B).tolist()}}}}))
    r = CliRun(capsys)("evaluate", tmp_path / "a.ply", tmp_path / "b.ply", "-o", tmp_path / "out", "--quiet",
                       "--source-sensor", tmp_path / "source.json", "--target-sensor", tmp_path / "target.json",
                       "--extrinsic", tmp_path / "rig.json", "--methods", "binning")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert np.allclose(res["registration"]["transform"], POSE_B, atol=1e-9)
    assert sum(res["source_reach"]["points"].values()) == sum(row["target points"] for row in res["reach_table"])
    table = (tmp_path / "out" / "table.md").read_text()
    assert table.startswith("| method |") and "| binning | outside source FOV |" in table


@pytest.mark.parametrize("matrix, message", [
    ([[float("nan"), 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "1 NaN or inf value(s)"),
    ([[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "its 3 x 3 part is not a rotation"),
])
def test_cli_refuses_a_bad_extrinsic_before_reading_any_frame(tmp_path, capsys, matrix, message):
    """A NaN or a scale in --extrinsic is said before the frames are read: the frames here are not point
    files at all, so reading either would fail first (reliab, #46 leftover)."""
    a, b = tmp_path / "a.xyz", tmp_path / "b.xyz"
    a.write_text("not a point\n")
    b.write_text("not a point\n")
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps({"data": matrix}))
    r = CliRun(capsys)("evaluate", a, b, "-o", tmp_path / "o", "--extrinsic", rig, "--target-sensor",
                       "velodyne_vlp16")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert f"--extrinsic {rig}: {message}" in r.stderr
    assert not (tmp_path / "o").exists()
