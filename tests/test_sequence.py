"""Sequences (slr_ray.sequence, `slr-ray sequence`): reading poses, the union, estimators,
leave-one-out evaluation and conversion, on a tiny synthetic drive with exact poses."""

import json

import numpy as np
import pytest

from slr_ray.errors import FormatError, InputValueError
from slr_ray.io import PointCloud, read_cloud, write_cloud
from slr_ray.sensors import sensor
from slr_ray.sequence import (MOVING_CLASSES, accumulate, estimate, evaluate_sequence,
                              nearest_of_frames, to_frame,
                              read_sequence, read_trajectory, window)
from slr_ray.sequence.frames import read_pose_files
from slr_ray.sequence.holdout import clamped_depth_errors, lidar4d_holdout
from slr_ray.sequence.synthetic import KITTI_TR, synthetic_drive
from conftest import CliRun


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("drive") / "seq"
    poses = synthetic_drive(root, n_frames=5, sensor="velodyne_vlp16", step=0.8)
    return root, poses


_Run = CliRun


def test_kitti_layout_poses_are_tr_inverse_p_tr(drive):
    root, poses = drive
    seq = read_sequence(root)
    assert np.abs(seq.poses - poses).max() < 1e-12
    assert not np.allclose(KITTI_TR, np.eye(4))  # the file's camera poses differ from the velodyne's
    f = seq.read(3)
    assert {"intensity", "semantic"} <= set(f.attributes)


def test_union_keeps_source_frames_and_drops_moving_classes(drive):
    root, poses = drive
    seq = read_sequence(root)
    assert window(seq, 2, half=1) == [1, 3]
    assert window(seq, 0, half=None, radius=1.0) == [1]
    u = accumulate(seq, [1, 3], drop_moving=False)
    assert set(np.unique(u.frame_of_point)) == {1, 3}
    assert np.allclose(u.origin_of_point[u.frame_of_point == 3], poses[3][:3, 3])
    assert np.isin(u.attributes["semantic"], MOVING_CLASSES).any()
    kept = accumulate(seq, [1, 3])
    assert not np.isin(kept.attributes["semantic"], MOVING_CLASSES).any()
    assert kept.removed["moving"] == len(u) - len(kept) > 0
    # a frame's own points, moved to the world and back, are the frame (float64)
    f = seq.read(1)
    assert np.abs((u.points[u.frame_of_point == 1] - poses[1][:3, 3]) @ poses[1][:3, :3] - f.points).max() < 1e-9


def test_fpa_averages_the_first_cluster_and_nearest_is_binning():
    pat = sensor("velodyne_vlp16")
    d = np.array([np.cos(0.01), np.sin(0.01), 0.0])
    pts = np.vstack([d * 10.0, d * 10.06, d * 10.12, d * 15.0])  # one pulse: a cluster at 10-10.12 m, a wall behind
    near, fpa = estimate(pts, pat, "nearest"), estimate(pts, pat, "fpa", gap=0.1)
    assert len(near) == len(fpa) == 1 and near.keys[0] == fpa.keys[0]
    assert near.ranges[0] == pytest.approx(10.0)
    assert fpa.ranges[0] == pytest.approx(10.06) and fpa.index[0] == 0
    assert estimate(pts, pat, "fpa", gap=0.01).ranges[0] == pytest.approx(10.0)


