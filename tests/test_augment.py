import dataclasses
import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from slr_ray import InputValueError, SlrWarning
from slr_ray.augment import AugmentConfig, augment
from slr_ray.cli import main
from slr_ray.errors import SlrError
from slr_ray.io import PointCloud, read_cloud, write_cloud


@pytest.fixture(scope="module")
def laz(tmp_path_factory):
    rng = np.random.default_rng(0)
    g = np.column_stack([rng.uniform(-20, 20, (150_000, 2)), rng.normal(0, 0.02, 150_000)])
    o = np.column_stack([rng.uniform(-20, 20, (30_000, 2)), rng.uniform(0.5, 5, 30_000)])
    pts = np.vstack([g, o]) + [5e5, 4e6, 100]
    cls = np.r_[np.full(150_000, 2, np.uint8), np.ones(30_000, np.uint8)]
    path = tmp_path_factory.mktemp("in") / "scan.laz"
    write_cloud(path, PointCloud(pts, {"classification": cls, "intensity": np.arange(180_000, dtype=np.uint16)}))
    return path


def _run(src, out, n, *, ground=None, progress=False, **settings):
    return augment(src, out, AugmentConfig(n=n, **settings), ground=ground, progress=progress)


def _files(d):
    return {p.name: read_cloud(p) for p in sorted(d.iterdir()) if p.suffix == ".laz"}


def test_serial_local_processes_and_dask_give_the_same_scans(laz, tmp_path):
    a = _run(laz, tmp_path / "serial", 3, heights=(1.0, 2.0), min_ground_points=1000, workers=1, progress=False)
    _run(laz, tmp_path / "procs", 3, heights=(1.0, 2.0), min_ground_points=1000, workers=2, progress=False)
    assert len(a["scans"]) == 6 and a["software"].startswith("slr_ray")
    fa, fb = _files(tmp_path / "serial"), _files(tmp_path / "procs")
    assert sorted(fa) == sorted(fb) and len(fa) == 6
    for name in fa:
        np.testing.assert_array_equal(fa[name].points, fb[name].points)
        np.testing.assert_array_equal(fa[name].attributes["intensity"], fb[name].attributes["intensity"])
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        _run(laz, tmp_path / "dask", 3, heights=(1.0, 2.0), min_ground_points=1000,
                scheduler=cluster.scheduler_address, progress=False)
    fc = _files(tmp_path / "dask")
    for name in fa:
        np.testing.assert_array_equal(fa[name].points, fc[name].points)


def test_manifest_and_attributes(laz, tmp_path):
    m = _run(laz, tmp_path / "o", 2, min_ground_points=1000, workers=1, progress=False)
    disk = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert disk["scans"] == m["scans"] and len(disk["positions"]) == 2
    src = read_cloud(laz)
    for s in m["scans"]:
        c = read_cloud(tmp_path / "o" / s["file"])
        assert len(c) == s["points"] > 100
        # every point comes from the input, with its attributes
        from scipy.spatial import cKDTree

        d, idx = cKDTree(src.points - src.points.mean(0)).query(c.points - src.points.mean(0))
        assert d.max() < 1e-6
        np.testing.assert_array_equal(c.attributes["intensity"], src.attributes["intensity"][idx])
        np.testing.assert_array_equal(c.attributes["classification"], src.attributes["classification"][idx])
    again = _run(laz, tmp_path / "o", 2, min_ground_points=1000, workers=1, progress=False)
    assert again["new_scans"] == 0


