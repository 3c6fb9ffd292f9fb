import json

import numpy as np
import pytest

from slr_ray import ScanPattern, simulate_scan
from slr_ray.cli import main
from slr_ray.io import PointCloud, read_cloud, write_cloud

from conftest import scene_cloud


@pytest.fixture
def cloud_ply(tmp_path):
    pts = scene_cloud(5000, 0)
    label = np.arange(len(pts), dtype=np.int32) % 7
    path = tmp_path / "in.ply"
    write_cloud(path, PointCloud(pts, {"label": label, "intensity": np.arange(len(pts), dtype=np.float32)}))
    return path, pts


def _subcommands():
    import argparse

    from slr_ray.cli import build_parser

    def walk(parser, prefix):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, p in action.choices.items():
                    yield prefix + [name]
                    yield from walk(p, prefix + [name])

    return list(walk(build_parser(), []))


@pytest.mark.parametrize("cmd", _subcommands(), ids=" ".join)
def test_every_command_prints_its_help(cmd, capsys):
    # the backend options' help comes from docstrings: a "%" in one once broke `scan --help`
    assert main(cmd + ["--help"]) == 0
    assert "usage:" in capsys.readouterr().out


def _parser_of(cmd):
    import argparse

    from slr_ray.cli import build_parser

    parser = build_parser()
    for name in cmd:
        parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[name]
    return parser


@pytest.mark.parametrize("cmd", _subcommands(), ids=" ".join)
def test_every_option_has_help(cmd):
    import argparse

    bare = [a.option_strings[0] if a.option_strings else a.dest for a in _parser_of(cmd)._actions
            if not isinstance(a, argparse._SubParsersAction) and not a.help]
    assert not bare, f"slr-ray {' '.join(cmd)}: options without help: {bare}"


def test_scan_help_is_short(capsys, monkeypatch):
    # a newcomer reads `scan --help` whole: one line an option where possible, details by link
    # (it was 202 lines of usage, choices and benchmark figures at 80 columns)
    monkeypatch.setenv("COLUMNS", "80")
    assert main(["scan", "--help"]) == 0
    out = capsys.readouterr().out
    assert len(out.splitlines()) <= 120
    assert out.startswith("usage: slr-ray scan input -o OUTPUT [options]")
    assert "README" not in out and "docs/backends.md" in out