def test_bad_poses_named_by_file_and_line(tmp_path, drive):
    root, _ = drive
    bins = sorted((root / "velodyne").glob("*.bin"))
    good = " ".join(["1 0 0 0 0 1 0 0 0 0 1 0"])
    traj = tmp_path / "t.txt"
    traj.write_text("\n".join([good] * 4) + "\n")
    with pytest.raises(InputValueError, match=r"t\.txt, line 5: 4 poses for 5 frames"):
        read_sequence(bins, traj)
    traj.write_text("\n".join([good] * 3 + ["2 0 0 0 0 1 0 0 0 0 1 0", good]) + "\n")
    with pytest.raises(InputValueError, match=r"t\.txt, line 4: .*not a rotation"):
        read_sequence(bins, traj)
    traj.write_text("\n".join([good] * 4 + ["nan 0 0 0 0 1 0 0 0 0 1 0"]) + "\n")
    with pytest.raises(InputValueError, match=r"t\.txt, line 5: .*NaN"):
        read_sequence(bins, traj)
    tum = tmp_path / "tum.txt"
    tum.write_text("".join(f"{i} {i} 0 0 0 0 0.0998334 0.9950042\n" for i in range(5)))
    P = read_trajectory(tum, 5)
    assert np.allclose(P[2][:3, 3], [2, 0, 0]) and np.allclose(np.linalg.det(P[:, :3, :3]), 1)
    (tmp_path / "p_bad.txt").write_text("2 0 0 0\n0 2 0 0\n0 0 2 0\n0 0 0 1\n")  # a scale: not a pose
    with pytest.raises(InputValueError, match=r"p_bad\.txt, line 1: .*not a rotation"):
        read_pose_files([tmp_path / "p_bad.txt"])
    files = []  # one pose file a frame
    for i in range(5):
        files.append(tmp_path / f"p{i}.txt")
        T = np.eye(4)
        T[0, 3] = i
        np.savetxt(files[-1], T)
    assert np.array_equal(read_sequence(bins, files).poses[:, 0, 3], np.arange(5.0))
    np.savetxt(files[3], np.diag([1.0, 1, -1, 1]))
    with pytest.raises(InputValueError, match=r"p3\.txt, line 1: .*determinant -1: a reflection"):
        read_sequence(bins, files)
    with pytest.raises(InputValueError, match="4 pose files for 5 frames"):
        read_sequence(bins, files[:4])


def test_bad_layouts_refused(tmp_path, drive):
    root, _ = drive
    import shutil
    bad = tmp_path / "bad"
    shutil.copytree(root, bad)
    (bad / "calib.txt").write_text("P0: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(InputValueError, match=r"calib\.txt: no 'Tr:' line"):
        read_sequence(bad)
    (bad / "calib.txt").unlink()
    (bad / "labels" / "000002.label").write_bytes(b"\0" * 8)
    with pytest.raises(FormatError, match=r"000002\.label: 2 labels for the \d+ points"):
        read_sequence(bad)
    shutil.copy(root / "labels" / "000002.label", bad / "labels" / "000002.label")
    with open(bad / "velodyne" / "000001.bin", "ab") as f:
        f.write(b"\0" * 5)
    with pytest.raises(FormatError, match=r"000001\.bin: \d+ bytes, not whole points"):
        read_sequence(bad)
    shutil.copy(root / "velodyne" / "000001.bin", bad / "velodyne" / "000001.bin")
    (bad / "velodyne" / "000003.bin").rename(bad / "velodyne" / "000007.bin")
    with pytest.raises(InputValueError, match=r"000004\.bin: frame number 4 where 3 was expected"):
        read_sequence(bad)


def test_leave_one_out_scores_every_method_and_union_beats_adjacent(drive):
    root, _ = drive
    seq = read_sequence(root)
    res = evaluate_sequence(seq, [2], sensor="velodyne_vlp16", half=2)
    rows = {r["method"]: r for r in res["frames"][0]["table"]}
    assert len(rows) == 5 and [r["frame"] for r in res["mean"]] == ["mean"] * 5
    for r in rows.values():
        assert {"points", "F@5cm", "depth_medae_m", "drop_accuracy"} <= set(r)
    union, adj = rows["nearest (binning of the union)"], rows["binning, adjacent frame alone"]
    assert union["drop_accuracy"] >= adj["drop_accuracy"]
    assert res["frames"][0]["removed"]["moving"] > 0


def test_cli_evaluate_and_convert_resume(tmp_path, drive, capsys):
    root, poses = drive
    _cli = _Run(capsys)
    out = tmp_path / "ev"
    r = _cli("sequence", "evaluate", root, "--holdout", "1", "--every", "3", "--sensor", "velodyne_vlp16",
             "--half", "1", "-o", out, "--quiet")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert len(doc["mean"]) == 5 and doc["holdout"] == ["000001", "000004"] and (out / "table.md").is_file()
    conv = tmp_path / "conv"
    args = ["sequence", "convert", root, "--sensor", "velodyne_vlp16", "--half", "1", "-o", conv, "--quiet",
            "--offset", "0", "0", "0.5"]
    r = _cli(*args)
    assert r.returncode == 0, r.stderr
    first = json.loads(r.stdout)
    assert first["written"] == 5
    c = read_cloud(conv / "velodyne" / "000002.bin")
    assert {"intensity", "semantic"} <= set(c.attributes)
    P = read_sequence(conv).poses
    assert np.allclose(P[:, :3, 3], poses[:, :3, 3] + poses[:, :3, :3] @ [0, 0, 0.5])
    again = json.loads(_cli(*args).stdout)
    assert again["written"] == 0 and again["resumed"] == 5
    r = _cli(*args[:-1], "0.6")  # other settings into the same directory: refused, nothing mixed
    assert r.returncode == 2 and "other settings (offset" in r.stderr
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    r = _cli("sequence", "convert", root, "--sensor", "velodyne_vlp16", "-o", other, "--quiet")
    assert r.returncode == 2 and "not a conversion by slr-ray (notes.txt)" in r.stderr
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]
    import shutil
    broken = tmp_path / "broken"
    shutil.copytree(root, broken, ignore=shutil.ignore_patterns("labels"))
    with open(broken / "velodyne" / "000002.bin", "r+b") as f:
        f.write(np.float32(np.nan).tobytes())  # a NaN coordinate: refused when the window first reads it
    r = _cli("sequence", "convert", broken, "--sensor", "velodyne_vlp16", "-o", tmp_path / "fails", "--quiet")
    assert r.returncode == 2 and "000002.bin" in r.stderr and not (tmp_path / "fails").exists()
    r = _cli("sequence", "convert", root, "--sensor", "velodyne_vlp16", "-o", root / "out", "--quiet")
    assert r.returncode == 2 and "input directory" in r.stderr and not (root / "out").exists()


