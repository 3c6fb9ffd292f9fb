"""The output plan: every path a command reads and writes, checked once, before the work."""

import json
import multiprocessing
import os
import subprocess
import sys

import numpy as np
import pytest

from slr_ray.cli import main
from slr_ray.errors import OutputError
from slr_ray.io import PointCloud, atomic_path, read_cloud, write_cloud
from slr_ray.outputs import LOCK_NAME, OutputPlan, clean_stale_parts, content_digest, part_prefix


def _kitti(path, n=400, seed=0, labels=True):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-10, 10, (n, 3)).astype(np.float32)
    np.column_stack([pts, rng.uniform(size=n).astype(np.float32)]).tofile(path)
    if labels:
        rng.integers(0, 260, n).astype("<u4").tofile(path.with_suffix(".label"))
    return path


def _scan(src, out, *extra):
    return ["scan", str(src), "--origin", "0", "0", "0", "--resolution", "2", "-o", str(out), *extra]


def _tree(d):
    return sorted((str(p.relative_to(d)), p.read_bytes() if p.is_file() else None) for p in d.rglob("*"))


# --- the plan itself ------------------------------------------------------------------------------------------

def test_two_outputs_that_are_one_file_are_refused(tmp_path):
    plan = OutputPlan()
    plan.write(tmp_path / "s.npz")
    with pytest.raises(OutputError, match="named twice"):
        plan.write(tmp_path / "." / "s.npz")
    (tmp_path / "d").mkdir()
    os.symlink(tmp_path / "s.npz", tmp_path / "d" / "link.npz")
    with pytest.raises(OutputError, match="named twice"):
        plan.write(tmp_path / "d" / "link.npz")  # a link to an output is that output


def test_an_output_that_is_an_input_is_refused_by_path_link_and_hard_link(tmp_path):
    src = tmp_path / "in.npz"
    np.savez(src, points=np.zeros((3, 3)))
    os.symlink(src, tmp_path / "soft.npz")
    os.link(src, tmp_path / "hard.npz")
    for out in (src, tmp_path / "soft.npz", tmp_path / "hard.npz", tmp_path / "x" / ".." / "in.npz"):
        plan = OutputPlan(force=True)
        plan.read(src)
        plan.write(out)
        with pytest.raises(OutputError, match="input"):
            plan.check()


def test_existing_outputs_need_force_and_non_regular_files_are_refused(tmp_path):
    (tmp_path / "o.ply").write_text("old")
    plan = OutputPlan()
    plan.write(tmp_path / "o.ply")
    with pytest.raises(OutputError, match="--force"):
        plan.check()
    plan = OutputPlan(force=True)
    plan.write(tmp_path / "o.ply")
    plan.check()
    (tmp_path / "adir").mkdir()
    os.mkfifo(tmp_path / "fifo.ply")
    for bad in ("adir", "fifo.ply"):
        plan = OutputPlan(force=True)
        plan.write(tmp_path / bad)
        with pytest.raises(OutputError, match="directory|regular"):
            plan.check()
    plan = OutputPlan()
    plan.write(tmp_path / "nodir" / "o.ply")
    with pytest.raises(OutputError, match="no directory"):
        plan.check()


def test_writes_go_through_a_link_and_never_replace_it(tmp_path):
    target = tmp_path / "real.npz"
    target.write_text("old")
    link = tmp_path / "link.npz"
    os.symlink(target, link)
    write_cloud(link, PointCloud(np.ones((4, 3))))
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert np.load(target)["points"].shape == (4, 3)


def test_a_kitti_output_plans_its_label_sidecar(tmp_path):
    src = _kitti(tmp_path / "k.bin")
    # the input's own labels are never written over, with --force too
    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    (seq / "labels").mkdir()
    _kitti(seq / "velodyne" / "000000.bin", labels=False)
    np.zeros(400, "<u4").tofile(seq / "labels" / "000000.label")
    before = (seq / "labels" / "000000.label").read_bytes()
    assert main(_scan(seq / "velodyne" / "000000.bin", seq / "labels" / "000000.bin", "--force")) == 2
    assert (seq / "labels" / "000000.label").read_bytes() == before
    assert not (seq / "labels" / "000000.bin").exists()
    # an output .bin whose .label exists needs --force like the .bin itself
    (tmp_path / "o.label").write_bytes(b"mine")
    assert main(_scan(src, tmp_path / "o.bin")) == 2
    assert (tmp_path / "o.label").read_bytes() == b"mine" and not (tmp_path / "o.bin").exists()
    # --format bin writes a .label beside an output of another extension: planned too
    (tmp_path / "p.label").write_bytes(b"mine")
    assert main(_scan(src, tmp_path / "p.xyz", "--format", "bin")) == 2
    assert (tmp_path / "p.label").read_bytes() == b"mine"


