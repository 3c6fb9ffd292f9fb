"""``evaluate``'s refusals (issue #40): poses that are not rigid, beam sources that are not a
scan's, registrations from too few points, duplicate methods and a non-empty output
directory; each one line naming the flag, nothing written, no numpy warning."""

import json
import math
import warnings

import numpy as np
import pytest

from slr_ray.arrays import as_rigid_pose
from slr_ray.cli import main
from slr_ray.errors import InputValueError
from slr_ray.evaluate import MIN_REGISTRATION_POINTS, evaluate_pair
from slr_ray.io import PointCloud, write_cloud
from slr_ray.sensors import sensor

VLP16 = sensor("velodyne_vlp16", columns=360)


def ring_frame(seed=0, pattern=VLP16):
    """A frame stored ring after ring (highest beam first, one turn each from azimuth 0), a wall-like
    range per azimuth: a KITTI-ordered frame of a 16-beam unit, 5,000 points."""
    rng = np.random.default_rng(seed)
    pts, beams = [], []
    for beam in pattern.beam_of_row:
        el = math.radians(pattern.elevation_deg[beam])
        az = (np.arange(pattern.columns) + 0.5) * 2 * math.pi / pattern.columns
        az = az[rng.random(len(az)) > 0.1]
        r = 10 + 3 * np.sin(3 * az)
        pts.append(np.column_stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)]))
        beams.append(np.full(len(az), beam))
    return np.vstack(pts), np.concatenate(beams)


