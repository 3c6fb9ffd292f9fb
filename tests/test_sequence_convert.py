"""`sequence convert`'s output directory (#48): what it locks, resumes, refuses and publishes.
A tiny synthetic drive (4 frames, VLP-16), converted nearest-a-frame."""

import errno
import json
import shutil
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import slr_ray.sequence.convert as C
from slr_ray.cli import main
from slr_ray.errors import InputValueError, OutputError, SlrError, SlrWarning
from slr_ray.io import read_cloud
from slr_ray.io.outputs import OutputPlan
from slr_ray.sequence import convert_sequence, read_sequence
from slr_ray.sequence.synthetic import synthetic_drive

SENSOR = "velodyne_vlp16"


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("drive") / "seq"
    synthetic_drive(root, n_frames=4, sensor=SENSOR, step=0.8)
    return root


def _convert(root, out, **kw):
    out.mkdir(exist_ok=True)
    kw = {"half": 1, "block": 1} | kw
    return convert_sequence(read_sequence(root), out, SENSOR, **kw)


def _interrupt_after(monkeypatch, n_blocks, exc=KeyboardInterrupt):
    """The run stops (Ctrl-C) when the ``n_blocks + 1``-th block starts."""
    real, calls = C._job, []

    def job(block, out, token):
        calls.append(block)
        if len(calls) > n_blocks:
            raise exc()
        return real(block, out, token)

    monkeypatch.setattr(C, "_job", job)
    return calls


def _bytes(d):
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_a_file_written_into_velodyne_during_a_conversion_is_refused(drive, tmp_path, monkeypatch):
    # (#48 item 1) the lock covers the subdirectories convert writes into
    out, real, tried = tmp_path / "out", C._job, []

    def job(block, out_, token):
        plan = OutputPlan()
        plan.write(out / "velodyne" / "000011.bin")  # what scan -o OUT/velodyne/000011.bin plans
        with pytest.raises(OutputError, match="in use by another slr-ray run"):
            with plan:
                pass
        tried.append(1)
        return real(block, out_, token)

    monkeypatch.setattr(C, "_job", job)
    _convert(drive, out)
    assert tried and not (out / "velodyne" / "000011.bin").exists()
    assert not list(out.rglob(".slr_ray.lock"))  # released


def test_a_resume_never_writes_over_a_file_it_did_not_write(drive, tmp_path, monkeypatch):
    # (#48 item 2) planted before the resume: refused before any work, left as it is
    out = tmp_path / "out"
    _interrupt_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        _convert(drive, out)
    monkeypatch.undo()
    planted = out / "velodyne" / "000002.bin"
    planted.write_bytes(b"mine")
    with pytest.raises(OutputError, match="000002.bin.*does not list"):
        _convert(drive, out)
    assert planted.read_bytes() == b"mine"
    # planted while the resume runs, after its checks: published without replacing, so refused too
    planted.unlink()
    real, theirs = C._job, out / "velodyne" / "000001.bin"

    def job(block, out_, token):
        entries = real(block, out_, token)
        theirs.write_bytes(b"theirs")
        return entries

    monkeypatch.setattr(C, "_job", job)
    with pytest.raises(OutputError, match="000001.bin appeared in the output directory"):
        _convert(drive, out)
    assert theirs.read_bytes() == b"theirs" and not (out / "labels" / "000001.label").exists()
    monkeypatch.undo()  # moved away, the rerun resumes
    theirs.unlink()
    assert _convert(drive, out)["written"] == 3


def test_workers_write_only_their_runs_staging_directory(drive, tmp_path, monkeypatch):
    # (#48 item 3) a worker of an interrupted run (a Dask task cancelled too late) writes into its
    # run's staging directory, gone once the run ends: never a frame under a final name
    out = tmp_path / "out"
    _interrupt_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        _convert(drive, out)
    monkeypatch.undo()
    before = _bytes(out)
    assert not [p for p in out.iterdir() if p.name.startswith(C.STAGE_PREFIX)]
    token = "0" * 32
    seq = read_sequence(drive)
    with pytest.raises((OSError, SlrError)):  # the late worker: its staging directory is gone
        C._dask_job([2], str(out), seq, seq.poses, json.loads((out / C.MANIFEST).read_text())["settings"], token)
    assert _bytes(out) == before
    # a killed run's staging directory (kill -9: never removed) is not published by the next run
    stale = out / f"{C.STAGE_PREFIX}{'1' * 32}" / "velodyne"
    stale.mkdir(parents=True)
    (stale / "000003.bin").write_bytes(b"old run")
    _convert(drive, out)
    journal = [json.loads(line) for line in (out / C.JOURNAL).read_text().splitlines()]
    assert sorted(e["frame"] for e in journal) == [0, 1, 2, 3]
    assert (out / "velodyne" / "000003.bin").read_bytes() != b"old run"
    assert not [p for p in out.iterdir() if p.name.startswith(C.STAGE_PREFIX)]