def test_long_steps_show_progress_on_stderr_unless_quiet(tmp_path, cloud_ply, capsys, monkeypatch):
    import slr_ray.progress

    monkeypatch.setattr(slr_ray.progress, "PHASE_AFTER", 0.0)  # every step counts as long
    path, _ = cloud_ply
    argv = ["scan", str(path), "--origin", "1", "0", "0", "--resolution", "2", "--backend", "embree"]
    assert main(argv + ["-o", str(tmp_path / "a.ply")]) == 0
    out, err = capsys.readouterr()
    assert len(out.splitlines()) == 1 and "embree: preparing 5,000 points" in err and "embree: scanning" in err
    assert main(argv + ["-o", str(tmp_path / "b.ply"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    assert main(["compare", str(path), "--origin", "1", "0", "0", "--resolution", "2", "--quiet"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("out_ext", [".ply", ".npz", ".npy"])
def test_scan_command(tmp_path, cloud_ply, capsys, out_ext):
    path, pts = cloud_ply
    out = tmp_path / f"out{out_ext}"
    rc = main(["scan", str(path), "--origin", "1", "0", "0", "--resolution", "1",
               "--max-range", "20", "-o", str(out)])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out.strip())
    ref = simulate_scan(pts, [1, 0, 0], ScanPattern(1, max_range=20))
    assert summary["points_in"] == len(pts) and summary["points_out"] == len(ref)
    assert summary["pulses"] == 180 * 360 and summary["seconds"] >= 0
    back = read_cloud(out)
    np.testing.assert_array_equal(back.points, pts[ref.indices])
    if out_ext == ".ply":  # every per-point property follows
        np.testing.assert_array_equal(back.attributes["label"], ref.indices % 7)
        np.testing.assert_array_equal(back.attributes["intensity"], ref.indices.astype(np.float32))


def test_print_config(tmp_path, cloud_ply, capsys):
    path, _ = cloud_ply
    assert main(["scan", str(path), "--origin", "0", "0", "0", "--preset", "syns",
                 "-o", str(tmp_path / "o.ply"), "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert cfg["pattern"]["max_range"] == 120 and not (tmp_path / "o.ply").exists()


@pytest.mark.parametrize("make_input, args", [
    (lambda p: None, []),                                              # missing file
    (lambda p: p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\n"), []),
    (lambda p: p.write_bytes(b"not a ply at all"), []),
    (lambda p: None, ["--resolution", "-1"]),
])
def test_bad_input_exits_nonzero_with_one_line_and_no_output(tmp_path, capsys, make_input, args):
    src = tmp_path / "in.ply"
    make_input(src)
    out = tmp_path / "out.ply"
    argv = ["scan", str(src), "--origin", "0", "0", "0", "--resolution", "1", "-o", str(out)] + args
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("slr-ray: error:")
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] in ([], ["in.ply"])


def test_scene_info_and_scan(tmp_path, capsys):
    assert main(["scene", "info", "rect-0500"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_rectangles"] == 500 and 330 < info["n_present"] < 420
    out = tmp_path / "truth.ply"
    assert main(["scene", "scan", "ground-only", "--origin", "0", "0", "0", "--resolution", "2",
                 "--quiet", "-o", str(out)]) == 0
    back = read_cloud(out)
    assert len(back) > 0 and np.all(back.attributes["label"] == 0)
    np.testing.assert_allclose(back.points[:, 2], -1.65, atol=1e-9)


def test_demo_quick(tmp_path, capsys):
    assert main(["demo", "--quick", "--positions", "2", "--rectangles", "50", "-o", str(tmp_path / "d")]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["positions"] == 2 and 0.3 < rep["mean_similarity"] <= 1
    for b in ("binning", "embree"):  # both backends, coverage and precision
        assert 0.3 < rep["backends"][b]["mean_similarity"] <= 1
        assert 0.5 < rep["backends"][b]["mean_precision"] <= 1
    files = {p.name for p in (tmp_path / "d").iterdir()}
    # numbered from 1 as in the table and the figure: position_01 is the table's row 1
    assert {"report.json", "demo.png", "position_01_slr_binning.ply",
            "position_01_slr_embree.ply", "position_02_true.ply"} <= files
    assert not any(name.startswith("position_00") for name in files)
    pairs = json.loads((tmp_path / "d" / "report.json").read_text())["pairs"]
    assert sorted({r["number"] for r in pairs}) == [1, 2]


def test_positions_command(tmp_path, capsys):
    rng = np.random.default_rng(0)
    g = np.column_stack([rng.uniform(-10, 10, (60_000, 2)), np.zeros(60_000)])
    o = np.column_stack([rng.uniform(-10, 10, (5000, 2)), rng.uniform(1, 3, 5000)])
    pts = np.vstack([g, o])
    cls = np.r_[np.full(60_000, 2, np.uint8), np.full(5000, 1, np.uint8)]
    write_cloud(tmp_path / "c.ply", PointCloud(pts, {"classification": cls}))
    out = tmp_path / "pos.json"
    assert main(["positions", str(tmp_path / "c.ply"), "--n", "4", "--seed", "1", "--min-ground-points",
                 "2000", "-o", str(out), "--png", str(tmp_path / "cells.png")]) == 0
    summary = json.loads(capsys.readouterr().out)
    res = json.loads(out.read_text())
    assert len(res["positions"]) == 4 and summary["n_positions"] == 4
    assert [s["stage"] for s in res["stages"]] == ["non_empty", "ground_support", "azimuth_profile"]
    assert (tmp_path / "cells.png").stat().st_size > 1000
    # no labels: ground found by CSF (said); too little of it for the paper's threshold: one error, no output
    # (the default, 'auto', follows the cloud's density: tests/test_first_use.py)
    write_cloud(tmp_path / "nolab.ply", PointCloud(pts))
    out2 = tmp_path / "pos2.json"
    assert main(["positions", str(tmp_path / "nolab.ply"), "--n", "2", "-o", str(out2),
                 "--min-ground-points", "50000"]) == 2
    err = capsys.readouterr().err
    assert "no ground labels" in err and "CSF labelled" in err and "--min-ground-points" in err
    assert not out2.exists()


def test_labels_that_mark_no_ground_are_replaced_by_csf(tmp_path, capsys):
    pts = np.random.default_rng(0).normal(size=(1000, 3))
    write_cloud(tmp_path / "c.ply", PointCloud(pts, {"classification": np.zeros(1000, np.uint8)}))
    assert main(["positions", str(tmp_path / "c.ply"), "--n", "1", "--min-ground-points", "50000",
                 "-o", str(tmp_path / "p.json")]) == 2
    assert "(classification 2) mark no point as ground: CSF labelled" in capsys.readouterr().err


def test_backend_options_on_the_command_line(tmp_path, capsys):
    """Embree options come from EmbreeOptions' fields; they are refused with another backend."""
    src = tmp_path / "in.npy"
    np.save(src, np.random.default_rng(0).normal(size=(500, 3)))
    base = ["scan", str(src), "--origin", "0", "0", "0", "--resolution", "2", "-o", str(tmp_path / "o.npy")]
    assert main(base + ["--backend", "embree", "--orientation", "billboard", "--radius", "0.05",
                        "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert cfg["options"]["orientation"] == "billboard" and cfg["options"]["radius"] == 0.05
    assert main(base + ["--orientation", "billboard"]) == 2  # binning has no orientation
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--orientation" in err[0]
    assert main(base + ["--backend", "embree", "--orientation", "sideways"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("slr-ray: error:") and "sideways" in err[0]
    assert main(base + ["--backend", "embree", "--radius", "0.05", "--orientation", "billboard"]) == 0
    assert json.loads(capsys.readouterr().out)["points_out"] > 0


def test_compare_has_no_backend_flag_it_would_ignore():
    """compare runs both backends: a --backend there was accepted and ignored; its embree options stay."""
    from slr_ray.cli import build_parser

    parser = build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["compare", "c.ply", "--origin", "0", "0", "0", "--backend", "binning"])
    args = parser.parse_args(["compare", "c.ply", "--origin", "0", "0", "0", "--radius", "0.05"])
    assert args.opt_radius == 0.05


def test_usage_errors_are_one_line_with_status_2(capsys):
    for argv in (["scan"], ["nonsense"], ["positions", "x.ply", "--n", "0", "-o", "p.json"],
                 ["compare", "x.ply", "--origin", "0", "0", "nan"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("slr-ray: error:"), argv
    assert main(["--version"]) == 0


def test_no_command_writes_over_an_input_or_an_existing_file(tmp_path, capsys):
    from slr_ray.io import PointCloud, write_cloud

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-20, 20, (4000, 2)), rng.normal(0, 0.01, 4000)])
    src = tmp_path / "v.ply"
    write_cloud(src, PointCloud(pts, {"classification": np.full(4000, 2, np.uint8)}))
    before = src.read_bytes()
    pos = ["positions", str(src), "--n", "1", "--min-ground-points", "10"]
    for argv in (pos + ["-o", str(src)], pos + ["-o", str(src), "--force"],
                 ["scan", str(src), "--origin", "0", "0", "1", "--resolution", "1", "-o", str(src), "--force"],
                 pos + ["-o", str(tmp_path / "p.json"), "--png", str(src), "--force"]):
        assert main(argv) == 2, argv
        assert "input" in capsys.readouterr().err
    assert src.read_bytes() == before
    (tmp_path / "taken.png").write_bytes(b"mine")
    (tmp_path / "taken.ply").write_bytes(b"mine")
    for argv in (pos + ["-o", str(tmp_path / "p2.json"), "--png", str(tmp_path / "taken.png")],
                 ["scene", "build", "ground-only", "-o", str(tmp_path / "taken.ply")],
                 ["profile", "-o", str(tmp_path / "taken.png")]):
        assert main(argv) == 2, argv
        assert "exists" in capsys.readouterr().err
    assert (tmp_path / "taken.png").read_bytes() == b"mine" and (tmp_path / "taken.ply").read_bytes() == b"mine"
    assert not (tmp_path / "p2.json").exists()
    assert main(["scene", "build", "ground-only", "-o", str(tmp_path / "taken.ply"), "--force"]) == 0


def test_hostile_inputs_get_one_line_errors(tmp_path, capsys):
    rng = np.random.default_rng(0)
    np.save(tmp_path / "complex.npy", rng.normal(size=(10, 3)) + 1j)
    np.save(tmp_path / "bool.npy", rng.normal(size=(10, 3)) > 0)
    (tmp_path / "adir.ply").mkdir()
    for src, word in (("complex.npy", "real"), ("bool.npy", "real"), ("adir.ply", "directory")):
        argv = ["scan", str(tmp_path / src), "--origin", "0", "0", "0", "--resolution", "1",
                "-o", str(tmp_path / "o.npy")]
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and word in err[0], err
    assert not (tmp_path / "o.npy").exists()
    for bad in ("0", "-1", "nan", "inf"):
        assert main(["positions", "x.ply", "--n", "1", "-o", "p.json", "--cloth-resolution", bad]) == 2
        assert main(["positions", "x.ply", "--n", "1", "-o", "p.json", "--scanner-height", bad]) == 2
        capsys.readouterr()


def test_a_tiny_cell_size_does_not_ask_for_terabytes():
    from slr_ray.positions import candidate_cells

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0, 700, (20_000, 2)), rng.normal(0, 0.01, 20_000)])
    cells = candidate_cells(pts, np.ones(20_000, bool), cell_size=0.001, min_ground_points=1)
    assert len(cells.ij) == 20_000  # one occupied cell per point; 4.9e11 cells never allocated


def test_results_are_strict_json():
    from slr_ray.arrays import json_safe

    out = json.dumps(json_safe({"a": float("nan"), "b": [1.0, float("inf")], "c": {"d": -float("inf")}}),
                     allow_nan=False)
    assert json.loads(out) == {"a": None, "b": [1.0, None], "c": {"d": None}}
    # numpy scalars and keys as every JSON the package writes takes them (one helper)
    assert json_safe({1: (np.float32("nan"), np.int64(3))}) == {"1": [None, 3]}


# --- issue 26/27: one line for deliberate errors, a traceback for bugs ---------------------------------------------

def _small(tmp_path, **attrs):
    src = tmp_path / "c.npz"
    rng = np.random.default_rng(0)
    np.savez(src, points=rng.uniform(-5, 5, (300, 3)), origin=np.zeros(3), **attrs)
    return src


@pytest.mark.parametrize("content, ext", [("{not json", ".json"), ('{"beam_altitude_angles": 3}', ".json"),
                                          ("[1, 2]", ".json"), ("lasers: [{}]", ".yaml"), ("a: [", ".yaml"),
                                          ("- 1\n- 2", ".yaml")])
def test_malformed_sensor_files_are_one_line_naming_the_file(tmp_path, capsys, content, ext):
    sensor = tmp_path / f"s{ext}"
    sensor.write_text(content)
    rc = main(["scan", str(_small(tmp_path)), "--sensor-file", str(sensor), "-o", str(tmp_path / "o.npz")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and str(sensor) in err, err
    assert not (tmp_path / "o.npz").exists()


def test_a_bug_shows_its_traceback_and_asks_for_a_report(tmp_path, capsys, monkeypatch):
    import slr_ray.cli.commands as C

    def broken(args):
        raise ValueError("an internal inconsistency")  # a library bug, not a deliberate error

    monkeypatch.setitem(C.COMMANDS, "scan", broken)
    rc = main(_scan_args(tmp_path))
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" in err and "report" in err


def _scan_args(tmp_path, *extra):
    return ["scan", str(_small(tmp_path)), "--resolution", "5", "-o", str(tmp_path / "o.npz"), *extra]


def test_ground_value_without_ground_attribute_is_an_error(tmp_path, capsys):
    src = _small(tmp_path, is_ground=np.ones(300, bool))
    assert main(["positions", str(src), "--n", "1", "--ground-value", "7", "-o", str(tmp_path / "p.json")]) == 2
    assert "--ground-attribute" in capsys.readouterr().err
    assert not (tmp_path / "p.json").exists()


@pytest.mark.parametrize("flag, name", [("--keep-range", "range"), ("--keep-ring", "ring"), ("--keep-ring", "column")])
def test_keep_flags_never_replace_the_inputs_own_attributes(tmp_path, capsys, flag, name):
    src = _small(tmp_path, **{name: np.arange(300.0)})
    assert main(["scan", str(src), "--resolution", "5", "-o", str(tmp_path / "o.npz"), flag]) == 2
    assert repr(name) in capsys.readouterr().err and not (tmp_path / "o.npz").exists()


def test_a_results_csv_of_another_program_is_a_clear_error(tmp_path, capsys):
    out = tmp_path / "v"
    out.mkdir()
    (out / "results.csv").write_text("a,b,c\n1,2,3\n")
    cfg = tmp_path / "c.toml"
    cfg.write_text('[validate]\nname = "t"\nscenes = ["rect-100"]\npositions = 1\n')
    assert main(["validate", str(cfg), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "not a results.csv of slr_ray" in err and len(err.strip().splitlines()) == 1
    assert (out / "results.csv").read_text() == "a,b,c\n1,2,3\n"


@pytest.mark.parametrize("line", ["n_rectangles = 3000000000", "xy_range = [nan, 10.0]", "z_range = [0.0, inf]"])
def test_scene_specs_that_would_exhaust_memory_or_hold_nan_are_refused_first(tmp_path, capsys, line):
    spec = tmp_path / "s.toml"
    spec.write_text(f"[scene]\n{line}\n")
    assert main(["scene", "info", str(spec)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and ("GiB" in err or "finite" in err)


def test_embree_settings_that_would_exhaust_memory_are_refused_with_the_figure(tmp_path, capsys):
    src = tmp_path / "big.npz"
    np.savez(src, points=np.random.default_rng(0).uniform(-5, 5, (100_000, 3)))  # no origin: no fit, no warning
    # a row of 3.6e9 rays (a 1e-7 deg band of 50 rows: 1.8e11 rays, a cast short enough to be tried);
    # a whole 2e-7 deg pattern is refused sooner, for the hours its cast would take
    for settings, says in ((["--resolution", "5", "--engine", "fan", "--segments", "1000000"], "GiB"),
                           (["--resolution", "1e-7", "--zenith-range", "90", "90.000005"], "GiB"),
                           (["--resolution", "2e-7"], "hours")):
        rc = main(["scan", str(src), "--origin", "0", "0", "0", "--backend", "embree", "--radius", "0.1", *settings,
                   "--quiet", "-o", str(tmp_path / "o.npz")])  # --quiet: a slow prepare is named on stderr otherwise
        err = capsys.readouterr().err
        assert rc == 2 and says in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "o.npz").exists()


@pytest.mark.parametrize("content", [b"a b c d\n", b"\xd7\x00\xff\xfe" * 20, b"1 0 0 0\n0 1 0 0\n0 0 1 nan\n0 0 0 1\n"])
def test_a_transform_that_is_not_a_finite_matrix_is_a_one_line_error(tmp_path, capsys, content):
    frame = tmp_path / "f.bin"
    np.random.default_rng(0).normal(size=(100, 4)).astype(np.float32).tofile(frame)
    (tmp_path / "t.txt").write_bytes(content)
    assert main(["evaluate", str(frame), str(frame), "--transform", str(tmp_path / "t.txt"), "--quiet",
                 "-o", str(tmp_path / "ev")]) == 2  # text and bytes were a ValueError traceback
    err = capsys.readouterr().err
    assert "Traceback" not in err and "t.txt" in err and not (tmp_path / "ev").exists()


def test_a_range_image_too_large_is_refused_before_the_scan(tmp_path, capsys, monkeypatch):
    import slr_ray.cli.commands as commands

    src = tmp_path / "c.npz"
    np.savez(src, points=np.random.default_rng(0).normal(size=(50, 3)), origin=np.zeros(3))
    scanned = []
    monkeypatch.setattr(commands, "prepare", lambda *a, **k: scanned.append(1))  # the scan must not start
    assert main(["scan", str(src), "--resolution", "0.001", "-o", str(tmp_path / "o.npz"),
                 "--range-image", str(tmp_path / "r.npz")]) == 2
    assert "larger than max_pixels" in capsys.readouterr().err and not scanned
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.npz"]


def _empty_inputs(tmp_path):
    """A file of no points in each format that can hold none."""
    import laspy

    np.savez(tmp_path / "e.npz", points=np.empty((0, 3)))
    np.save(tmp_path / "e.npy", np.empty((0, 3)))
    (tmp_path / "e.bin").write_bytes(b"")
    (tmp_path / "e.xyz").write_text("")
    laspy.LasData(laspy.LasHeader(point_format=3, version="1.4")).write(tmp_path / "e.las")
    write_cloud(tmp_path / "e.pcd", PointCloud(np.empty((0, 3))))
    return sorted(p for p in tmp_path.iterdir() if p.stem == "e")


@pytest.mark.parametrize("cmd", [
    ["scan", "--origin", "1", "1", "1", "--resolution", "1", "-o", "{out}.npz"],
    ["scan", "--origin", "1", "1", "1", "--resolution", "1", "--backend", "embree", "-o", "{out}.npz"],
    ["augment", "--n", "2", "--resolution", "1", "-o", "{out}"],
    ["compare", "--origin", "1", "1", "1", "--resolution", "1"],
    ["positions", "--n", "2", "-o", "{out}.json"],
    ["distances", "--origin", "1", "1", "1", "-o", "{out}.csv"],
], ids=lambda c: " ".join(c[:3]))
def test_an_empty_input_is_refused_in_every_format(tmp_path, capsys, cmd):
    # a zero-point .npz/.ply/.xyz or 0-byte .bin used to give an empty scan with exit 0,
    # while an empty LAS was an error: every format and command now says "no points"
    for path in _empty_inputs(tmp_path):
        out = tmp_path / f"out_{path.suffix[1:]}"
        argv = [cmd[0], str(path)] + [a.format(out=out) for a in cmd[1:]]
        assert main(argv) == 2, path
        err = capsys.readouterr().err
        assert "no points" in err and path.name in err, (path, err)
        assert err.count("\n") == 1 and "\r" not in err, (path, err)  # one line: no progress bar of 0 points
        assert not [p for p in tmp_path.iterdir() if p.name.startswith("out_")], path


def test_read_cloud_allow_empty(tmp_path):
    from slr_ray.errors import FormatError

    for path in _empty_inputs(tmp_path):
        assert len(read_cloud(path)) == 0  # the library reads an empty file as an empty cloud
        with pytest.raises(FormatError, match="no points"):
            read_cloud(path, allow_empty=False)


@pytest.mark.parametrize("name", ["image.txt", "image.png", "image"])
def test_range_image_other_than_npz_is_refused_before_the_scan(tmp_path, cloud_ply, capsys, name):
    # it was written as npz bytes under any name
    path, _ = cloud_ply
    out = tmp_path / "out.npz"
    rc = main(["scan", str(path), "--origin", "1", "0", "0", "--resolution", "1", "-o", str(out),
               "--range-image", str(tmp_path / name)])
    assert rc == 2 and "--range-image" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / name).exists()


@pytest.mark.parametrize("ext", [".npz", ".ply", ".las", ".laz", ".pcd", ".bin", ".xyz"])
def test_a_scan_of_no_point_in_the_pattern_is_an_empty_output(tmp_path, cloud_ply, ext):
    # every point beyond --max-range: a legitimate empty scan (exit 0, a file read_cloud reads back);
    # its range image raised IndexError (an internal error) indexing the scan's empty indices
    path, _ = cloud_ply
    out, image = tmp_path / f"out{ext}", tmp_path / "image.npz"
    assert main(["scan", str(path), "--origin", "1", "0", "0", "--resolution", "1", "--max-range", "0.001",
                 "-o", str(out), "--range-image", str(image), "--png", str(tmp_path / "image.png")]) == 0
    assert len(read_cloud(out)) == 0
    with np.load(image) as got:
        assert (got["index"] == -1).all() and got["index"].shape == (180, 360)


def test_a_sensor_scan_that_carries_the_inputs_ring_field_says_so(tmp_path, capsys):
    # (hostile2 pass) scan --sensor velodyne_vlp16 of a Pandar64 frame wrote the Pandar64's ring (0-63) as the
    # output's 'ring' without a word; slr-ray sensor fit of that output then fitted a 46-beam card for a
    # VLP-16 scan (it reads 'ring' as each point's beam)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(4000, 3))
    d[:, 2] *= 0.2
    pts = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(3, 20, (4000, 1))
    src = tmp_path / "frame.pcd"
    write_cloud(src, PointCloud(pts, {"ring": rng.integers(0, 64, 4000).astype(np.uint16),
                                      "intensity": np.ones(4000, np.float32)}, origin=np.zeros(3)))
    for i, flags in enumerate((["--sensor", "velodyne_vlp16"], ["--resolution", "1"])):
        out = tmp_path / f"out{i}.pcd"
        assert main(["scan", str(src), "-o", str(out), "--quiet", *flags]) == 0
        err = capsys.readouterr().err
        assert ("'ring'" in err and "velodyne_vlp16" in err) == (i == 0), err  # a uniform grid has no beams to mistake
        assert "ring" in read_cloud(out).attributes  # carried, as every attribute is: said, not dropped
