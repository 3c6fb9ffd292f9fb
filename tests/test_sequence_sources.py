"""Each source frame's own sensor (slr_ray.sequence.sources): see-through removal of moving objects
without labels, embree discs from each frame's own pulse grid; their CLI options."""

import json
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from slr_ray.cli import main
from slr_ray.errors import InputValueError
from slr_ray.sequence import MOVING_CLASSES, FrameCache, SeeThrough, accumulate, evaluate_sequence, read_sequence
from slr_ray.sequence.synthetic import synthetic_drive


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("drive") / "seq"
    synthetic_drive(root, n_frames=5, sensor="velodyne_vlp16", step=0.8)
    return root


@pytest.fixture
def run(capsys):
    def call(*args):
        capsys.readouterr()
        rc = main([str(a) for a in args])
        out = capsys.readouterr()
        return SimpleNamespace(returncode=rc, stdout=out.out, stderr=out.err)
    return call


def test_see_through_removes_the_moving_box_without_its_labels(drive):
    seq = read_sequence(drive)
    cache = FrameCache(seq)
    st = SeeThrough("velodyne_vlp16")
    flagged = moving = hits = 0
    for i in range(3):  # frames whose neighbours drove past the box's places
        f, _ = cache.get(i)
        keep, removed = cache.selection(i, False, st)  # labels not used
        gone = np.zeros(len(f.points), bool) if keep is None else ~keep
        mv = np.isin(f.attributes["semantic"], MOVING_CLASSES)
        flagged, moving, hits = flagged + gone.sum(), moving + mv.sum(), hits + (gone & mv).sum()
        assert removed["seen_through"] == gone.sum()
    assert hits / flagged > 0.9 and hits / moving > 0.3
    u = accumulate(seq, [0, 1, 2], drop_moving=False, see_through=st, cache=cache)
    assert u.removed["seen_through"] == flagged and len(u) == sum(len(cache.get(i)[1]) for i in range(3)) - flagged


def test_a_held_out_frame_does_not_vote(drive):
    seq = read_sequence(drive)
    cache = FrameCache(seq)
    # frame 1's neighbours within 1 are 0 and 2 (frame 2, ahead, saw through the box's old place)
    st = SeeThrough("velodyne_vlp16", votes=1, half=1)
    assert cache.selection(1, False, st)[1]["seen_through"] > 0
    for held_out in ((2,), (0, 2)):
        assert cache.selection(1, False, st, exclude=held_out) == (None, {"moving": 0, "seen_through": 0})
    with pytest.raises(InputValueError, match="votes"):
        SeeThrough("velodyne_vlp16", votes=0)


def test_discs_from_each_source_frame_meet_the_exact_surfaces(drive):
    seq = read_sequence(drive)
    res = evaluate_sequence(seq, [2], "velodyne_vlp16", ["nearest", "embree-sources"], half=1)
    rows = {r["method"]: r for r in res["mean"]}
    own = rows["embree discs from each source frame's pulse grid"]
    near = rows["nearest (binning of the union)"]
    # exact scans: a pulse's centre ray meets the discs of its own surface, where the nearest point
    # of a pulse is its footprint's near edge
    assert own["depth_medae_m"] < 0.5 * near["depth_medae_m"] and own["F@5cm"] > near["F@5cm"]


def test_convert_with_see_through_and_source_discs(drive, run, tmp_path):
    out = tmp_path / "out"
    r = run("sequence", "convert", drive, "--sensor", "velodyne_vlp16", "--estimator", "embree-sources",
            "--remove-moving", "visibility", "-o", out, "--quiet")
    assert r.returncode == 2 and "--source-sensor" in r.stderr and not out.exists()
    r = run("sequence", "convert", drive, "--sensor", "velodyne_vlp16", "--keep-moving", "--remove-moving", "both",
            "--source-sensor", "velodyne_vlp16", "-o", out, "--quiet")
    assert r.returncode == 2 and "--keep-moving" in r.stderr and not out.exists()
    r = run("sequence", "convert", drive, "--sensor", "velodyne_vlp16", "--estimator", "embree-sources",
            "--source-sensor", "velodyne_vlp16", "--remove-moving", "both", "--half", "1", "-o", out, "--quiet")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["written"] == 5 and doc["settings"]["see_through"]["votes"] == 2
    labels = np.fromfile(out / "labels" / "000002.label", np.uint32)
    assert len(labels) > 1000 and not np.isin(labels & 0xFFFF, MOVING_CLASSES).any()
    # a rerun with another removal is refused (it would mix with these frames)
    r = run("sequence", "convert", drive, "--sensor", "velodyne_vlp16", "--estimator", "embree-sources",
            "--source-sensor", "velodyne_vlp16", "--half", "1", "-o", out, "--quiet")
    assert r.returncode == 2 and "see_through" in r.stderr