def test_a_frame_without_labels_among_labelled_ones_is_refused(drive, tmp_path):
    # (#48 item 4) it would strip its neighbours' labels and keep its moving objects
    root = tmp_path / "seq"
    shutil.copytree(drive, root)
    (root / "labels" / "000002.label").unlink()
    with pytest.raises(InputValueError, match="000002.*no labels") as e:
        _convert(root, tmp_path / "out")
    assert "\n" not in str(e.value)
    assert not any((tmp_path / "out").iterdir())


def test_inputs_are_known_by_content_not_path(drive, tmp_path, monkeypatch):
    # (#48 item 6)
    root = tmp_path / "seq"
    shutil.copytree(drive, root)
    out = tmp_path / "out"
    _interrupt_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        _convert(root, out)
    monkeypatch.undo()
    monkeypatch.chdir(tmp_path)  # the same frames by a relative path: resumed, not "other settings"
    res = convert_sequence(read_sequence("seq"), out, SENSOR, half=1, block=1)
    assert res["resumed"] == 1 and res["written"] == 3
    # a frame edited since: refused, naming it
    with open(root / "velodyne" / "000001.bin", "r+b") as f:
        f.write(np.float32(0.5).tobytes())
    with pytest.raises(InputValueError, match="frame 1's content"):
        _convert(root, out)
    # another sequence at the same path: refused
    shutil.rmtree(root)
    synthetic_drive(root, n_frames=4, sensor=SENSOR, step=0.9)
    with pytest.raises(InputValueError, match="other settings"):
        _convert(root, out)


def test_a_failure_in_the_first_block_leaves_nothing_and_the_fixed_rerun_runs(drive, tmp_path, monkeypatch):
    # (#48 item 7) frame 0 converted, frame 1 fails: no orphan frame without a manifest
    out = tmp_path / "out"
    real = C._frame_cloud

    def frame_cloud(seq, i, *a):
        if i == 1:
            raise InputValueError("frame 1 is broken")
        return real(seq, i, *a)

    monkeypatch.setattr(C, "_frame_cloud", frame_cloud)
    with pytest.raises(InputValueError):
        _convert(drive, out, block=4)
    assert list(out.iterdir()) == []
    monkeypatch.undo()
    assert _convert(drive, out, block=4)["written"] == 4


def test_a_conversion_of_nothing_is_an_error_at_its_first_frame(drive, tmp_path, monkeypatch):
    # (#48 item 7) --offset 1000 0 0: no pulse returns
    out, real, calls = tmp_path / "out", C._frame_cloud, []
    monkeypatch.setattr(C, "_frame_cloud", lambda *a: calls.append(1) or real(*a))
    with pytest.raises(OutputError, match="frame 000000: no pulse") as e:
        _convert(drive, out, offset=(1000.0, 0.0, 0.0), block=4)
    assert len(calls) == 1 and "\n" not in str(e.value)
    assert list(out.iterdir()) == []


def test_a_frame_whose_labels_are_gone_is_converted_again(drive, tmp_path):
    # (#48 item 10)
    out = tmp_path / "out"
    _convert(drive, out)
    want = _bytes(out / "labels")
    (out / "labels" / "000001.label").unlink()
    with pytest.warns(SlrWarning, match="000001.*converting it again"):
        res = _convert(drive, out)
    assert res["written"] == 1 and _bytes(out / "labels") == want
    c = read_cloud(out / "velodyne" / "000001.bin")
    assert "semantic" in c.attributes