def test_interrupted_run_resumes_to_the_same_result(laz, tmp_path):
    cmd = [sys.executable, "-m", "slr_ray.cli", "augment", str(laz), "--n", "12", "--min-ground-points",
           "1000", "--workers", "1", "--quiet", "-o"]
    full = tmp_path / "full"
    # the uninterrupted reference is the same command run in this process (an interpreter
    # start and the package's import less); the interrupted run and its resume stay processes
    # of their own, so the resume still starts from nothing but what the first left on disk
    assert main(cmd[3:] + [str(full)]) == 0
    part = tmp_path / "part"
    proc = subprocess.Popen(cmd + [str(part)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and not any(p.suffix == ".laz" for p in part.glob("*.laz")):
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    proc.wait(60)
    # no half-written scan under a final name
    for p in part.glob("*.laz"):
        read_cloud(p)
    subprocess.run(cmd + [str(part)], check=True, capture_output=True)
    fa, fb = _files(full), _files(part)
    assert sorted(fa) == sorted(fb) and len(fa) == 12
    for name in fa:
        np.testing.assert_array_equal(fa[name].points, fb[name].points)
    assert not [p for p in part.iterdir() if p.name.startswith(".")]


def test_bad_inputs(laz, tmp_path, capsys):
    from slr_ray.cli import main

    nolabel = tmp_path / "n.ply"
    write_cloud(nolabel, PointCloud(np.random.default_rng(0).normal(size=(100, 3))))
    with pytest.raises(InputValueError, match="ground labels"):  # csf=False: labels or an error
        _run(nolabel, tmp_path / "x", 2, ground={"csf": False}, progress=False)
    assert not (tmp_path / "x").exists()
    assert main(["augment", str(tmp_path / "missing.laz"), "--n", "2", "-o", str(tmp_path / "y")]) == 2
    assert main(["augment", str(laz), "--n", "2", "--format", "doc", "-o", str(tmp_path / "z")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert all(line.startswith("slr-ray: error:") for line in err)
    assert not (tmp_path / "y").exists()


def test_unwritable_output_and_unlabelled_las(laz, tmp_path, capsys):
    from slr_ray.cli import main

    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert main(["augment", str(laz), "--n", "1", "--min-ground-points", "1000", "-o",
                 str(blocker / "out")]) == 2
    nolab = tmp_path / "nolab.las"
    write_cloud(nolab, PointCloud(read_cloud(laz).points[:5000]))
    assert main(["augment", str(nolab), "--n", "1", "--min-ground-points", "50000", "-o", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # no ground class: ground found by CSF, said; 5,000 points are too few for the paper's threshold
    assert len(err) == 3 and [e.split(":")[1] for e in err] == [" error", " note", " error"]
    assert "mark no point as ground: CSF labelled" in err[1] and "--min-ground-points" in err[2]
    assert not (tmp_path / "o2").exists()


def test_sigterm_stops_workers_and_leaves_no_temporaries(laz, tmp_path):
    """SIGTERM during a parallel augment: the command exits 143 promptly, its
    worker processes are gone, no hidden temporary file is left, and a rerun
    completes the set."""
    out = tmp_path / "part"
    n = 40
    cmd = [sys.executable, "-m", "slr_ray.cli", "augment", str(laz), "--n", str(n), "--min-ground-points",
           "1000", "--workers", "2", "--quiet", "-o", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and not [p for p in out.glob("*.laz") if not p.name.startswith(".")]:
        time.sleep(0.01)
    children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
    proc.send_signal(signal.SIGTERM)
    rc = proc.wait(60)
    if rc == 0:
        pytest.skip("the run finished before the signal arrived (a loaded machine)")
    err = proc.stderr.read().decode()
    assert rc == 143 and err.strip().splitlines() == ["slr-ray: terminated"], err  # no worker's traceback

    def running(pid):
        return subprocess.run(["ps", "-p", pid, "-o", "stat="], capture_output=True,
                              text=True).stdout.strip() not in ("", "Z")

    deadline = time.time() + 20
    while time.time() < deadline and any(running(c) for c in children):
        time.sleep(0.1)
    assert not [c for c in children if running(c)], "workers still running"
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    assert len(list(out.glob("*.laz"))) < n
    assert main(cmd[3:]) == 0  # the same command, in this process: a rerun from what is on disk
    assert len(list(out.glob("*.laz"))) == n


def test_a_rerun_with_other_settings_never_mixes_with_the_old_scans(laz, tmp_path):
    out = tmp_path / "aug"
    kw = dict(min_ground_points=1000, workers=1, progress=False)
    first = _run(laz, out, 3, **kw)
    files = sorted(p.name for p in out.iterdir())
    for change, match in (({"seed": 1}, "seed"), ({"resolution": 0.5}, "pattern"),
                          ({"heights": (2.0,)}, "heights"), ({"backend": "embree"}, "backend")):
        with pytest.raises(InputValueError, match=match):
            _run(laz, out, 3, **(kw | change))
        assert sorted(p.name for p in out.iterdir()) == files
    more = _run(laz, out, 5, **kw)  # more positions of the same draw extend the run
    assert more["positions"][:3] == first["positions"] and len(more["scans"]) == 5
    manifest = (out / "manifest.json").read_bytes()
    with pytest.raises(InputValueError, match="holds a run of 5 positions and this run asks 3"):
        _run(laz, out, 3, **kw)  # fewer: its manifest would list scans it has no positions for
    assert (out / "manifest.json").read_bytes() == manifest and len(_files(out)) == 5
    assert len(_run(laz, out, 5, **kw)["scans"]) == 5  # the same run again: nothing to do
    with pytest.raises(InputValueError, match="repeat"):
        _run(laz, tmp_path / "h", 2, heights=(1.65, 1.65), **kw)
    assert not (tmp_path / "h").exists()


def test_relative_output_paths_are_made_absolute_before_work_is_sent(laz, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = _run(laz, "rel", 2, min_ground_points=1000, workers=1, progress=False)
    assert (tmp_path / "rel" / res["scans"][0]["file"]).exists()


def test_scans_in_the_journal_are_not_redone(laz, tmp_path):
    """An interrupted run may have scans only in manifest.scans.jsonl (the manifest is
    rewritten every few seconds, not after each scan): a rerun keeps them."""
    import json

    from slr_ray.augment import JOURNAL

    out = tmp_path / "aug"
    kw = dict(min_ground_points=1000, workers=1, progress=False)
    first = _run(laz, out, 3, **kw)
    assert not (out / JOURNAL).exists()  # a completed run leaves only the manifest
    manifest = json.loads((out / "manifest.json").read_text())
    last = manifest["scans"].pop()
    (out / "manifest.json").write_text(json.dumps(manifest))
    (out / JOURNAL).write_text(json.dumps(last) + "\n" + '{"file": "cut sho')  # a torn last line
    again = _run(laz, out, 3, **kw)
    assert again["new_scans"] == 0 and len(again["scans"]) == len(first["scans"])
    assert not (out / JOURNAL).exists()


def test_streamed_augment_writes_the_same_files_as_a_whole_read(laz, tmp_path, las_reads):
    # chunks of 7,001 points, 2 positions per pass: same positions, byte-identical LAZ files
    whole = _run(laz, tmp_path / "whole", 3, heights=(1.0, 2.0), min_ground_points=1000, workers=1,
                    progress=False)
    las_reads.clear()
    streamed = _run(laz, tmp_path / "streamed", 3, heights=(1.0, 2.0), min_ground_points=1000,
                       progress=False, chunk_size=7001, per_pass=2)
    assert whole["positions"] == streamed["positions"] and len(streamed["scans"]) == 6
    # two passes for the positions, then one per batch of 2 scans (6 scans: 3 batches)
    assert las_reads == [180_000] * (2 + 3)
    for entry in whole["scans"]:
        a = (tmp_path / "whole" / entry["file"]).read_bytes()
        assert a == (tmp_path / "streamed" / entry["file"]).read_bytes()
    # the settings are the same, so a streamed rerun resumes a whole-read run
    again = _run(laz, tmp_path / "whole", 4, heights=(1.0, 2.0), min_ground_points=1000,
                    progress=False, chunk_size=50_000)
    assert again["new_scans"] == 2 and len(again["scans"]) == 8


def test_streamed_augment_refuses_what_it_cannot_stream(laz, tmp_path):
    with pytest.raises(InputValueError, match="binning"):
        _run(laz, tmp_path / "a", 2, backend="embree", chunk_size=1000, min_ground_points=1000, progress=False)
    with pytest.raises(InputValueError, match="binning"):
        _run(laz, tmp_path / "b", 2, sensor="velodyne_vlp16", chunk_size=1000, min_ground_points=1000,
                progress=False)
    npy = tmp_path / "c.npy"
    np.save(npy, np.zeros((10, 3)))
    with pytest.raises(InputValueError, match="streams"):
        _run(npy, tmp_path / "c", 2, chunk_size=1000, progress=False, ground=np.ones(10, bool))
    with pytest.raises(InputValueError, match="per_pass"):
        _run(laz, tmp_path / "d", 2, chunk_size=1000, per_pass=0, min_ground_points=1000, progress=False)


def test_streamed_positions_thin_a_large_ground_with_a_warning(laz):
    from slr_ray.streaming import las_positions

    with pytest.warns(UserWarning, match="every 8th"):
        a, cells, n = las_positions(laz, 4, seed=1, min_ground_points=1000, max_ground_points=20_000, chunk=9999)
    with pytest.warns(UserWarning):
        b, _, _ = las_positions(laz, 4, seed=1, min_ground_points=1000, max_ground_points=20_000, chunk=50_000)
    np.testing.assert_array_equal(a, b)  # chunking does not change the thinning
    assert n == 180_000 and len(a) == 4 and cells.params["min_ground_points"] == 125
    np.testing.assert_allclose(a[:, 2], 100 + 1.65, atol=0.05)  # on the ground (z = 100), 1.65 m above


# --- issue 26: what augment reads and writes ---------------------------------------------------------------------

def test_an_input_inside_the_output_directory_is_never_a_scan_name(laz, tmp_path):
    out = tmp_path / "aug"
    out.mkdir()
    victim = out / "scan_0000_h1.65.laz"
    victim.write_bytes(laz.read_bytes())
    before = victim.read_bytes()
    with pytest.raises(SlrError, match="input"):
        _run(victim, out, 2, min_ground_points=1000, workers=1)
    assert victim.read_bytes() == before and sorted(p.name for p in out.iterdir()) == [victim.name]


def test_a_second_run_into_a_locked_directory_is_refused(laz, tmp_path):
    from slr_ray.errors import OutputError
    from slr_ray.outputs import OutputPlan

    plan = OutputPlan()
    plan.directory(tmp_path / "aug")
    with plan:  # another run holds it (a flock per open file: as another process would)
        with pytest.raises(OutputError, match="in use"):
            _run(laz, tmp_path / "aug", 2, min_ground_points=1000, workers=1)


def test_an_input_edited_in_place_is_not_resumed(laz, tmp_path):
    import os
    import shutil

    src = tmp_path / "in.laz"
    shutil.copy(laz, src)
    out = tmp_path / "aug"
    _run(src, out, 2, min_ground_points=1000, workers=1)
    c = read_cloud(src)
    c.attributes["intensity"] = c.attributes["intensity"][::-1].copy()  # same size, other content
    st = src.stat()
    write_cloud(src, c)
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns))
    with pytest.raises(InputValueError, match="input_digest"):
        _run(src, out, 2, min_ground_points=1000, workers=1)


def test_a_run_that_fails_before_its_first_scan_leaves_nothing(laz, tmp_path, monkeypatch):
    import slr_ray.augment as A

    def boom(*a, **k):
        raise InputValueError("no scan for you")

    monkeypatch.setattr(A, "_scan_job", boom)
    with pytest.raises(InputValueError, match="no scan"):
        _run(laz, tmp_path / "new" / "aug", 2, min_ground_points=1000, workers=1)
    assert not (tmp_path / "new").exists()


def test_scanner_height_is_honoured(laz, tmp_path):
    a = _run(laz, tmp_path / "a", 2, min_ground_points=1000, workers=1)
    b = _run(laz, tmp_path / "b", 2, min_ground_points=1000, workers=1, scanner_height=3.0)
    pa, pb = np.array([s["origin"] for s in a["scans"]]), np.array([s["origin"] for s in b["scans"]])
    assert b["heights"] == [3.0] and a["heights"] == [1.65]
    np.testing.assert_allclose(pb[:, 2] - pa[:, 2], 3.0 - 1.65, atol=1e-9)
    assert main(["augment", str(laz), "--n", "1", "--min-ground-points", "1000", "--scanner-height", "2.5",
                 "--workers", "1", "--quiet", "-o", str(tmp_path / "c")]) == 0
    assert json.loads((tmp_path / "c" / "manifest.json").read_text())["heights"] == [2.5]


@pytest.mark.parametrize("chunk_size", [None, 50_000])
def test_no_position_found_is_an_error_that_leaves_nothing(laz, tmp_path, chunk_size):
    out = tmp_path / "o"
    with pytest.raises(InputValueError, match="no scanner position found"),  \
            pytest.warns(SlrWarning, match="0 positions of the 2 asked"):  # was: exit 0, an empty manifest
        _run(laz, out, 2, min_ground_points=10**9, chunk_size=chunk_size, allow_fewer=True)
    assert not out.exists()


def test_a_number_of_scans_whose_plan_would_exhaust_memory_is_refused_first(laz, tmp_path):
    with pytest.raises(InputValueError, match="would need about .* GiB"):  # was: a list of 10**12 names
        _run(laz, tmp_path / "o", 10**12)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("content", ["[]", '{"settings": 5}', "null"])
def test_a_manifest_of_another_shape_is_a_one_line_error(laz, tmp_path, content):
    out = tmp_path / "o"
    out.mkdir()
    (out / "manifest.json").write_text(content)  # valid JSON, not ours: was an AttributeError traceback
    with pytest.raises(InputValueError, match="not a manifest slr_ray can read"):
        _run(laz, out, 1, min_ground_points=1000)
    assert (out / "manifest.json").read_text() == content


def test_a_fresh_run_never_removes_a_label_file_it_did_not_write(tmp_path):
    # a directory with another program's scan_0000_h1.65.label and no manifest: a fresh --format bin
    # run removed it as a stale sidecar of its scan (and would have written over it with labels)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-20, 20, (4000, 2)), rng.normal(0, 0.01, 4000)])
    src = tmp_path / "g.npz"
    np.savez(src, points=pts, is_ground=np.ones(4000, bool))
    out = tmp_path / "out"
    out.mkdir()
    (out / "scan_0000_h1.65.label").write_bytes(b"mine")
    with pytest.raises(SlrError, match="scan_0000_h1.65.label"):
        _run(src, out, 1, resolution=2.0, min_ground_points=10, workers=1, fmt=".bin")
    assert (out / "scan_0000_h1.65.label").read_bytes() == b"mine"
    assert sorted(p.name for p in out.iterdir()) == ["scan_0000_h1.65.label"]


# --- issue 40: augment writes only its own files, and stops quietly --------------------------------------------

def _ground(tmp_path, n=4000):
    rng = np.random.default_rng(0)
    src = tmp_path / "g.npz"
    np.savez(src, points=np.column_stack([rng.uniform(-20, 20, (n, 2)), rng.normal(0, 0.01, n)]),
             is_ground=np.ones(n, bool))
    return src


_SMALL = ["--resolution", "2", "--min-ground-points", "10", "--workers", "1", "--quiet"]


@pytest.mark.parametrize("how", ["extend", "resume"])
@pytest.mark.parametrize("fmt, planted", [(".npz", "scan_0002_h1.65.npz"), (".bin", "scan_0002_h1.65.label")])
def test_an_extension_or_a_resume_never_writes_over_a_file_it_did_not_write(tmp_path, capsys, how, fmt, planted):
    # a finished run of 2 extended to 3, or a run of 3 interrupted before scan_0002: another program's file
    # under that name was replaced (or, a .label, removed as stale) without --force
    out = tmp_path / "out"
    cmd = ["augment", str(_ground(tmp_path)), *_SMALL, "--format", fmt, "-o", str(out), "--n"]
    assert main(cmd + ["2" if how == "extend" else "3"]) == 0
    if how == "resume":
        m = json.loads((out / "manifest.json").read_text())
        m["scans"] = [s for s in m["scans"] if not s["file"].startswith("scan_0002")]
        (out / "manifest.json").write_text(json.dumps(m))
        for p in out.glob("scan_0002_*"):
            p.unlink()
    (out / planted).write_bytes(b"mine")
    before = sorted(p.name for p in out.iterdir())
    capsys.readouterr()
    assert main(cmd + ["3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("slr-ray: error:") and planted in err[0], err
    assert (out / planted).read_bytes() == b"mine" and sorted(p.name for p in out.iterdir()) == before
    (out / planted).unlink()  # moved away: the run goes on
    assert main(cmd + ["3"]) == 0 and (out / f"scan_0002_h1.65{fmt}").exists()


def test_a_file_written_into_the_directory_during_the_run_is_never_replaced(tmp_path, monkeypatch):
    # `scan -o r2/scan_0001_h1.65.npz` while augment ran: augment replaced it silently
    import slr_ray.augment as A
    from pathlib import Path

    from slr_ray.errors import OutputError

    staged = A._write_job

    def theirs_first(job, *rest):
        entry = staged(job, *rest)
        if entry["file"] == "scan_0001_h1.65.npz":
            Path(job["path"]).write_bytes(b"theirs")  # between the scan and its rename
        return entry

    monkeypatch.setattr(A, "_write_job", theirs_first)
    src, out = _ground(tmp_path), tmp_path / "out"
    kw = dict(resolution=2.0, min_ground_points=10, workers=1)
    with pytest.raises(OutputError, match="scan_0001_h1.65.npz appeared .* did not write it"):
        _run(src, out, 3, **kw)
    assert (out / "scan_0001_h1.65.npz").read_bytes() == b"theirs"
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]
    monkeypatch.undo()
    (out / "scan_0001_h1.65.npz").unlink()
    assert len(_run(src, out, 3, **kw)["scans"]) == 3  # resumed: its withdrawn entry is made again


def test_a_scan_into_a_directory_another_run_holds_is_refused(tmp_path, capsys):
    from slr_ray.outputs import OutputPlan

    src, held = _ground(tmp_path), tmp_path / "r2"
    cmd = ["scan", str(src), "--origin", "0", "0", "1.65", "--resolution", "2", "--quiet", "-o",
           str(held / "scan_0000_h1.65.npz")]
    plan = OutputPlan()
    plan.directory(held)
    with plan:  # an augment into r2 (a flock per open file: as another process would)
        assert main(cmd) == 2
        assert "in use by another slr-ray run" in capsys.readouterr().err
        assert not (held / "scan_0000_h1.65.npz").exists()
    assert main(cmd) == 0  # released: single-file commands share a directory, locked or not


def test_ctrl_c_while_workers_start_prints_one_line_and_no_worker_traceback(laz, tmp_path):
    # Ctrl-C reaches the whole process group: workers still starting printed KeyboardInterrupt and
    # SemLock/pickle tracebacks after "slr-ray: interrupted"
    import os

    cmd = [sys.executable, "-m", "slr_ray.cli", "augment", str(laz), "--n", "40", "--min-ground-points",
           "1000", "--workers", "2", "--quiet", "-o", str(tmp_path / "o")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.time() + 120
    while time.time() < deadline and len(subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True,
                                                        text=True).stdout.split()) < 2:
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal does
    rc = proc.wait(60)
    err = proc.stderr.read().decode()
    if rc == 0:
        pytest.skip("the run finished before the signal arrived (a loaded machine)")
    assert rc == 130 and err.strip().splitlines() == ["slr-ray: interrupted"], err


def test_a_scan_that_cannot_be_written_is_named_by_its_own_name_not_its_hidden_one(tmp_path, monkeypatch, capsys):
    import errno

    from slr_ray.io import REGISTRY

    def full(path, *a):
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setitem(REGISTRY, ".npz", dataclasses.replace(REGISTRY[".npz"], write=full))
    out = tmp_path / "out"
    assert main(["augment", str(_ground(tmp_path)), *_SMALL, "--n", "2", "-o", str(out)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(f"cannot write {out / 'scan_0000_h1.65.npz'}: File too large"), line
    assert not out.exists()


def test_a_warning_every_scan_gives_is_said_once_with_its_count(tmp_path):
    # was: one line a scan (2,000 scans, 2,000 lines), each naming its own file
    rng = np.random.default_rng(0)
    g = np.column_stack([rng.uniform(-4, 4, (8000, 2)), rng.normal(0, 0.005, 8000)])
    src = tmp_path / "c.ply"
    write_cloud(src, PointCloud(g, {"classification": np.full(len(g), 2, np.uint8)}))
    with pytest.warns(UserWarning) as said:
        _run(src, tmp_path / "aug", 3, min_ground_points=500, resolution=8, fmt="xyz", workers=1)
    columns = [str(w.message) for w in said if "stores columns" in str(w.message)]
    assert columns == [f"{tmp_path / 'aug' / 'scan_*.xyz'}: .xyz stores columns, not names: ['classification'] "
                       "will read back as ['intensity'] (in 3 scans)"]