def test_an_e57_scans_rotation_is_its_frames(tmp_path):
    pye57 = pytest.importorskip("pye57")
    from slr_ray.sequence import accumulate
    path, local, world, R = tmp_path / "rotated.e57", [], [], []
    e = pye57.E57(str(path), mode="w")
    for k in range(2):
        axis = np.array([0.1, 0.2 * k - 0.1, 1.0])  # mostly a yaw, a little tilt
        axis /= np.linalg.norm(axis)
        angle = np.radians(30.0 + 90.0 * k)
        q = np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis]  # w, x, y, z
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        rot = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K  # Rodrigues
        p = np.random.default_rng(k).normal(size=(50, 3)) * 5
        t = np.array([10.0 * k, 2.0, 0.5])
        local.append(p), world.append(p @ rot.T + t), R.append(rot)
        e.write_scan_raw({"cartesianX": p[:, 0], "cartesianY": p[:, 1], "cartesianZ": p[:, 2]}, name=f"s{k}",
                         translation=t, rotation=q)
    e.close()
    seq = read_sequence(path)
    for k in range(2):
        assert np.abs(seq.poses[k, :3, :3] - R[k]).max() < 1e-6 and not np.allclose(R[k], np.eye(3))
        f = seq.read(k)
        assert np.abs(f.points - local[k]).max() < 1e-4  # the scanner's own axes (pye57 stores float32)
        assert np.abs(f.world() - world[k]).max() < 1e-4
    assert np.abs(accumulate(seq, [0, 1]).points - np.vstack(world)).max() < 1e-4


def test_one_las_of_several_scans_is_a_sequence(tmp_path, run):
    from slr_ray.io import PointCloud, write_cloud
    rng = np.random.default_rng(0)
    origins = np.array([[100.0, 200.0, 10.0], [110.0, 200.0, 10.0], [120.0, 201.0, 10.5]])
    parts = [o + rng.normal(size=(200, 3)) * 4 for o in origins]
    ids = np.repeat(np.array([9, 3, 5], np.uint16), 200)  # scans in the file in another order than their ids
    order = rng.permutation(600)
    cloud = PointCloud(np.vstack(parts)[order], {"point_source_id": ids[order]})
    write_cloud(tmp_path / "campaign.las", cloud)
    (tmp_path / "origins.txt").write_text("\n".join(" ".join(map(str, o)) for o in origins[[1, 2, 0]]) + "\n")
    seq = read_sequence(tmp_path / "campaign.las", origins=tmp_path / "origins.txt", scan_field="point_source_id")
    assert len(seq) == 3 and seq.meta["scan_ids"] == [3, 5, 9]
    for k, part in enumerate((1, 2, 0)):  # ids 3, 5, 9 ascending
        f = seq.read(k)
        assert len(f.points) == 200 and np.all(f.attributes["point_source_id"] == seq.meta["scan_ids"][k])
        assert np.abs(np.sort(f.world(), axis=0) - np.sort(parts[part], axis=0)).max() < 1e-3  # LAS: mm
        assert np.allclose(f.pose[:3, 3], origins[part])
    (tmp_path / "two.txt").write_text("0 0 0\n1 1 1\n")
    with pytest.raises(InputValueError, match="2 origins for 3 frames.*3 scans by its field"):
        read_sequence(tmp_path / "campaign.las", origins=tmp_path / "two.txt", scan_field="point_source_id")
    r = run("sequence", "evaluate", tmp_path / "campaign.las", "--origins", tmp_path / "origins.txt",
            "--scan-field", "nope", "--holdout", "1", "-o", tmp_path / "out")
    assert r.returncode == 2 and "no per-point field 'nope'" in r.stderr and not (tmp_path / "out").exists()