@pytest.mark.parametrize("edit", ["file", "junk", "frame"])
def test_a_journal_it_did_not_write_is_refused_in_one_line(drive, tmp_path, monkeypatch, edit):
    # (#48 item 10, crashes) a hand-edited 'file', a line of junk, a frame out of range
    out = tmp_path / "out"
    _interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        _convert(drive, out)
    monkeypatch.undo()
    j = out / C.JOURNAL
    lines = j.read_text().splitlines()
    e = json.loads(lines[0])
    if edit == "file":
        lines[0] = json.dumps(e | {"file": "../../elsewhere.bin"})
    elif edit == "junk":
        lines[0] = "[1, 2"
    else:
        lines[0] = json.dumps(e | {"frame": 99})
    j.write_text("\n".join(lines) + "\n")
    before = _bytes(out)
    with pytest.raises(InputValueError, match="journal.jsonl line 1 is not an entry") as exc:
        _convert(drive, out)
    assert "\n" not in str(exc.value) and _bytes(out) == before


@pytest.mark.parametrize("text", ["[]", '{"settings": "x"}', "{not json", "\xff\xfe"])
def test_a_manifest_it_cannot_read_is_refused_in_one_line(drive, tmp_path, text):
    out = tmp_path / "out"
    out.mkdir()
    (out / C.MANIFEST).write_bytes(text.encode("latin-1"))
    with pytest.raises(InputValueError, match="manifest.json") as e:
        _convert(drive, out)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("fmt,error", [("laz", OSError(errno.ENOSPC, "No space left on device")),
                                       ("laz", RuntimeError("lazrs: No space left on device (os error 28)")),
                                       ("e57", RuntimeError("E57 element path well-formed, but not defined"))])
def test_a_writer_failing_is_one_output_error_naming_the_frame(drive, tmp_path, monkeypatch, fmt, error):
    # full disk in LAZ (laspy / lazrs) or E57 (pye57): the library's own exception, said in one line
    import laspy
    import pye57

    def fail(*a, **k):
        raise error

    monkeypatch.setattr(laspy.LasData, "write", fail)
    monkeypatch.setattr(pye57.E57, "make_buffers", fail)
    with pytest.raises(OutputError, match=r"cannot write frame 000000 \(" + fmt) as e:
        _convert(drive, tmp_path / "out", fmt=fmt)
    assert "\n" not in str(e.value)
    assert list((tmp_path / "out").iterdir()) == []


def _cli(capsys, *args):
    capsys.readouterr()
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return SimpleNamespace(returncode=rc, stdout=out.out, stderr=out.err)


def test_evaluate_into_a_directory_that_is_not_empty_needs_force(drive, tmp_path, capsys):
    # (#48 item 16)
    out = tmp_path / "ev"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    r = _cli(capsys, "sequence", "evaluate", drive, "--holdout", "1", "--source-sensor", SENSOR, "-o", out, "--quiet")
    assert r.returncode == 2 and "is not empty (notes.txt)" in r.stderr and "--force" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_convert_refuses_force(drive, tmp_path, capsys):
    # (#48 item 16) it had no effect: now said
    r = _cli(capsys, "sequence", "convert", drive, "--target-sensor", SENSOR, "-o", tmp_path / "c", "--force", "--quiet")
    assert r.returncode == 2 and "no --force" in r.stderr and not (tmp_path / "c").exists()


def test_a_field_convert_does_not_carry_is_named(drive, tmp_path):
    # (hostile pass) an E57's colour, a PCD's normals, a LAS's extra dimensions were dropped
    # from the converted frames without a word; intensity and the labels are carried
    from slr_ray.io import PointCloud, write_cloud
    paths = []
    for i, f in enumerate(sorted((drive / "velodyne").glob("*.bin"))[:2]):
        c = read_cloud(f)
        n = len(c)
        paths.append(tmp_path / "in" / f"f{i}.npz")
        paths[-1].parent.mkdir(exist_ok=True)
        write_cloud(paths[-1], PointCloud(c.points, {"intensity": c.attributes["intensity"],
                                                     "red": np.arange(n) % 256, "normal_x": np.ones(n),
                                                     "unused": np.zeros(n)}))
    poses = tmp_path / "in" / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.8 0 1 0 0 0 0 1 0\n")
    out = tmp_path / "out"
    out.mkdir()
    # "unused" is all 0: nothing lost, not named
    with pytest.warns(SlrWarning, match=r"not carried into the converted frames: normal_x, red \(") as got:
        convert_sequence(read_sequence(paths, str(poses)), out, SENSOR, half=1, fmt="npz")
    assert len([w for w in got if "not carried" in str(w.message)]) == 1  # said once, not a frame
    assert set(read_cloud(out / "velodyne" / "000000.npz").attributes) == {"intensity", "ring"}


