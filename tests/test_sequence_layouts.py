"""Sequence layouts (slr_ray.sequence.layouts): the registry and detection, a toy layout by the
recipe of docs/architecture.md, and the refusals of poses files (#47 item 2, #48 items 5 and 10)."""

import json
from pathlib import Path

import numpy as np
import pytest

from slr_ray.errors import InputValueError, SlrNote
from slr_ray.io import PointCloud, write_cloud
from slr_ray.sequence import accumulate, read_sequence
from slr_ray.sequence.layouts import REGISTRY, FrameSource, Sequence, SequenceInputs, detect
from slr_ray.sequence.poses import read_calib_tr, read_pose_blocks, read_trajectory, write_kitti_poses
from slr_ray.sequence.synthetic import KITTI_TR
from conftest import DATA, CliRun


def _velodyne_poses(n):
    P = np.repeat(np.eye(4)[None], n, 0)
    for i in range(n):
        a = 0.1 * i
        P[i, :3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        P[i, :3, 3] = [2.0 * i, 0.5 * i, 0.1 * i]
    return P


@pytest.fixture
def kitti(tmp_path):
    """A three-frame KITTI directory: camera poses in poses.txt, KITTI's Tr in calib.txt."""
    root = tmp_path / "seq"
    (root / "velodyne").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(3):
        write_cloud(root / "velodyne" / f"{i:06d}.bin", PointCloud(rng.normal(size=(50, 3)) * 5,
                                                                   {"intensity": np.zeros(50)}))
    vel = _velodyne_poses(3)
    cam = np.einsum("ij,njk,kl->nil", KITTI_TR, vel, np.linalg.inv(KITTI_TR))
    write_kitti_poses(root / "poses.txt", cam)
    (root / "calib.txt").write_text("P0: 1 0 0 0 0 1 0 0 0 0 1 0\nTr: " + " ".join(map(str, KITTI_TR[:3].ravel()))
                                    + "\n")
    return root, vel, cam


_Run = CliRun


# -- #48 item 5: a trajectory given for a KITTI directory is taken as its poses.txt is

def test_a_kitti_form_trajectory_for_a_kitti_directory_is_the_cameras(kitti, tmp_path):
    root, vel, cam = kitti
    own = read_sequence(root)
    assert np.abs(own.poses - vel).max() < 1e-9
    copy = tmp_path / "refined.txt"
    write_kitti_poses(copy, cam)  # a refined trajectory, as KITTI's poses.txt: the left camera's
    with pytest.warns(SlrNote, match="left camera's.*calib.txt's Tr"):
        seq = read_sequence(root, copy)
    assert np.abs(seq.poses - vel).max() < 1e-9 and "calib.txt Tr" in seq.pose_source
    with pytest.warns(SlrNote, match="left camera's"):
        assert np.abs(seq.trajectory(copy)[0] - vel).max() < 1e-9  # --target-poses reads it so too
    tum = tmp_path / "tum.txt"  # TUM form: the velodyne's own, said so
    tum.write_text("".join(f"{i} {T[0, 3]} {T[1, 3]} {T[2, 3]} 0 0 0 1\n" for i, T in enumerate(vel)))
    with pytest.warns(SlrNote, match="velodyne's own"):
        assert np.allclose(read_sequence(root, tum).poses[:, :3, 3], vel[:, :3, 3])


def test_target_poses_for_a_kitti_directory_are_moved_by_tr(kitti, tmp_path, capsys, monkeypatch):
    import slr_ray.cli.sequence_command as sc
    root, vel, cam = kitti
    got = {}

    def fake_convert(seq, out, sensor, **kw):
        got["poses"] = kw["poses"]
        return {}

    monkeypatch.setattr(sc, "convert_sequence", fake_convert)
    target = tmp_path / "target.txt"
    write_kitti_poses(target, cam)
    r = _Run(capsys)("sequence", "convert", root, "--sensor", "velodyne_vlp16", "-o", tmp_path / "out",
                     "--target-poses", target, "--quiet")
    assert r.returncode == 0, r.stderr
    assert np.abs(got["poses"] - vel).max() < 1e-9
    assert "note:" in r.stderr and "left camera's" in r.stderr


def test_poses_origins_refuses_files_that_record_none(tmp_path):
    rng = np.random.default_rng(1)
    bins = []
    for i in range(3):  # KITTI .bin: no origin, read as 0, 0, 0
        bins.append(tmp_path / f"{i}.bin")
        write_cloud(bins[-1], PointCloud(rng.normal(size=(20, 3)), {"intensity": np.zeros(20)}))
    with pytest.raises(InputValueError, match=r"0\.bin: records no scanner origin \(0, 0, 0, as 3 of the 3"):
        read_sequence(bins, "origins")
    npz = []
    for i, o in enumerate(([0.0, 0, 0], [1.0, 0, 0])):  # one scanner at the world's origin is fine
        npz.append(tmp_path / f"s{i}.npz")
        write_cloud(npz[-1], PointCloud(rng.normal(size=(20, 3)), {}, np.array(o)))
    assert np.array_equal(read_sequence(npz, "origins").poses[:, 0, 3], [0, 1])


# -- #48 item 10 (and 16's missing path): each refused in one line

def test_a_trajectory_mixing_kitti_and_tum_lines_is_refused(tmp_path):
    t = tmp_path / "mixed.txt"
    t.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 1 0 0 0 0 0 1\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(InputValueError, match=r"mixed\.txt, line 2: 8 numbers \(TUM form\) where line 1 is 12"):
        read_trajectory(t, 3)


def test_two_tr_lines_in_calib_are_refused(kitti):
    root, _, _ = kitti
    calib = root / "calib.txt"
    calib.write_text(calib.read_text() + "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(InputValueError, match=r"calib\.txt, line 3: a second 'Tr:' line \(line 2 is one\)"):
        read_calib_tr(calib)
    with pytest.raises(InputValueError, match="second 'Tr:'"):
        read_sequence(root)


def test_an_e57_quaternion_not_of_norm_one_is_refused(tmp_path):
    pye57 = pytest.importorskip("pye57")
    path = tmp_path / "bad.e57"
    e = pye57.E57(str(path), mode="w")
    for k, q in enumerate(([1.0, 0, 0, 0], [2.0, 0, 0, 0])):
        local = np.random.default_rng(k).normal(size=(30, 3))
        e.write_scan_raw({"cartesianX": local[:, 0], "cartesianY": local[:, 1], "cartesianZ": local[:, 2]},
                         name=f"s{k}", translation=np.array([5.0 * k, 0, 0]), rotation=np.array(q))
    e.close()
    with pytest.raises(InputValueError, match=r"bad\.e57, scan 1's pose: the quaternion's norm is 2"):
        read_sequence(path)


def test_a_missing_sequence_path_is_named_not_said_to_have_no_poses(tmp_path, capsys):
    r = _Run(capsys)("sequence", "evaluate", tmp_path / "nowhere", "--every", "2", "-o", tmp_path / "out")
    assert r.returncode == 2 and "nowhere: no such file or directory" in r.stderr and "no poses" not in r.stderr
    with pytest.raises(InputValueError, match="gone.bin: no such file"):
        read_sequence([tmp_path / "gone.bin", tmp_path / "gone2.bin"])


# -- #47 item 2: the registry, detection, ambiguity

def test_each_layout_is_detected_and_an_ambiguous_directory_names_the_candidates(kitti, tmp_path, capsys):
    root, _, _ = kitti
    assert detect(root) == "kitti" and read_sequence(root).layout.name == "kitti"
    write_cloud(root / "extra.pcd", PointCloud(np.ones((3, 3)), {}))  # PCD frames beside velodyne/
    with pytest.raises(InputValueError, match=r"ambiguous sequence layout, it could be kitti or pcd-directory"):
        read_sequence(root)
    assert read_sequence(root, layout="kitti").layout.name == "kitti"
    r = _Run(capsys)("sequence", "evaluate", root, "--every", "2", "-o", tmp_path / "out")
    assert r.returncode == 2 and "kitti or pcd-directory" in r.stderr and "--layout" in r.stderr
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputValueError, match="not a sequence layout slr_ray knows"):
        read_sequence(tmp_path / "empty")
    e57 = tmp_path / "x.e57"
    e57.write_bytes(b"")
    assert detect(e57) == "e57" and detect(root / "velodyne" / "000000.bin") == "files"


def test_a_sequence_says_its_layout_not_in_a_meta_dict(kitti):
    root, _, _ = kitti
    seq = read_sequence(root)
    assert isinstance(seq.layout, REGISTRY["kitti"]) and np.allclose(seq.layout.tr, KITTI_TR)
    assert [p.name for p in seq.inputs()][-2:] == ["poses.txt", "calib.txt"]
    assert seq.meta["layout"] == "kitti"  # the old dict, read from them
    with pytest.raises(TypeError, match="no longer a meta dict"):
        Sequence(seq.paths, seq.poses, seq.names, "x", None, None, {"layout": "kitti"})
    from slr_ray.sequence.frames import (POSE_TOLERANCE, read_e57_sequence, read_file_list,  # noqa: F401
                                         read_kitti_layout, read_split_scans)
    assert read_kitti_layout(root).layout.name == "kitti"


@pytest.mark.skipif(not (DATA / "balm_os0_64").is_dir(), reason="shared data not here")
def test_the_new_sensors_directories_are_layouts():
    balm = read_sequence(DATA / "balm_os0_64")  # PCD frames + a CSV of 4 x 4 poses: frame fullN takes pose N
    assert balm.layout.name == "pcd-directory" and len(balm) == 10 and balm.names[0] == "full20"
    assert np.array_equal(balm.poses, read_pose_blocks(DATA / "balm_os0_64" / "alidarPose.csv")[20:30])
    f = balm.read(0)
    assert len(f.points) == 73082
    ouster = read_sequence(DATA / "ouster_os1_128")  # npz frames + metadata json + KITTI-form poses
    assert ouster.layout.name == "ouster-directory" and len(ouster) == 3
    assert ouster.layout.metadata.name.endswith(".json") and 0.2 < ouster.poses[1][0, 3] < 0.3
    hesai = read_sequence(DATA / "hesai_p64_seq")  # PCD frames, no poses: --poses or --register
    assert hesai.layout.name == "pcd-directory" and len(hesai) == 5 and hesai.poses is None


# -- the recipe (docs/architecture.md, Extension recipes): a toy layout, one class and its registry line

class ToyLayout(FrameSource):
    """A directory holding ``toy.txt``: one frame a line, ``x y z`` of its sensor's position (the
    frames' points are made from it: a cube of 8 corners around the origin)."""

    name = "toy"
    what = "a toy directory (toy.txt)"

    @classmethod
    def detect(cls, path):
        return 1.0 if (Path(path) / "toy.txt").is_file() else 0.0

    @classmethod
    def open(cls, path, inputs: SequenceInputs):
        inputs.refuse(path, "toy", "origins", "scan_field", "trajectory")
        xyz = np.loadtxt(Path(path) / "toy.txt", ndmin=2)
        poses = np.repeat(np.eye(4)[None], len(xyz), 0)
        poses[:, :3, 3] = xyz
        return Sequence([Path(path) / "toy.txt"] * len(xyz), poses, [f"toy{i}" for i in range(len(xyz))],
                        "toy.txt", Path(path), None, cls())

    def frame(self, seq, i):
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
        return corners * (i + 1), {"intensity": np.full(8, float(i))}


def test_a_toy_layout_is_one_class_and_its_registry_line(tmp_path, monkeypatch):
    monkeypatch.setitem(REGISTRY, "toy", ToyLayout)
    d = tmp_path / "toyseq"
    d.mkdir()
    (d / "toy.txt").write_text("0 0 0\n10 0 0\n20 0 0\n")
    seq = read_sequence(d)
    assert seq.layout.name == "toy" and len(seq) == 3 and seq.pose_source == "toy.txt"
    u = accumulate(seq, [1, 2], drop_moving=False)  # the union reads it as any layout
    assert len(u.points) == 16 and np.allclose(u.points[:8].mean(axis=0), [10, 0, 0])
    with pytest.raises(InputValueError, match="toy sequence takes no poses"):
        read_sequence(d, tmp_path / "t.txt")


def test_a_tum_trajectory_gives_frames_named_by_time_the_pose_of_their_time(tmp_path):
    """TUM with timestamps: a SLAM trajectory of more poses than frames (frames dropped, or poses at
    another rate), the frames named by their times: each frame the pose of its time (within 1 ms)."""
    rng = np.random.default_rng(2)
    stamps = [100.0, 100.2, 100.4]
    files = []
    for t in stamps:
        files.append(tmp_path / f"{t:.6f}.npy")
        write_cloud(files[-1], PointCloud(rng.normal(size=(10, 3)), {}))
    tum = tmp_path / "traj.tum"
    tum.write_text("".join(f"{100 + 0.1 * k:.6f} {k} 0 0 0 0 0 1\n" for k in range(6)))  # 10 Hz poses, 5 Hz frames
    seq = read_sequence(files, tum)
    assert np.allclose(seq.poses[:, 0, 3], [0, 2, 4])
    tum.write_text("".join(f"{100 + 0.1 * k + 0.05:.6f} {k} 0 0 0 0 0 1\n" for k in range(6)))  # 50 ms off
    with pytest.raises(InputValueError, match=r"traj\.tum: 6 poses for 3 frames, and frame 0 \(time 100\.000000 s"):
        read_sequence(files, tum)


def _ouster_directory(root, lift_mm):
    """A toy Ouster directory: 3 beams (+10, 0, -10 deg) x 16 columns at 2 m from a lidar origin
    ``lift_mm`` above the sensor origin, the points in the sensor frame (as Ouster's xyz), 2 frames."""
    root.mkdir()
    alt = np.array([10.0, 0.0, -10.0])
    az = np.radians(np.arange(16) * 22.5)
    e = np.radians(alt)[:, None]
    d = np.stack([np.cos(e) * np.cos(az), np.cos(e) * np.sin(az), np.sin(e) * np.ones_like(az)], axis=-1)
    xyz = 2.0 * d + np.array([0.0, 0.0, lift_mm / 1000.0])
    for i in range(2):
        np.savez(root / f"f{i}.npz", xyz=xyz, range_mm=np.full((3, 16), 2000, np.uint32))
    m = np.eye(4)
    m[2, 3] = lift_mm
    (root / "meta.json").write_text(json.dumps({"beam_altitude_angles": alt.tolist(), "beam_azimuth_angles": [0] * 3,
                                                "lidar_mode": "16x10", "lidar_to_sensor_transform": m.ravel().tolist()}))
    (root / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n")
    return xyz.reshape(-1, 3)


def test_an_ouster_frame_is_moved_to_the_lidar_origin_its_beams_start_from(tmp_path):
    # failed before (#45): the points stayed in the sensor frame, 36 mm below the beams' origin on an OS1, so
    # each beam's points lay at an elevation that changes with range (0.4 deg at 5 m)
    xyz = _ouster_directory(tmp_path / "os", 500.0)
    seq = read_sequence(tmp_path / "os")
    assert np.allclose(seq.layout.origin, [0, 0, 0.5])
    f = seq.read(1)
    el = np.degrees(np.arcsin(f.points[:, 2] / np.linalg.norm(f.points, axis=1)))
    assert np.allclose(el, np.array([10.0, 0.0, -10.0])[f.attributes["ring"]], atol=1e-9)  # each beam's own
    assert np.allclose(f.world(), xyz + [1.0, 0, 0])  # the world points unchanged (frame 1 is 1 m along x)
    assert np.allclose(seq.trajectory(tmp_path / "os" / "poses.txt")[0], seq.poses)  # a given trajectory too


def test_directory_layouts_take_one_trajectory_file_through_one_check():
    # the KITTI, PCD and Ouster directories refuse several files and 'origins' with one message (#47)
    from slr_ray.sequence.layouts.base import one_trajectory

    assert one_trajectory("d", None, "a PCD directory") is None
    assert one_trajectory("d", ["p.txt"], "a PCD directory") == one_trajectory("d", "p.txt", "x") == "p.txt"
    with pytest.raises(InputValueError, match="d: an Ouster directory takes one trajectory file, got 2"):
        one_trajectory("d", ["a", "b"], "an Ouster directory")
    with pytest.raises(InputValueError, match="a KITTI sequence's frames are each in their sensor's frame"):
        one_trajectory("d", "origins", "a KITTI sequence")


def test_e57_files_placed_by_their_recorded_poses_keep_their_rotation(tmp_path):
    """E57 files with --poses origins: each frame in its scanner's own axes, R^T (p - t), its pose's rotation
    the file's, as an E57 of several scans gives; the rotation was read and dropped (the frame taken in the
    world's axes: a tilted scanner's rows about the world's z). Failed before."""
    pye57 = pytest.importorskip("pye57")
    local = np.random.default_rng(1).normal(size=(40, 3)) * 4
    half = np.radians(25.0)
    q = np.array([np.cos(half), np.sin(half), 0.0, 0.0])  # 50 deg about x: a tilted scanner
    paths = []
    for k in range(2):
        paths.append(tmp_path / f"s{k}.e57")
        e = pye57.E57(str(paths[-1]), mode="w")
        e.write_scan_raw({"cartesianX": local[:, 0], "cartesianY": local[:, 1], "cartesianZ": local[:, 2]},
                         name=f"s{k}", translation=np.array([5.0 * k + 1, 2.0, 1.0]), rotation=q)
        e.close()
    seq = read_sequence(paths, "origins")
    c, s = np.cos(2 * half), np.sin(2 * half)
    np.testing.assert_allclose(seq.poses[1, :3, :3], [[1, 0, 0], [0, c, -s], [0, s, c]], atol=1e-9)
    np.testing.assert_allclose(seq.poses[:, :3, 3], [[1, 2, 1], [6, 2, 1]])
    for i in range(2):
        np.testing.assert_allclose(seq.read(i).points, local, atol=1e-4)


def test_a_tum_trajectory_written_w_first_is_warned_of(tmp_path):
    # (hostile2 pass) TUM lines are time x y z qx qy qz qw; a drive written qw first (w x y z, Eigen's and
    # E57's order) read as every frame turned upside down (a near-identity 1 0 0 0 is 180 deg about x),
    # converted without a word; a mount that is upside down both ways read is not warned of
    import warnings
    from scipy.spatial.transform import Rotation
    from slr_ray.errors import SlrWarning
    rng = np.random.default_rng(5)
    rots = Rotation.from_euler("zyx", np.c_[rng.uniform(-3, 3, 6), rng.uniform(-0.05, 0.05, (6, 2))])
    q = rots.as_quat()  # x y z w
    for name, quats, warned in (("xyzw", q, False), ("wxyz", q[:, [3, 0, 1, 2]], True),
                                ("ceiling", (rots * Rotation.from_euler("x", np.pi)).as_quat(), False)):
        t = tmp_path / f"{name}.txt"
        t.write_text("".join(f"{i * 0.1} {i} 0 0 " + " ".join(map(repr, qq.tolist())) + "\n" for i, qq in enumerate(quats)))
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            read_trajectory(t, 6)
        said = [str(x.message) for x in w if issubclass(x.category, SlrWarning)]
        assert len(said) == warned and all(str(t) in s and "qw" in s for s in said), (name, said)


def test_a_poses_path_that_is_a_directory_is_refused_naming_it(tmp_path):
    # (hostile2 pass) --poses DIR said "[Errno 21] Is a directory: 'DIR'": Python's words, not what was wrong
    d = tmp_path / "poses"
    d.mkdir()
    with pytest.raises(InputValueError, match=r"poses: a directory, not a poses file"):
        read_trajectory(d, 2)