def test_convert_on_a_dask_scheduler_writes_what_local_workers_write(drive, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    from slr_ray.sequence import convert_sequence
    seq = read_sequence(drive)
    for name in ("local", "dask"):
        (tmp_path / name).mkdir()
    convert_sequence(seq, tmp_path / "local", "velodyne_vlp16", half=1, block=2)
    # one worker thread in this process (worker processes would start numba anew: 30 s under load)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        res = convert_sequence(seq, tmp_path / "dask", "velodyne_vlp16", half=1, block=2,
                               scheduler=cluster.scheduler_address)
    assert res["written"] == 5
    for i in range(5):
        a, b = (np.fromfile(tmp_path / d / "velodyne" / f"{i:06d}.bin", np.float32) for d in ("local", "dask"))
        assert len(a) > 1000 and np.array_equal(a, b)


def test_convert_on_a_scheduler_without_dask(drive, tmp_path, monkeypatch):
    from slr_ray.errors import MissingDependencyError
    from slr_ray.sequence import convert_sequence
    for name in ("dask", "dask.distributed"):
        monkeypatch.setitem(sys.modules, name, None)  # "import dask" now raises ImportError
    (tmp_path / "out").mkdir()
    with pytest.raises(MissingDependencyError, match=r'pip install "slr_ray\[dask\]"'):
        convert_sequence(read_sequence(drive), tmp_path / "out", "velodyne_vlp16", scheduler="tcp://127.0.0.1:1")
    assert not any((tmp_path / "out").iterdir())


def test_ring_values_outside_the_sensors_table_are_refused_naming_the_frame_and_its_file():
    """#48: a ring field of another sensor (rings 0-99 read with a 64-beam table) was refused as
    'beams must lie in [-1, 64) ...' with no frame or file named."""
    from slr_ray.sensors import sensor
    from slr_ray.sequence.embree_rays import frame_beams
    from slr_ray.sequence.layouts.base import Frame
    from slr_ray.sequence.sources import known_beams, source_view

    base = sensor("velodyne_hdl64e_s2")
    pts = np.random.default_rng(0).uniform(-20, 20, (500, 3))
    ring = np.arange(500) % 100
    what = "frame 000003 (drive/000003.pcd)"
    for call in (lambda: known_beams(pts, {"ring": ring}, base, what), lambda: source_view(pts, {"ring": ring}, base, what)):
        with pytest.raises(InputValueError, match=r"^frame 000003 \(drive/000003.pcd\): its ring field: beams must lie in "
                                                  r"\[-1, 64\).*got 0 \.\.\. 99.*--source-sensor"):
            call()
    frame = Frame(3, "000003", pts, {"ring": ring}, np.eye(4))
    with pytest.raises(InputValueError, match=r"^frame 000003 \(drive/000003.pcd\): its ring field"):
        frame_beams(frame, base, SimpleNamespace(paths=["a", "b", "c", "drive/000003.pcd"]))
    np.testing.assert_array_equal(known_beams(pts, {"ring": ring % 64}, base, what), ring % 64)  # in range: kept


def test_a_ring_field_outside_the_default_table_names_the_held_out_frame(tmp_path):
    """(hostile pass) an Ouster OS1-128 directory evaluated without --source-sensor was refused as
    'a frame: its ring field: ...': the frame and the default table it was read with not named."""
    from slr_ray.io import PointCloud, write_cloud
    from slr_ray.sequence import evaluate_sequence, read_sequence

    rng = np.random.default_rng(0)
    paths = []
    for i in range(2):
        paths.append(tmp_path / f"f{i}.npz")
        write_cloud(paths[-1], PointCloud(rng.uniform(-20, 20, (500, 3)), {"ring": np.arange(500) % 128}))
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.5 0 1 0 0 0 0 1 0\n")
    with pytest.raises(InputValueError, match=r"^frame 000001 \(.*f1.npz\), read with the default velodyne_hdl64e_s2's "
                                              r"table \(no --source-sensor named\): its ring field"):
        evaluate_sequence(read_sequence([str(p) for p in paths], str(poses)), [1], "auto", ["nearest"], half=1)