def run(argv, capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy warning is a failure, not a second message
        rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    pts, beams = ring_frame()
    rng = np.random.default_rng(1)
    files = {}
    for name, cloud in (("ordered", PointCloud(pts)), ("shuffled", PointCloud(pts[rng.permutation(len(pts))])),
                        ("float_ring", PointCloud(pts, {"ring": rng.random(len(pts))})),
                        ("random_ring", PointCloud(pts, {"ring": rng.integers(0, 16, len(pts)).astype(np.int32)}))):
        files[name] = d / f"{name}.npz"
        write_cloud(files[name], cloud)
    return files


BAD_POSES = {"scale 2": np.diag([2.0, 2, 2, 1]), "zero": np.zeros((4, 4)), "last row 0 0 0 5": np.diag([1.0, 1, 1, 5]),
             "reflection": np.diag([1.0, 1, -1, 1]), "shear": np.eye(4) + np.eye(4, k=1) * 0.1,
             "1e300 translation": np.r_[np.c_[np.eye(3), [1e300, 0, 0]], [[0, 0, 0, 1]]],
             "1e300 rotation": np.diag([1e300, 1, 1, 1]), "NaN": np.full((4, 4), np.nan), "3 x 3": np.eye(3)}


def test_as_rigid_pose_refuses_every_matrix_that_is_not_a_rigid_pose():
    for what, T in BAD_POSES.items():
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(InputValueError, match="pose"):
                as_rigid_pose(T)
    ang = 0.3
    R = np.array([[math.cos(ang), -math.sin(ang), 0], [math.sin(ang), math.cos(ang), 0], [0, 0, 1]])
    good = np.r_[np.c_[R, [4.5e5, 5.4e6, 120]], [[0, 0, 0, 1]]]
    np.testing.assert_array_equal(as_rigid_pose(np.round(good, 7)), np.round(good, 7))  # text with 7 digits
    np.testing.assert_array_equal(as_rigid_pose(good[:3]), good)  # a KITTI poses row: 3 x 4


def test_cli_evaluate_refuses_a_transform_that_is_not_a_rigid_pose(frames, tmp_path, capsys):
    out = tmp_path / "out"
    texts = {k: "\n".join(" ".join(repr(float(v)) for v in row) for row in T) for k, T in BAD_POSES.items()}
    texts |= {"empty": "", "comments only": "# nothing\n", "ragged": "1 0 0\n0 1 0 0\n", "words": "one two\n",
              "far (1e6 m)": "1 0 0 1e6\n0 1 0 0\n0 0 1 0\n0 0 0 1\n"}
    for what, text in texts.items():
        path = tmp_path / "T.txt"
        path.write_text(text)
        rc, stdout, err = run(["evaluate", str(frames["ordered"]), str(frames["ordered"]), "-o", str(out), "--quiet",
                               "--source-sensor", "velodyne_vlp16", "--methods", "zbuffer", "--transform", str(path)], capsys)
        assert rc == 2 and stdout == "" and not out.exists(), what
        assert err.count("\n") == 1 and "--transform" in err and "Traceback" not in err, (what, err)


def test_cli_evaluate_beams_scan_order_refuses_a_frame_not_in_scan_order_and_auto_says_so(frames, tmp_path, capsys):
    eye = tmp_path / "eye.txt"
    eye.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")  # a line of a KITTI poses file: 3 x 4, row by row
    base = ["--source-sensor", "velodyne_vlp16", "--methods", "zbuffer", "--transform", str(eye), "--quiet"]
    shuffled, ordered = str(frames["shuffled"]), str(frames["ordered"])
    rc, _, err = run(["evaluate", ordered, shuffled, "-o", str(tmp_path / "s"), "--beams", "scan-order", *base],
                     capsys)
    assert rc == 2 and err.startswith("slr-ray: error: --beams scan-order: frame B") and err.count("\n") == 1
    assert not (tmp_path / "s").exists()
    rc, out, err = run(["evaluate", ordered, shuffled, "-o", str(tmp_path / "a"), *base], capsys)
    assert rc == 0 and "--beams auto: frame B" in err and "not in scan order" in err
    res = json.loads(out)
    doc = json.loads((tmp_path / "a" / "evaluation.json").read_text())
    assert doc["patterns"]["a"]["beams"] == "scan order" and doc["patterns"]["b"]["beams"].startswith("none")
    assert res["other_files_in_directory"] == []
    # a ring attribute that is not beam ids: random floats (once truncated to beam 0, a 46-column
    # table fitted from them), random integers (each 'beam' spread over the whole field of view)
    for name, says in (("float_ring", "non-integers"), ("random_ring", "not a scan's beams")):
        rc, _, err = run(["evaluate", str(frames[name]), ordered, "-o", str(tmp_path / name), *base], capsys)
        assert rc == 2 and says in err and "frame A" in err and err.count("\n") == 1, err
        assert not (tmp_path / name).exists()


def test_cli_evaluate_refuses_duplicate_methods_and_a_non_empty_directory(frames, tmp_path, capsys):
    eye = tmp_path / "eye.txt"
    eye.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    f = str(frames["ordered"])
    base = ["evaluate", f, f, "--source-sensor", "velodyne_vlp16", "--transform", str(eye), "--quiet"]
    rc, _, err = run([*base, "-o", str(tmp_path / "d"), "--methods", "binning", "binning"], capsys)
    assert rc == 2 and "--methods: binning given twice" in err and not (tmp_path / "d").exists()
    rc, _, err = run([*base, "-o", str(tmp_path / "d"), "--min-fitness", "nan"], capsys)
    assert rc == 2 and "--min-fitness nan" in err and not (tmp_path / "d").exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    rc, out, err = run([*base, "-o", str(mine), "--methods", "zbuffer"], capsys)
    assert rc == 2 and "not empty" in err and "--force" in err and sorted(p.name for p in mine.iterdir()) == [
        "notes.txt"]
    rc, out, err = run([*base, "-o", str(mine), "--methods", "zbuffer", "--force"], capsys)
    assert rc == 0 and "notes.txt" in err and json.loads(out)["other_files_in_directory"] == ["notes.txt"]
    assert (mine / "notes.txt").read_text() == "keep"


def test_a_registration_needs_enough_points_and_a_bounded_rmse():
    """A 40-point B once passed the fitness gate (0.35) at a 76 m pose where the truth was 0.68 m."""
    pts, _ = ring_frame()
    rng = np.random.default_rng(2)
    b = pts[rng.choice(len(pts), 40, replace=False)]
    with pytest.raises(InputValueError, match="frame B has 40 points, too few to register"):
        evaluate_pair(pts, b, a_beams=None, b_beams=None, sensor=VLP16, methods=("zbuffer",), min_fitness=0.0)
    assert len(pts) >= MIN_REGISTRATION_POINTS
    with pytest.raises(InputValueError, match="methods: none given"):
        evaluate_pair(pts, pts, a_beams=None, b_beams=None, sensor=VLP16, methods=(), transform=np.eye(4))
    with pytest.raises(InputValueError, match="inlier RMSE"):
        evaluate_pair(pts, pts + rng.normal(0, 0.01, pts.shape), a_beams=None, b_beams=None, sensor=VLP16,
                      methods=("zbuffer",), max_rmse=1e-3)


def test_an_empty_transform_file_is_one_line_in_a_real_process(frames, tmp_path):
    """numpy's loadtxt printed its warning and source line on an empty file before the error."""
    import subprocess
    import sys

    empty = tmp_path / "T.txt"
    empty.write_text("")
    f = str(frames["ordered"])
    proc = subprocess.run([sys.executable, "-m", "slr_ray.cli", "evaluate", f, f, "-o", str(tmp_path / "o"),
                           "--transform", str(empty), "--source-sensor", "velodyne_vlp16", "--quiet"],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stdout == "" and not (tmp_path / "o").exists()
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("slr-ray: error: --transform"), proc.stderr