def test_a_format_that_carries_the_labels_leaves_no_empty_labels_directory(drive, tmp_path):
    # (hostile pass) --format ply of a labelled sequence: the labels are in each .ply, and an
    # empty labels/ was left beside velodyne/ (a SemanticKITTI reader takes it for frames without labels)
    out = tmp_path / "out"
    _convert(drive, out, fmt="ply")
    assert not (out / "labels").exists()
    assert "semantic" in read_cloud(out / "velodyne" / "000001.ply").attributes
    assert _convert(drive, out, fmt="ply")["resumed"] == 4


def test_frames_without_intensity_converted_to_bin_say_it_is_zero(drive, tmp_path):
    # (hostile pass) a KITTI .bin's fourth column was filled with 0 without a word
    paths = []
    for i, f in enumerate(sorted((drive / "velodyne").glob("*.bin"))[:2]):
        paths.append(tmp_path / f"f{i}.npy")
        np.save(paths[-1], read_cloud(f).points)
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.8 0 1 0 0 0 0 1 0\n")
    for fmt, said in (("bin", True), ("npz", False)):
        out = tmp_path / fmt
        out.mkdir()
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            convert_sequence(read_sequence(paths, str(poses)), out, SENSOR, half=1, fmt=fmt)
        assert any("no intensity field" in str(w.message) for w in got) == said


def test_a_sensor_card_edited_since_is_not_resumed(drive, tmp_path, capsys):
    # (hostile pass) --target-sensor card.json edited between runs: the resume kept three frames of
    # the old card and converted the fourth with the new one, mixed without a word (the manifest held
    # the card's path only)
    card = tmp_path / "vlp.json"
    assert main(["sensor", "show", SENSOR]) == 0
    card.write_text(capsys.readouterr().out)
    out = tmp_path / "out"
    out.mkdir()
    convert_sequence(read_sequence(drive), out, str(card), half=1)
    (out / "velodyne" / "000002.bin").unlink()
    doc = json.loads(card.read_text())
    doc["elevation_deg"] = [e + 3 for e in doc["elevation_deg"]]
    card.write_text(json.dumps(doc))
    with pytest.raises(InputValueError, match="other settings.*sensor_card"):
        convert_sequence(read_sequence(drive), out, str(card), half=1)
    assert not (out / "velodyne" / "000002.bin").exists()


def test_labels_read_with_the_frames_are_written_as_label_files(drive, tmp_path):
    # (hostile pass) .npz frames with a semantic field converted to .bin: the labels were staged
    # beside each .bin, never published, and the frames came out without labels, without a word
    from slr_ray.io import write_cloud
    paths = []
    for i, f in enumerate(sorted((drive / "velodyne").glob("*.bin"))[:2]):
        paths.append(tmp_path / "in" / f"f{i}.npz")
        paths[-1].parent.mkdir(exist_ok=True)
        write_cloud(paths[-1], read_cloud(f))
    poses = tmp_path / "in" / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.8 0 1 0 0 0 0 1 0\n")
    out = tmp_path / "out"
    out.mkdir()
    convert_sequence(read_sequence(paths, str(poses)), out, SENSOR, half=1)
    for name in ("000000", "000001"):
        c = read_cloud(out / "velodyne" / f"{name}.bin")
        assert "semantic" in c.attributes and len(c.attributes["semantic"]) == len(c)


def test_a_writers_warning_names_the_frames_not_the_staging_file_once(drive, tmp_path):
    # (hostile pass) --format npy: "OUT/.convert-TOKEN/velodyne/000000.npy: .npy columns keep values,
    # not names ..." once a frame, naming the hidden staging file that is gone after the run
    out = tmp_path / "out"
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        _convert(drive, out, fmt="npy")
    said = [str(w.message) for w in got if ".npy columns" in str(w.message)]
    assert len(said) == 1 and ".convert-" not in said[0] and said[0].startswith(str(out / "velodyne" / "*.npy"))
    with warnings.catch_warnings(record=True) as got:  # the next conversion in this process says it again
        warnings.simplefilter("always")
        _convert(drive, tmp_path / "again", fmt="npy")
    assert len([w for w in got if ".npy columns" in str(w.message)]) == 1