def test_files_in_one_world_frame_with_their_origins(tmp_path):
    rng = np.random.default_rng(0)
    world = rng.normal(size=(50, 3)) * 5 + [4e5, 5e6, 10]  # UTM-sized: moved to the origin in float64
    paths = []
    for k, o in enumerate(([4e5, 5e6, 11], [4e5 + 1, 5e6, 11])):
        paths.append(tmp_path / f"s{k}.npz")
        write_cloud(paths[-1], PointCloud(world, {}, np.array(o)))
    seq = read_sequence(paths, "origins")
    assert np.array_equal(seq.poses[1][:3, 3], [4e5 + 1, 5e6, 11])
    f = seq.read(1)
    assert np.abs(f.points - (world - [4e5 + 1, 5e6, 11])).max() < 1e-9 and np.abs(f.world() - world).max() < 1e-9
    origins = tmp_path / "origins.txt"  # files that record no origin (LAS of a campaign): a text file of them
    las = [tmp_path / "a.las", tmp_path / "b.las"]
    for p in las:
        write_cloud(p, PointCloud(world, {}))
    origins.write_text("400000 5000000 11\n400001 5000000 11\n")
    seq = read_sequence(las, origins=origins)
    assert np.abs(seq.read(1).points - (world - [4e5 + 1, 5e6, 11])).max() < 1e-3  # LAS: 1 mm
    origins.write_text("400000 5000000 11\nnan 5000000 11\n")
    with pytest.raises(InputValueError, match=r"origins\.txt, line 2: an origin holds NaN"):
        read_sequence(las, origins=origins)
    write_cloud(tmp_path / "bare.npy", PointCloud(world, {}))
    with pytest.raises(InputValueError, match=r"bare\.npy: records no scanner origin"):
        read_sequence([paths[0], tmp_path / "bare.npy"], "origins")
    for k, beams in enumerate((16, 64)):  # frames of two sensors in one sequence
        write_cloud(paths[k], PointCloud(world, {"ring": np.arange(50) % beams}, np.array([4e5, 5e6, 11])))
    seq = read_sequence(paths, "origins")
    seq.read(0)
    with pytest.raises(InputValueError, match=r"s1\.npz: rings up to 49 \(50 beams\) where .*s0\.npz has 16"):
        seq.read(1)