def test_input_format_bin_plans_the_labels_it_reads_beside_any_name(tmp_path):
    # `--input-format bin` reads k.label beside k.dat: it is an input, never written over (--force too)
    src = _kitti(tmp_path / "k.dat")
    before = _tree(tmp_path)
    assert main(_scan(src, tmp_path / "k.bin", "--input-format", "bin", "--force")) == 2  # writes k.label
    assert main(_scan(src, tmp_path / "k.label", "--input-format", "bin", "--format", "npy", "--force")) == 2
    assert _tree(tmp_path) == before


def test_a_bin_written_through_a_link_leaves_no_stale_labels_beside_the_file_it_points_to(tmp_path):
    (tmp_path / "real").mkdir()
    (tmp_path / "view").mkdir()
    real = _kitti(tmp_path / "real" / "r.bin", n=50, seed=1)  # with its own labels
    os.symlink(real, tmp_path / "view" / "r.bin")
    src = _kitti(tmp_path / "k.bin")
    assert main(_scan(src, tmp_path / "view" / "r.bin", "--force")) == 0
    assert (tmp_path / "view" / "r.bin").is_symlink()
    direct, linked = read_cloud(real), read_cloud(tmp_path / "view" / "r.bin")
    assert len(direct) == len(linked) != 50
    for c in (direct, linked):  # the new labels wherever a reader looks, never the old ones
        assert np.array_equal(c.attributes["semantic"], linked.attributes["semantic"])
    # written without labels: neither place keeps labels paired with the new points
    write_cloud(tmp_path / "view" / "r.bin", PointCloud(np.zeros((5, 3))))
    assert not (tmp_path / "real" / "r.label").exists() and not (tmp_path / "view" / "r.label").exists()


def test_a_bin_written_without_labels_leaves_no_stale_labels_beside_it(tmp_path):
    out = tmp_path / "o.bin"
    np.arange(3, dtype="<u4").tofile(tmp_path / "o.label")
    write_cloud(out, PointCloud(np.zeros((5, 3))))
    assert not (tmp_path / "o.label").exists()


@pytest.mark.parametrize("flag", ["--range-image", "--png"])
def test_secondary_outputs_never_hit_an_input_or_each_other(tmp_path, flag):
    src = _kitti(tmp_path / "k.bin")
    sensor = tmp_path / "sensor.json"
    sensor.write_text(json.dumps({"beam_altitude_angles": [-10.0, 0.0, 10.0],
                                  "beam_azimuth_angles": [0.0, 0.0, 0.0], "columns_per_frame": 512}))
    before = _tree(tmp_path)
    base = ["scan", str(src), "--origin", "0", "0", "0", "--sensor-file", str(sensor), "-o"]
    assert main(base + [str(tmp_path / "s.npz"), flag, str(sensor), "--force"]) == 2  # the sensor file
    assert main(base + [str(tmp_path / "s.npz"), flag, str(tmp_path / "s.npz")]) == 2  # one file twice
    assert main(base + [str(tmp_path / "s.npz"), flag, str(tmp_path / "k.label"), "--force"]) == 2  # a sidecar
    assert _tree(tmp_path) == before


def test_positions_never_overwrite_its_profile(tmp_path, capsys):
    src = tmp_path / "c.npz"
    np.savez(src, points=np.zeros((10, 3)), is_ground=np.ones(10, bool))
    prof = tmp_path / "profile.json"
    prof.write_text("{}")
    assert main(["positions", str(src), "--n", "1", "--profile", str(prof), "-o", str(prof), "--force"]) == 2
    assert prof.read_text() == "{}"
    assert "input" in capsys.readouterr().err


# --- temporaries, locks -------------------------------------------------------------------------------------