def test_a_frame_copied_under_another_name_is_said(drive, tmp_path):
    # (hostile pass) the same frame by two paths (a copy) was accumulated at both poses without a word
    frames = sorted((drive / "velodyne").glob("*.bin"))[:2]
    copy = tmp_path / "copy.bin"
    shutil.copyfile(frames[0], copy)
    shutil.copyfile(drive / "labels" / "000000.label", copy.with_suffix(".label"))
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.8 0 1 0 0 0 0 1 0\n")
    for paths, said in (([frames[0], copy], True), (frames, False)):
        out = tmp_path / f"out{said}"
        out.mkdir()
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            convert_sequence(read_sequence([str(p) for p in paths], str(poses)), out, SENSOR, half=1)
        assert any("hold the same content" in str(w.message) for w in got) == said


@pytest.mark.parametrize("workers,least", [(2, 16), (2, 1), (3, 4), (1, 8)])
def test_a_pools_runs_are_consecutive_frames_covering_the_work_in_order(workers, least):
    # (#46 item 4) a worker converts runs of consecutive frames (its cache slides: each frame read and
    # meshed once by it), never blocks handed out in turn (each block's window read anew)
    rng = np.random.default_rng(workers * 100 + least)
    for n in (1, 7, 40, 200):
        todo = sorted(rng.choice(n + 5, size=n, replace=False).tolist()) if n < 40 else list(range(n))
        runs = C._spans(todo, workers, least)
        assert [i for r in runs for i in r] == todo
        assert all(r == list(range(r[0], r[0] + len(r))) for r in runs)
        for r, nxt in zip(runs, runs[1:]):  # a run shorter than least ends at a gap in the work
            assert len(r) >= least or nxt[0] != r[-1] + 1
        if todo == list(range(n)):
            assert len(runs) <= -(-n // least) and len(runs) <= max(1, 2 * workers * (1 + int(np.log2(n + 1))))


def test_two_worker_processes_write_what_one_writes_each_frame_recorded_alone(drive, tmp_path, monkeypatch):
    # (#46 item 4) the pool's workers each take runs of frames and report every frame as it is written
    one = _convert(drive, tmp_path / "one", block=4)
    monkeypatch.setattr(C, "_SPAN_LEAST", 1)  # 4 frames: runs of one or two frames, both workers busy
    two = _convert(drive, tmp_path / "two", block=4, workers=2)
    assert one["written"] == two["written"] == 4 and one["points"] == two["points"]
    a, b = _bytes(tmp_path / "one"), _bytes(tmp_path / "two")
    for d in (a, b):
        d.pop(C.JOURNAL)
    assert a == b
    journal = [json.loads(line) for line in (tmp_path / "two" / C.JOURNAL).read_text().splitlines()]
    assert sorted(e["frame"] for e in journal) == [0, 1, 2, 3]


def test_a_schedulers_blocks_are_chains_of_consecutive_frames():
    # (#46 item 4) on Dask each block of a chain depends on the one before, so it runs where that one
    # did: a worker's cache slides along the chain's consecutive frames
    blocks = [[4 * k + j for j in range(4)] for k in range(50)] + [[200, 201]]
    for workers in (1, 2, 3):
        chains = C._dask_chains(blocks, workers, 4)
        assert [i for c in chains for b in c for i in b] == list(range(202))
        for c in chains:
            frames = [i for b in c for i in b]
            assert frames == list(range(frames[0], frames[0] + len(frames)))
            assert all(1 <= len(b) <= 4 for b in c)
        assert len(chains) == workers  # one a worker: a freed worker goes on with its own chain


def test_a_workers_cache_holds_its_window_reading_each_frame_once(tmp_path, monkeypatch):
    # (#46 item 4) the window slides: each frame read once, and no more frames held than a window
    # (with embree-rays each held frame keeps its mesh's Embree scene: 20 held for --half 2 was 1.46 GiB)
    from slr_ray.sequence.union import FrameCache
    root = tmp_path / "seq"
    synthetic_drive(root, n_frames=8, sensor=SENSOR, step=0.8)
    reads, held, real = [], [], FrameCache.get

    def get(self, i):
        if i not in self._held:
            reads.append(i)
        out = real(self, i)
        held.append(len(self._held))
        return out

    monkeypatch.setattr(FrameCache, "get", get)
    _convert(root, tmp_path / "out", half=1, block=3)
    assert sorted(reads) == list(range(8)) and max(held) <= 2 * 1 + 2


def test_the_input_format_is_a_setting_a_resume_compares(drive, tmp_path):
    """The frames read as another format (--input-format bin: KITTI's four floats a point, where the first
    run read the nuScenes .pcd.bin files as named, five) are other frames of the same files: refused, not
    resumed into the first run's directory (failed before: the format was not recorded, and the run
    resumed, mixing the two). Given as the files' own format, it is the same run: resumed."""
    src = tmp_path / "frames"
    src.mkdir()
    for f in sorted((drive / "velodyne").glob("*.bin")):
        a = np.fromfile(f, np.float32).reshape(-1, 4)
        a = a[: len(a) // 4 * 4]  # whole points in both formats
        np.column_stack([a, np.zeros(len(a), np.float32)]).astype(np.float32).tofile(src / f"{f.stem}.pcd.bin")
    paths, poses = sorted(src.glob("*.pcd.bin")), read_sequence(drive).poses
    out = tmp_path / "out"
    out.mkdir()

    def run(fmt):
        return convert_sequence(read_sequence(paths, poses, input_format=fmt), out, SENSOR, half=1, block=4)

    assert run(None)["written"] == 4
    assert run("pcd.bin")["resumed"] == 4
    with pytest.raises(InputValueError, match=r"other settings \(input_format\)"):
        run("bin")
    assert json.loads((out / C.MANIFEST).read_text())["settings"].get("input_format") is None


def test_target_poses_and_an_offset_are_both_applied_and_said(drive, tmp_path, capsys):
    """--target-poses with --offset: the offset moves each target pose in its own axes (neither is ignored);
    poses.txt holds the poses cast from; the help of both flags says so (it did not: an offset beside a
    trajectory read as one of them ignored)."""
    from slr_ray.sequence import read_trajectory

    seq = read_sequence(drive)
    target = seq.poses.copy()
    c, s_ = np.cos(0.3), np.sin(0.3)
    target[:, :3, :3] = target[:, :3, :3] @ np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])  # turned: axes matter
    tp = tmp_path / "target.txt"
    np.savetxt(tp, target[:, :3, :].reshape(len(target), 12))
    out = tmp_path / "out"
    assert main(["sequence", "convert", str(drive), "--target-sensor", SENSOR, "--half", "1", "--target-poses",
                 str(tp), "--offset", "1", "0", "0.5", "-o", str(out), "--quiet"]) == 0
    capsys.readouterr()
    given = seq.trajectory(str(tp))[0]  # as the command reads it (a KITTI directory's: the camera's, by Tr)
    want = given.copy()
    want[:, :3, 3] += given[:, :3, :3] @ np.array([1.0, 0.0, 0.5])
    np.testing.assert_allclose(read_trajectory(out / "poses.txt", len(seq)), want, atol=1e-9)
    try:
        main(["sequence", "convert", "--help"])
    except SystemExit:
        pass
    text = " ".join(capsys.readouterr().out.split())
    assert "with --target-poses, in each target pose's own axes (both applied)" in text