def test_nearest_a_frame_at_a_time_equals_nearest_of_the_union(drive):
    root, poses = drive
    seq = read_sequence(root)
    pat = sensor("velodyne_vlp16")
    pose = poses[2].copy()
    pose[:3, 3] += [0.3, -0.2, 0.4]
    u = accumulate(seq, [0, 1, 2, 3])
    whole = estimate(to_frame(u.points, pose), pat, "nearest")
    parts, carried = nearest_of_frames(seq, [0, 1, 2, 3], pose, pat)
    assert np.array_equal(parts.keys, whole.keys) and np.array_equal(parts.index, whole.index)
    assert np.array_equal(parts.points, whole.points)
    assert np.array_equal(carried["semantic"], u.attributes["semantic"][whole.index])


def test_lidar4d_protocol_clamps_depth_and_takes_its_split(drive, capsys):
    real = np.array([[10.0, np.nan], [90.0, 5.0]])
    sim = np.array([[10.5, 3.0], [np.nan, 5.0]])
    rmse, medae = clamped_depth_errors(real, sim)
    e = np.array([0.5, 3.0 - 1e-6, 80.0 - 1e-6, 0.0])  # no return counts as 1e-6 m, 90 m as 80
    assert rmse == pytest.approx(np.sqrt(np.mean(e ** 2))) and medae == pytest.approx(np.median(e))
    assert lidar4d_holdout(51) == [10, 20, 30, 40]
    r = _Run(capsys)("sequence", "evaluate", drive[0], "--protocol", "lidar4d", "-o", drive[0].parent / "l4d")
    assert r.returncode == 2 and "51 frames" in r.stderr and not (drive[0].parent / "l4d").exists()


def test_an_e57_files_scans_are_a_sequence(tmp_path):
    pye57 = pytest.importorskip("pye57")
    path, world = tmp_path / "campaign.e57", []
    e = pye57.E57(str(path), mode="w")
    for k in range(3):
        local = np.random.default_rng(k).normal(size=(100, 3)) * 5
        world.append(local + [10.0 * k, 0, 0])
        e.write_scan_raw({"cartesianX": local[:, 0], "cartesianY": local[:, 1], "cartesianZ": local[:, 2]},
                         name=f"s{k}", translation=np.array([10.0 * k, 0, 0]), rotation=np.array([1.0, 0, 0, 0]))
    e.close()
    seq = read_sequence(path)
    assert len(seq) == 3 and seq.pose_source == "e57 scan poses"
    assert np.array_equal(seq.poses[:, 0, 3], [0, 10, 20])
    u = accumulate(seq, [0, 2])
    assert np.abs(u.points - np.vstack([world[0], world[2]])).max() < 1e-5  # pye57 stores float32
    # (hostile pass) read as one cloud (slr-ray scan campaign.e57): the refusal named a Python function only
    with pytest.raises(FormatError, match=r"holds 3 scans: .*slr-ray sequence"):
        read_cloud(path)


def test_a_registered_metric_reaches_the_sequence_tables(drive, monkeypatch):
    """Held-out frames are scored by every registered metric (slr_ray.metrics.REGISTRY), as `slr-ray
    evaluate` scores a pair: a new metric's column reaches the per-frame and mean rows."""
    from slr_ray.metrics import REGISTRY, Metric

    def score(pair):
        return {"ratio": len(pair.simulated) / len(pair.target)}

    monkeypatch.setitem(REGISTRY, "ratio", Metric("ratio", score, lambda block, result: {"sim/real": block["ratio"]}))
    root, _ = drive
    res = evaluate_sequence(read_sequence(root), [2], sensor="velodyne_vlp16", half=1, methods=("nearest", "fpa"))
    rows = res["frames"][0]["rows"]
    assert [r["ratio"]["ratio"] for r in rows] == [r["points_out"] / r["points"]["target_points"] for r in rows]
    assert [r["sim/real"] for r in res["frames"][0]["table"]] == [r["ratio"]["ratio"] for r in rows]
    assert all("sim/real" in r for r in res["mean"])


