"""A first use on a real scan works, or says why (issues #40, #41): each case as a user types it.

One command per case runs as a subprocess (the console script's own process: its
warnings, its stderr, its exit status); its variants run through ``main`` in-process.
Inputs are tiny: a flat 8 x 8 m ground with a few boxes.
"""

import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

from slr_ray.cli import main
from slr_ray.io import PointCloud, read_cloud, write_cloud

UTM = np.array([500_000.0, 5_000_000.0, 100.0])


def _cloud(n_ground=8000, n_boxes=800, half=4.0, seed=0):
    rng = np.random.default_rng(seed)
    g = np.column_stack([rng.uniform(-half, half, (n_ground, 2)), rng.normal(0, 0.005, n_ground)])
    o = np.column_stack([rng.uniform(-half, half, (n_boxes, 2)), rng.uniform(0.5, 2.5, n_boxes)])
    cls = np.r_[np.full(n_ground, 2, np.uint8), np.ones(n_boxes, np.uint8)]
    return np.vstack([g, o]), cls


def _slr_ray(*args, cwd):
    """``slr-ray ARGS`` in its own process, as typed in a shell (this checkout's slr_ray)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [os.path.dirname(os.path.dirname(
        os.path.abspath(__file__))), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "slr_ray.cli", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


# --- 1. a georeferenced cloud and a local origin ------------------------------------------------------------

@pytest.fixture
def utm_laz(tmp_path):
    pts, _ = _cloud(n_ground=10_000)
    path = tmp_path / "utm.laz"
    write_cloud(path, PointCloud(pts + UTM))  # a LAS in UTM coordinates, no labels
    return path


def test_a_local_origin_for_a_georeferenced_cloud_is_refused_naming_its_extent(utm_laz, tmp_path):
    # the README's example origin on a UTM cloud: was one point, exit 0, no word
    run = _slr_ray("scan", utm_laz, "--origin", 12, -3.5, 0.2, "--resolution", 0.144, "--max-range", 120,
                   "-o", "slr.laz", cwd=tmp_path)
    assert run.returncode == 2 and run.stdout == ""
    err = run.stderr.strip()
    assert err.count("\n") == 0 and err.startswith("slr-ray: error: the origin (12.00, -3.50, 0.20) lies ")
    assert "x 499,996.0 to 500,004.0, y 4,999,996.0 to 5,000,004.0" in err and "--origin-relative centre" in err
    assert not (tmp_path / "slr.laz").exists()


def test_a_far_origin_without_a_range_limit_is_warned_and_one_relative_to_the_centre_works(utm_laz, tmp_path,
                                                                                         capsys):
    args = ["scan", str(utm_laz), "--resolution", "2", "--quiet"]
    assert main(args + ["--origin", "12", "-3.5", "0.2", "-o", str(tmp_path / "a.laz")]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["points_out"] <= 1
    assert out.err.startswith("slr-ray: warning: the origin (12.00, -3.50, 0.20) lies ")
    assert "over ten times farther than the cloud is wide" in out.err and "y 4,999,996.0 to 5,000,004.0" in out.err
    assert main(args + ["--origin-relative", "centre", "--origin", "0", "0", "1", "--max-range", "120",
                        "-o", str(tmp_path / "b.laz")]) == 0
    out = capsys.readouterr()
    res = json.loads(out.out)
    assert out.err == "" and res["points_out"] > 1000
    lo, hi = read_cloud(utm_laz).points.min(0), read_cloud(utm_laz).points.max(0)
    np.testing.assert_allclose(res["origin"], (lo + hi) / 2 + [0, 0, 1])
    # a scan that returns almost nothing of a large cloud is said to, with the cloud's extent
    assert main(args + ["--origin-relative", "centre", "--origin", "0", "0", "5", "--zenith-range", "0", "10",
                        "-o", str(tmp_path / "up.laz")]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["points_out"] == 0
    assert out.err.startswith("slr-ray: warning: the scan returned 0 of the cloud's 10,800 points")
    assert "x 499,996.0 to 500,004.0" in out.err
    # compare's origins are checked alike
    assert main(["compare", str(utm_laz), "--origin", "12", "-3.5", "0.2", "--resolution", "2",
                 "--max-range", "50"]) == 2
    assert "beyond the pattern's max range (50 m)" in capsys.readouterr().err
    # relative to a recorded scanner origin: a LAS records none, which is said
    assert main(args + ["--origin-relative", "scanner", "-o", str(tmp_path / "c.laz")]) == 2
    assert "records no scanner origin" in capsys.readouterr().err


# --- 2. ground labels: found when absent, the tool's own recognised ----------------------------------------

def test_a_cloud_without_ground_labels_gets_them_by_csf_said_on_stderr(tmp_path):
    pts, cls = _cloud()
    write_cloud(tmp_path / "nolabels.ply", PointCloud(pts))
    run = _slr_ray("positions", "nolabels.ply", "--n", 3, "--min-ground-points", 500, "-o", "p.json", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    note = [line for line in run.stderr.splitlines() if line.startswith("slr-ray: note:")]
    assert len(note) == 1 and "the input has no ground labels" in note[0], run.stderr
    n = int(note[0].split("CSF labelled ")[1].split(" of ")[0].replace(",", ""))
    assert abs(n - np.count_nonzero(cls == 2)) < 0.02 * len(pts)  # the flat ground, not the boxes
    res = json.loads(run.stdout)
    assert res["ground_points"] == n and res["n_positions"] == 3


def test_the_labels_of_the_tools_own_scene_scan_are_ground_labels(tmp_path, capsys):
    out = tmp_path / "scene.ply"
    assert main(["scene", "scan", "rect-1000", "--origin", "0", "0", "1.65", "--resolution", "1",
                 "--max-range", "20", "--quiet", "-o", str(out)]) == 0  # its 'label': 0 ground, k rectangle k
    label = read_cloud(out).attributes["label"]
    capsys.readouterr()
    assert main(["positions", str(out), "--n", "1", "--min-ground-points", "50", "-o",
                 str(tmp_path / "p.json")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("slr-ray: note: ground labels from 'label' == 0") and "CSF" not in err
    assert json.loads((tmp_path / "p.json").read_text())["ground_points"] == np.count_nonzero(label == 0)


def test_a_streamed_augment_of_an_unlabelled_las_says_why_it_cannot_find_ground(utm_laz, tmp_path, capsys):
    # was: 'only 0 candidate cells' (its classification 0 read as labels marking no ground)
    assert main(["augment", str(utm_laz), "--n", "2", "--chunk-size", "5000", "--quiet", "-o",
                 str(tmp_path / "aug")]) == 2
    err = capsys.readouterr().err
    assert "mark no point as ground, and a streamed read cannot find them (CSF needs the whole cloud)" in err
    assert "drop --chunk-size, or name them with --ground-attribute" in err and not (tmp_path / "aug").exists()


# --- 4. fewer positions than --n: one rule for augment and positions ---------------------------------------

@pytest.fixture
def labelled_ply(tmp_path):
    pts, cls = _cloud()  # 16 cells of 2 m
    path = tmp_path / "c.ply"
    write_cloud(path, PointCloud(pts, {"classification": cls}))
    return path


def test_augment_asked_more_positions_than_cells_refuses_naming_both_counts_and_the_flags(labelled_ply,
                                                                                         tmp_path):
    # was: exit 0 with 16 scans for --n 20, the JSON's n_requested the only trace
    run = _slr_ray("augment", labelled_ply, "--n", 20, "--min-ground-points", 500, "--resolution", 2,
                   "--workers", 1, "--quiet", "-o", "aug", cwd=tmp_path)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.startswith("slr-ray: error: only 16 candidate cells for n=20: ")
    assert "--min-ground-points" in run.stderr and "--allow-fewer" in run.stderr
    assert "allow_fewer" not in run.stderr and "min_ground_points" not in run.stderr  # flags, not arguments
    assert not (tmp_path / "aug").exists()


def test_allow_fewer_accepts_fewer_with_a_warning_in_both_commands(labelled_ply, tmp_path, capsys):
    common = ["--n", "20", "--min-ground-points", "500"]
    assert main(["positions", str(labelled_ply), *common, "-o", str(tmp_path / "p.json")]) == 2
    assert "only 16 candidate cells for n=20" in capsys.readouterr().err  # the same refusal as augment's
    assert main(["augment", str(labelled_ply), *common, "--resolution", "4", "--workers", "1", "--quiet",
                 "--allow-fewer", "-o", str(tmp_path / "aug")]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["scans"] == 16
    assert out.err.startswith("slr-ray: warning: 16 positions of the 20 asked: 16 candidate cells")


def test_no_position_at_all_is_an_error_in_both_commands_even_with_allow_fewer(labelled_ply, tmp_path, capsys):
    # was: positions exited 0 writing an empty list while augment refused
    common = ["--n", "2", "--min-ground-points", "100000", "--allow-fewer"]
    assert main(["positions", str(labelled_ply), *common, "-o", str(tmp_path / "p.json")]) == 2
    assert "no scanner position found" in capsys.readouterr().err and not (tmp_path / "p.json").exists()
    assert main(["augment", str(labelled_ply), *common, "--quiet", "-o", str(tmp_path / "aug")]) == 2
    assert "no scanner position found" in capsys.readouterr().err


def test_augments_effects_error_names_the_flags_typed(labelled_ply, tmp_path, capsys):
    assert main(["augment", str(labelled_ply), "--n", "2", "--min-ground-points", "500", "--intensity", "correct",
                 "--quiet", "-o", str(tmp_path / "aug")]) == 2
    err = capsys.readouterr().err
    assert "--intensity correct needs where" in err and "(use --intensity carry)" in err and "intensity='" not in err


# --- 5. a hostile user's typing --------------------------------------------------------------------------

@pytest.mark.parametrize("argv, command", [
    (["positions", "x.ply", "--n", "1", "-o", "p.json", "--quite"], "positions"),
    (["scene", "info", "ground-only", "--bogus"], "scene info"),
    (["effects", "fit-drop", "f.bin", "-o", "m.json", "--bogus"], "effects fit-drop"),
])
def test_an_unknown_flag_is_named_with_the_command_that_refused_it(argv, command, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"slr-ray: error: {command}: unrecognized arguments: "), err
    assert f"slr-ray {command} --help" in err[0]


def test_every_warning_reaches_the_terminal_as_one_line(tmp_path, capsys):
    # was: the library's UserWarnings (a format that loses names) in Python's form, file:line and source
    src = tmp_path / "c.npz"
    np.savez(src, points=_cloud(400, 40)[0], label=np.arange(440))
    with warnings.catch_warnings():  # as at a terminal: pytest records warnings, a terminal prints them
        warnings.simplefilter("always")
        warnings.showwarning = (lambda m, c, f, n, file=None, line=None:
                                sys.stderr.write(warnings.formatwarning(m, c, f, n, line)))
        assert main(["scan", str(src), "--origin", "0", "0", "1", "--resolution", "2", "--quiet",
                     "-o", str(tmp_path / "s.xyz")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err and all(line.startswith("slr-ray: warning: ") for line in err), err
    assert ".xyz stores columns, not names: ['label']" in err[0]


def test_csf_is_a_named_phase_and_positions_is_quiet_with_quiet(tmp_path, capsys, monkeypatch):
    # CSF with its 0.5 m cloth took 73 s on the 110,000-point airborne tile without a word on stderr
    monkeypatch.setattr("slr_ray.progress.PHASE_AFTER", 0.0)
    pts, _ = _cloud(2000, 200)
    write_cloud(tmp_path / "nolabels.ply", PointCloud(pts))
    argv = ["positions", str(tmp_path / "nolabels.ply"), "--n", "1", "--min-ground-points", "50", "--force",
            "-o", str(tmp_path / "p.json")]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "CSF: labelling the ground of 2,200 points (cloth 0.5 m over 8 x 8 m) ..." in err
    assert main(argv + ["--quiet"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("slr-ray: note: the input has no ground labels"), err


def test_a_rerun_asking_fewer_positions_names_the_flag_to_type(labelled_ply, tmp_path, capsys):
    argv = ["augment", str(labelled_ply), "--min-ground-points", "500", "--resolution", "4", "--workers", "1",
            "--quiet", "-o", str(tmp_path / "aug")]
    assert main(argv + ["--n", "2"]) == 0
    capsys.readouterr()
    assert main(argv + ["--n", "1"]) == 2
    err = capsys.readouterr().err
    assert "ask --n 2 (or more)" in err and "n=2" not in err, err


@pytest.mark.parametrize("flags, said", [
    (["--resolution", "400"], "--resolution must be in (0, 180] degrees"),
    (["--resolution", "1", "--zenith-range", "100", "50"], "--zenith-range must satisfy 0 <= min < max <= 180"),
    (["--resolution", "1", "--min-range", "50", "--max-range", "10"], "--min-range (50.0) must not exceed --max-range"),
    (["--sensor", "velodyne_vlp16", "--max-range", "-1"], "--max-range must be a finite number >= 0"),
])
def test_a_bad_pattern_flag_is_named_as_typed(flags, said, labelled_ply, tmp_path, capsys):
    # was: the library's argument names (zenith_range, min_range, azimuth_resolution)
    assert main(["scan", str(labelled_ply), "--origin", "0", "0", "1", *flags, "-o", str(tmp_path / "s.ply")]) == 2
    err = capsys.readouterr().err
    assert said in err and "_range" not in err and "_resolution" not in err, err


def test_a_missing_profile_is_refused_before_csf_runs(tmp_path, capsys, monkeypatch):
    def no_csf(*a, **k):
        raise AssertionError("CSF ran")

    monkeypatch.setattr("slr_ray.positions.label_ground", no_csf)
    write_cloud(tmp_path / "nolabels.ply", PointCloud(_cloud(200, 20)[0]))
    assert main(["positions", str(tmp_path / "nolabels.ply"), "--n", "1", "--profile", str(tmp_path / "no.json"),
                 "-o", str(tmp_path / "p.json")]) == 2
    assert "cannot read azimuth profile" in capsys.readouterr().err


def test_keep_range_and_ring_go_with_a_range_image(labelled_ply, tmp_path, capsys):
    # was: "attribute name 'range' is taken by the range image", for the image's own layers
    image = tmp_path / "ri.npz"
    assert main(["scan", str(labelled_ply), "--origin", "0", "0", "1", "--resolution", "4", "--keep-range",
                 "--keep-ring", "--range-image", str(image), "--quiet", "-o", str(tmp_path / "s.ply")]) == 0
    with np.load(image) as z:
        assert {"range", "ring", "classification"} <= set(z.files) and z["ring"].ndim == 1  # columns: its own


def test_an_input_attribute_the_range_image_keeps_is_refused_naming_the_flag(tmp_path, capsys):
    # was: "attribute name 'ring' is taken by the range image", naming no flag
    pts, cls = _cloud(200, 20)
    write_cloud(tmp_path / "r.ply", PointCloud(pts, {"ring": np.zeros(len(pts), np.uint16)}))
    assert main(["scan", str(tmp_path / "r.ply"), "--origin", "0", "0", "1", "--resolution", "8", "--range-image",
                 str(tmp_path / "ri.npz"), "--quiet", "-o", str(tmp_path / "s.ply")]) == 2
    err = capsys.readouterr().err
    assert "'ring'" in err and "drop --range-image" in err and not (tmp_path / "s.ply").exists()
    assert "attribute(s) 'ring': names the range image of --range-image keeps" in err  # one sentence that parses


def test_repeated_heights_name_the_flag(labelled_ply, tmp_path, capsys):
    assert main(["augment", str(labelled_ply), "--n", "1", "--heights", "2", "2", "--quiet",
                 "-o", str(tmp_path / "aug")]) == 2
    assert "--heights repeats [2.0]" in capsys.readouterr().err


# --- 6. augment's output directory ------------------------------------------------------------------------

_AUG = ["--n", "1", "--min-ground-points", "500", "--resolution", "8", "--workers", "1", "--quiet"]


def test_augment_into_a_directory_of_other_files_is_refused_naming_them_unless_force(labelled_ply, tmp_path,
                                                                                      capsys):
    # was: a fresh run scattered its scans and manifest among a user's unrelated files
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep")
    assert main(["augment", str(labelled_ply), *_AUG, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "notes.txt" in err and "--force" in err and sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert main(["augment", str(labelled_ply), *_AUG, "--force", "-o", str(out)]) == 0
    assert (out / "notes.txt").read_text() == "keep" and (out / "manifest.json").exists()
    assert main(["augment", str(labelled_ply), *_AUG, "-o", str(out)]) == 0  # a resume needs no --force
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["new_scans"] == 0


def test_an_augment_rerun_with_other_settings_is_refused_before_csf(labelled_ply, tmp_path, capsys, monkeypatch):
    # was: refused only after CSF had labelled the ground (minutes on an airborne tile)
    assert main(["augment", str(labelled_ply), *_AUG, "-o", str(tmp_path / "aug")]) == 0

    def no_csf(*a, **k):
        raise AssertionError("CSF ran")

    monkeypatch.setattr("slr_ray.positions.label_ground", no_csf)
    assert main(["augment", str(labelled_ply), *_AUG, "--csf", "--seed", "1", "-o", str(tmp_path / "aug")]) == 2
    assert "holds a run with other settings" in capsys.readouterr().err