def test_a_dask_workers_threads_do_not_share_a_frames_cache(drive, monkeypatch):
    """A Dask worker of several threads runs blocks at once: each thread holds its own state (its frames
    cache, not thread-safe), kept for its next blocks; they shared the module's, which a thread's first
    block cleared and set up while another read it (failed before: one cache for both threads)."""
    import threading

    seq = read_sequence(drive)
    settings = {"sensor": SENSOR, "radius": None, "half": 1, "cache": 1, "drop_moving": True}
    barrier, seen, lock = threading.Barrier(2), {}, threading.Lock()

    def job(block, out, token, state=None):
        cache = (C._STATE if state is None else state).get("cache")
        barrier.wait(timeout=10)  # both threads' blocks at once
        with lock:
            seen.setdefault(threading.get_ident(), []).append(id(cache))
        return []

    monkeypatch.setattr(C, "_job", job)

    def blocks():
        for b in ([0], [1]):
            C._dask_job(b, "out", seq, seq.poses, settings, "a" * 32)

    threads = [threading.Thread(target=blocks) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    ids = list(seen.values())
    assert len(ids) == 2 and all(len(set(i)) == 1 and len(i) == 2 for i in ids), ids  # kept between its blocks
    assert ids[0][0] != ids[1][0]  # not shared