def test_a_target_sensors_held_out_frame_is_scored_on_its_own_table_reach_apart(tmp_path, drive, capsys):
    # failed before (#45): sequence evaluate had no --target-sensor; a frame of another unit among the source's
    # was scored on the source's table. Here a VLP-32C frame (down to -25 deg) held out among VLP-16 frames
    # (+-15 deg): its grid is the VLP-32C's, and its beams below what the VLP-16 saw are scored apart
    root, poses = drive
    other = tmp_path / "vlp32"
    synthetic_drive(other, n_frames=3, sensor="velodyne_vlp32c", step=0.8, moving=False)
    files = [root / "velodyne" / "000000.bin", other / "velodyne" / "000001.bin", root / "velodyne" / "000002.bin"]
    from slr_ray.sequence.frames import write_kitti_poses
    write_kitti_poses(tmp_path / "poses.txt", poses[:3])
    out = tmp_path / "ev"
    r = _Run(capsys)("sequence", "evaluate", *files, "--poses", tmp_path / "poses.txt", "--holdout", "1",
                     "--half", "1", "--source-sensor", "velodyne_vlp16", "--target-sensor", "velodyne_vlp32c",
                     "--methods", "zbuffer", "nearest", "rays", "-o", out, "--quiet")
    assert r.returncode == 0, r.stderr
    res = json.loads((out / "evaluation.json").read_text())
    f = res["frames"][0]
    assert f["pattern"]["beams"] == 32 and f["target_sensor"] == "velodyne_vlp32c"
    lo, hi = f["source_elevation_range_deg"]
    table = sensor("velodyne_vlp32c")
    assert f["target_beams_out_of_reach"] == int(np.sum((np.asarray(table.elevation_deg) < lo) |
                                                        (np.asarray(table.elevation_deg) > hi))) > 0
    for row in f["table"]:
        assert row["target points out of reach"] > 0 and row["target points in reach"] > 0
        assert row["points in reach"] + row["points out of reach"] == row["points"] or row["method"].startswith("no SLR")
    near = {r["method"]: r for r in f["table"]}["nearest (binning of the union)"]
    assert near["F@5cm in reach"] > near["F@5cm"]  # what the source never saw pulls the whole frame's score down
    assert "F@5cm in reach" in (out / "table.md").read_text()