def test_temporaries_name_their_writer_and_stale_ones_are_cleaned(tmp_path):
    out = tmp_path / "o.npz"
    with atomic_path(out) as tmp:
        assert tmp.name.startswith(part_prefix(out)) and ".part" in tmp.name
        tmp.write_text("x")
        assert clean_stale_parts(tmp_path) == []  # our own, alive: kept
    # one left by a process that no longer exists (kill -9)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale = tmp_path / part_prefix(out).replace(f".{os.getpid()}@", f".{dead}@")
    stale = stale.with_name(stale.name + "abc.part.npz")
    stale.write_text("half")
    src = tmp_path / "in.npz"
    np.savez(src, points=np.random.default_rng(0).normal(size=(50, 3)), origin=np.zeros(3))
    assert main(["scan", str(src), "--resolution", "5", "-o", str(out), "--force"]) == 0
    assert not stale.exists()


def _hold_lock(directory, ready, release):
    plan = OutputPlan()
    plan.directory(directory)
    with plan:
        ready.set()
        release.wait(30)


def test_two_runs_into_one_directory_cannot_both_proceed(tmp_path):
    ctx = multiprocessing.get_context("spawn")
    ready, release = ctx.Event(), ctx.Event()
    holder = ctx.Process(target=_hold_lock, args=(tmp_path / "run", ready, release))
    holder.start()
    try:
        assert ready.wait(60)
        plan = OutputPlan()
        plan.directory(tmp_path / "run")
        with pytest.raises(OutputError, match="in use by another slr-ray run"):
            with plan:
                pass
        assert (tmp_path / "run" / LOCK_NAME).exists()
    finally:
        release.set()
        holder.join(30)
    assert not (tmp_path / "run" / LOCK_NAME).exists()  # released, and removed
    with plan:  # now free
        pass


def test_a_failed_plan_removes_the_directories_it_created(tmp_path):
    plan = OutputPlan()
    plan.directory(tmp_path / "a" / "b")
    with pytest.raises(RuntimeError):
        with plan:
            assert (tmp_path / "a" / "b").is_dir()
            raise RuntimeError("boom")
    assert not (tmp_path / "a").exists()


# --- commands that write directories ---------------------------------------------------------------------------

def test_distances_and_demo_refuse_to_overwrite_without_force(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "slr.csv").write_text("mine")
    src = tmp_path / "c.npz"
    np.savez(src, points=np.zeros((10, 3)), origin=np.zeros(3), is_ground=np.ones(10, bool))
    assert main(["distances", str(src), "-o", str(tmp_path / "d"), "--quiet"]) == 2
    assert (tmp_path / "d" / "slr.csv").read_text() == "mine"
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "report.json").write_text("mine")
    assert main(["demo", "-o", str(tmp_path / "demo"), "--quick", "--positions", "1"]) == 2
    assert (tmp_path / "demo" / "report.json").read_text() == "mine"


def test_content_digest_sees_an_edit_that_keeps_size_and_mtime(tmp_path):
    p = tmp_path / "f.bin"
    p.write_bytes(b"a" * 100_000)
    st = p.stat()
    d = content_digest(p)
    with open(p, "r+b") as f:
        f.seek(54_321)
        f.write(b"b")
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert p.stat().st_size == st.st_size and p.stat().st_mtime_ns == st.st_mtime_ns
    assert content_digest(p) != d


# --- refused before the work: what cannot be written at all ------------------------------------------------------

def _deny_writing_in(monkeypatch, directory):
    """os.access as for a user who may not write in ``directory`` (tests run as root, who may)."""
    real = os.access

    def access(path, mode, **kw):
        if mode & os.W_OK and os.path.realpath(path) == os.path.realpath(directory):
            return False
        return real(path, mode, **kw)
    monkeypatch.setattr(os, "access", access)


def test_an_unwritable_directory_is_refused_before_the_work(tmp_path, monkeypatch, capsys):
    src = _kitti(tmp_path / "k.bin")
    ro = tmp_path / "ro"
    ro.mkdir()
    _deny_writing_in(monkeypatch, ro)
    before = _tree(tmp_path)
    assert main(_scan(src, ro / "o.npz")) == 2
    assert "no permission to write in" in capsys.readouterr().err
    # an output directory to create there: its nearest existing parent is what must be writable
    assert main(["distances", str(src), "-o", str(ro / "sub"), "--origin", "0", "0", "0", "--quiet"]) == 2
    assert "no permission to write in" in capsys.readouterr().err
    plan = OutputPlan()
    plan.directory(ro)
    with pytest.raises(OutputError, match="no permission"):
        plan.check()
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("command", ["scan", "positions", "compare"])
def test_a_figure_format_matplotlib_cannot_write_is_refused_before_the_work(tmp_path, capsys, command):
    src = tmp_path / "c.npz"
    rng = np.random.default_rng(0)
    np.savez(src, points=rng.normal(size=(200, 3)) * 5, origin=np.zeros(3), is_ground=np.ones(200, bool))
    before = _tree(tmp_path)
    argv = {"scan": _scan(src, tmp_path / "s.npz"),
            "positions": ["positions", str(src), "--n", "1", "--min-ground-points", "1", "-o",
                          str(tmp_path / "p.json")],
            "compare": ["compare", str(src), "--origin", "0", "0", "0", "--resolution", "2"]}[command]
    assert main(argv + ["--png", str(tmp_path / "fig.xyz")]) == 2  # was: the scan written, then a traceback
    err = capsys.readouterr().err
    assert "fig.xyz" in err and "Traceback" not in err
    assert _tree(tmp_path) == before


def test_a_scene_spec_of_any_extension_is_an_input(tmp_path):
    spec = tmp_path / "scene.txt"  # a TOML spec need not end in .toml, and .txt is a point format
    spec.write_text('[scene]\nn_rectangles = 3\nseed = 0\n')
    before = spec.read_text()
    assert main(["scene", "scan", str(spec), "--origin", "0", "0", "0", "--resolution", "5", "--quiet",
                 "-o", str(spec), "--force"]) == 2
    assert spec.read_text() == before


def test_validate_never_writes_its_reports_over_its_config(tmp_path):
    out = tmp_path / "v"
    out.mkdir()
    config = out / "report.md"  # a config named like a report the command writes into its directory
    config.write_text('[validate]\nname = "x"\nscenes = ["rect-0500"]\npositions = 1\n')
    before = _tree(tmp_path)
    assert main(["validate", str(config), "-o", str(out), "--quiet"]) == 2
    assert main(["validate", str(config), "-o", str(config), "--quiet"]) == 2
    assert _tree(tmp_path) == before


def test_a_demo_whose_file_plan_would_exhaust_memory_is_refused_first(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path / "d"), "--quick", "--positions", str(10**12)]) == 2  # was: OOM
    assert "would need about" in capsys.readouterr().err and not (tmp_path / "d").exists()


def test_a_bin_written_into_the_semantickitti_layout_never_leaves_another_frames_labels_paired(tmp_path, capsys):
    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    (seq / "labels").mkdir()
    src = _kitti(tmp_path / "k.bin")  # with labels beside it
    old = seq / "labels" / "000001.label"  # the labels of a frame this scan will replace
    np.full(7, 9, "<u4").tofile(old)
    out = seq / "velodyne" / "000001.bin"
    assert main(_scan(src, out)) == 2  # its labels exist: --force, as for the .bin itself
    assert "000001.label exists" in capsys.readouterr().err and old.read_bytes() == np.full(7, 9, "<u4").tobytes()
    assert main(_scan(src, out, "--force")) == 0
    back = read_cloud(out)  # the new labels, in labels/ where SemanticKITTI's tools look (were: the old frame's)
    assert len(back.attributes["semantic"]) == len(back) and old.stat().st_size == 4 * len(back)
    assert not (seq / "velodyne" / "000001.label").exists()
    write_cloud(out, PointCloud(np.zeros((3, 3))), "bin")  # without labels: the stale ones go
    assert not old.exists() and "semantic" not in read_cloud(out).attributes
    # a .bin outside velodyne/ never reads or removes a labels/ file of the directory above
    (tmp_path / "other").mkdir()
    np.zeros(3, "<u4").tofile(tmp_path / "labels.label")
    (tmp_path / "labels").mkdir()
    np.zeros(3, "<u4").tofile(tmp_path / "labels" / "f.label")
    write_cloud(tmp_path / "other" / "f.bin", PointCloud(np.zeros((3, 3))))
    assert (tmp_path / "labels" / "f.label").exists()
    assert "semantic" not in read_cloud(tmp_path / "other" / "f.bin").attributes