def test_evaluate_force_takes_an_earlier_register_runs_poses_away(tmp_path, drive, capsys):
    # (hostile pass) a --force rerun without --register replaced evaluation.json and the tables but
    # left the earlier run's registered poses.txt beside them, as if these results had used it
    root, _ = drive
    _cli = _Run(capsys)
    args = ["sequence", "evaluate", root, "--holdout", "1", "--source-sensor", "velodyne_vlp16", "--half", "1",
            "--methods", "nearest", "--quiet", "--force"]
    for earlier, kept in (("register", False), ("trajectory", True)):
        out = tmp_path / earlier
        out.mkdir()
        (out / "evaluation.json").write_text(json.dumps({"pose_source": earlier}))
        (out / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
        r = _cli(*args, "-o", out)
        assert r.returncode == 0, r.stderr
        assert json.loads((out / "evaluation.json").read_text())["pose_source"] != "register"
        assert (out / "poses.txt").exists() == kept  # not an earlier --register run's: not ours to remove


def test_radius_alone_is_not_capped_by_the_default_half(tmp_path, drive, capsys):
    # (hostile pass) --radius 100 alone kept the default --half 2 too: frame 0's window held frames
    # 1 and 2 of a drive whose every frame lies within 100 m, and nothing said so
    root, _ = drive
    _cli = _Run(capsys)
    base = ["sequence", "evaluate", root, "--holdout", "0", "--source-sensor", "velodyne_vlp16", "--methods",
            "nearest", "--quiet"]
    r = _cli(*base, "--radius", "100", "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "r" / "evaluation.json").read_text())
    assert doc["frames"][0]["window"] == ["000001", "000002", "000003", "000004"]
    r = _cli(*base, "--radius", "100", "--half", "2", "-o", tmp_path / "both")  # both given: both hold
    assert json.loads((tmp_path / "both" / "evaluation.json").read_text())["frames"][0]["window"] == ["000001",
                                                                                                       "000002"]


def test_read_sequence_takes_an_array_of_poses_and_refuses_other_kinds(drive):
    # (n, 4, 4) poses crashed ("truth value of an array is ambiguous"); now read as a trajectory file is
    root, poses = drive
    bins = sorted((root / "velodyne").glob("*.bin"))
    seq = read_sequence(bins, poses)
    assert np.array_equal(seq.poses, poses) and seq.poses.dtype == np.float64
    assert np.array_equal(read_sequence(root, poses.astype(np.float32)).poses, poses.astype(np.float32))
    with pytest.raises(InputValueError, match=r"trajectory: an array of poses must be \(n, 4, 4\).*\(5, 3, 4\)"):
        read_sequence(bins, poses[:, :3])
    with pytest.raises(InputValueError, match="4 poses for 5 frames"):
        read_sequence(bins, poses[:4])
    bad = poses.copy()
    bad[2, 0, 3] = np.nan
    with pytest.raises(InputValueError, match=r"trajectory: pose 2 of the array: .*NaN"):
        read_sequence(bins, bad)
    bad = poses.copy()
    bad[3, :3, :3] *= 2
    with pytest.raises(InputValueError, match=r"pose 3 of the array: .*not a rotation"):
        read_sequence(bins, bad)
    for wrong in (poses.tolist(), 3.0, [poses[0]]):
        with pytest.raises(TypeError, match="trajectory must be a file, a list of pose files"):
            read_sequence(bins, wrong)


def test_evaluate_force_over_a_pair_evaluation_takes_its_splits_and_figure_away(tmp_path, drive, capsys):
    # (hostile2 pass) sequence evaluate --force into the directory of an earlier `slr-ray evaluate A B`
    # replaced evaluation.json and the tables but left that run's splits.csv and evaluation.png beside
    # them without a word: a figure and splits of another pair, read as this run's
    root, _ = drive
    _cli = _Run(capsys)
    args = ["sequence", "evaluate", root, "--holdout", "1", "--source-sensor", "velodyne_vlp16", "--half", "1",
            "--methods", "nearest", "--quiet", "--force"]
    for earlier, kept in (({"inputs": {"a": "a.bin", "b": "b.bin"}}, False), (None, True)):
        out = tmp_path / ("pair" if earlier else "loose")
        out.mkdir()
        if earlier is not None:
            (out / "evaluation.json").write_text(json.dumps(earlier))
        (out / "splits.csv").write_text("split,part\n")
        (out / "evaluation.png").write_bytes(b"\x89PNG")
        r = _cli(*args, "-o", out)
        assert r.returncode == 0, r.stderr
        assert isinstance(json.loads((out / "evaluation.json").read_text())["inputs"], list)
        for name in ("splits.csv", "evaluation.png"):  # not beside a pair evaluation's results: not ours to remove
            assert (out / name).exists() == kept
        assert ("splits.csv" in r.stderr) == (not kept)  # said, as the pair command says what it leaves


def test_a_negative_half_is_refused_naming_the_flag(tmp_path, drive, capsys):
    # (hostile2 pass) --half -1 said "the window's half width must be >= 0, got -1": no flag named
    root, _ = drive
    r = _Run(capsys)("sequence", "convert", root, "--target-sensor", "velodyne_vlp16", "--half", "-1",
                     "-o", tmp_path / "o")
    assert r.returncode == 2 and "argument --half: must be >= 0" in r.stderr, r.stderr
