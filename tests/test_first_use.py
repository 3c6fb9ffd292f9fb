"""A first use as a new user makes it (issue #48, items 11-16): the README's set-up, defaults that
follow the cloud, augment's primary as scan's, what the help and the progress lines say."""

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from slr_ray import paper
from slr_ray.cli import main
from slr_ray.errors import SlrNote
from slr_ray.positions import candidate_cells

ROOT = Path(__file__).resolve().parents[1]


# --- 11. the README's two commands set up a virtual environment; CI runs the second --------------------------

def _quick_start() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"^## Quick start\n.*?```bash\n(.*?)```", text, flags=re.S | re.M).group(1)
    return [line for line in block.splitlines() if line.strip() and not line.startswith("#")]


def test_the_quick_start_is_two_commands_that_install_into_a_virtual_environment():
    commands = _quick_start()
    assert len(commands) == 2 and commands[0].endswith("slr-ray demo") and "pytest" in commands[1]
    for c in commands:  # Debian 12 / Ubuntu 24.04: pip into the system's Python is refused
        parts = [p.strip() for p in c.split("&&")]
        venv = parts.index("python3 -m venv .venv")
        assert parts[venv + 1] == ". .venv/bin/activate"
        assert "python3-venv" in shlex.split(parts[1]) and parts[1].startswith("apt-get install")
        pip = next(i for i, p in enumerate(parts) if p.startswith("pip install"))
        assert pip > venv + 1  # pip only once the environment is active


def test_ci_runs_the_readmes_test_command_after_its_apt_get_part():
    command = _quick_start()[1]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    after_apt = command.split(" && ", 2)[2]
    assert after_apt.startswith("python3 -m venv .venv") and after_apt in ci.splitlines()
    assert "python3 -m pip install" not in ci  # nothing into the system's Python
    assert "libusb-1.0-0 python3-venv" in ci


# --- 12. --min-ground-points follows the cloud's density --------------------------------------------------------

def _ground(density: float, half=12.0, seed=0):
    """A flat square of ground at ``density`` points/m², denser towards its centre as a scan's, and boxes."""
    rng = np.random.default_rng(seed)
    n = int(density * (2 * half) ** 2)
    xy = rng.uniform(-half, half, (3 * n, 2))
    xy = xy[rng.random(len(xy)) < np.exp(-np.hypot(*xy.T) / 6)][:n]
    g = np.column_stack([xy, rng.normal(0, 0.01, len(xy))])
    boxes = np.column_stack([rng.uniform(-half, half, (n // 10, 2)), rng.uniform(0.5, 2.5, n // 10)])
    return np.vstack([g, boxes]), np.r_[np.ones(len(g), bool), np.zeros(len(boxes), bool)]


def test_auto_ground_support_scales_with_the_density_and_keeps_the_same_cells():
    from slr_ray.positions import AUTO_GROUND_FRACTION

    pts, g = _ground(200.0)
    full = candidate_cells(pts, g, min_ground_points="auto")
    thin = candidate_cells(pts[::4], g[::4], min_ground_points="auto")
    assert full.params["min_ground_points_rule"] == "auto"
    for c in (full, thin):  # the threshold is the paper's fraction of the best cell
        assert c.params["min_ground_points"] == max(1, int(np.ceil(AUTO_GROUND_FRACTION * c.ground_counts.max())))
    ratio = full.params["min_ground_points"] / thin.params["min_ground_points"]
    assert 3.0 < ratio < 5.0  # a quarter of the points, about a quarter of the threshold
    a, b = ({tuple(ij) for ij in c.ij[c.final].tolist()} for c in (full, thin))
    assert len(a & b) >= 0.9 * len(a | b) and len(a) > 10
    assert candidate_cells(pts, g, min_ground_points=paper.MIN_GROUND_POINTS).params["min_ground_points"] == 50_000
    with pytest.raises(ValueError, match="'auto'"):
        candidate_cells(pts, g, min_ground_points="many")


def test_positions_of_a_sparse_cloud_by_default_and_the_papers_number_on_demand(tmp_path, capsys):
    from slr_ray.io import PointCloud, write_cloud

    pts, g = _ground(20.0)
    write_cloud(tmp_path / "c.npz", PointCloud(pts, {"is_ground": g}))
    assert main(["positions", str(tmp_path / "c.npz"), "--n", "3", "-o", str(tmp_path / "p.json"), "--quiet"]) == 0
    d = json.loads((tmp_path / "p.json").read_text())
    assert len(d["positions"]) == 3 and d["params"]["min_ground_points_rule"] == "auto"
    # the paper's number, typed, is the paper's: no cell here
    assert main(["positions", str(tmp_path / "c.npz"), "--n", "3", "-o", str(tmp_path / "q.json"), "--quiet",
                 "--min-ground-points", "50000"]) == 2
    assert "ground_support removed 144" in capsys.readouterr().err


def test_the_paper_configs_keep_the_papers_number():
    from slr_ray.validation.config import load_config

    for path in sorted((ROOT / "slr_ray" / "data" / "scenes").glob("validate-*.toml")):
        value = load_config(path).min_ground_points  # never 'auto': the paper's runs stay the same
        assert value == (300 if path.stem == "validate-quick" else paper.MIN_GROUND_POINTS), path


# --- 13. augment --backend embree takes a sensor frame's primary as scan does -----------------------------------

def _ring_frame():
    """A KITTI-like frame: 64 rings of 300 points (the HDL-64E's table), ring by ring, each a turn."""
    from slr_ray.sensors import sensor

    el = np.radians(np.sort(np.asarray(sensor("velodyne_hdl64e_s2").elevation_deg))[::-1])
    az = np.radians(np.arange(300) * 1.2 + 0.6)
    e, a = np.meshgrid(el, az, indexing="ij")
    rng = np.random.default_rng(0)
    e = e + np.radians(rng.normal(scale=0.05, size=e.shape))
    a = a + np.radians(rng.normal(scale=0.3, size=a.shape))
    r = np.where(np.abs(np.sin(3 * a)) > 0.8, 4.0, 12.0) + rng.normal(scale=0.02, size=a.shape)
    pts = np.stack([r * np.cos(e) * np.cos(a), r * np.cos(e) * np.sin(a), r * np.sin(e), np.ones_like(r)], -1)
    return pts.reshape(-1, 4)


def test_augment_with_embree_fits_a_sensor_frames_primary_as_scan_does(tmp_path):
    from slr_ray import prepare
    from slr_ray.augment import AugmentConfig, augment
    from slr_ray.io import read_cloud

    frame = tmp_path / "frame.bin"
    _ring_frame().astype("<f4").tofile(frame)
    cloud = read_cloud(frame)
    ground = cloud.points[:, 2] < -1.0
    config = AugmentConfig(n=2, sensor="velodyne_vlp16", backend="embree", min_ground_points=1, workers=1)
    with pytest.warns(SlrNote, match="pattern fitted to the points"):
        m = augment(frame, tmp_path / "out", config, ground=ground, progress=False)
    fitted = prepare(cloud.points, "embree", primary_origin=[0, 0, 0], primary_pattern="fit")
    for s in m["scans"]:
        assert s["points"] == len(fitted.scan(s["origin"], "velodyne_vlp16"))
    # the manifest says what ran, not only the options given (it recorded no primary: #48 review)
    assert m["backend_options_from_input"] == {"primary_origin": [0.0, 0.0, 0.0], "primary_pattern": "fit"}
    on_disk = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert on_disk["backend_options_from_input"] == m["backend_options_from_input"]


# --- 14. a first run's numba compiling is said once, a cached kernel says nothing -------------------------------

def _python(code: str, cwd):
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), str(cwd)]))}
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=120)


def test_numba_compiling_is_said_once_and_not_when_loaded_from_the_cache(tmp_path):
    from slr_ray.progress import COMPILING

    (tmp_path / "kernels.py").write_text("import numba\n\n\n@numba.njit(cache=True)\ndef twice(x):\n"
                                         "    return 2 * x\n\n\n@numba.njit(cache=True)\ndef thrice(x):\n"
                                         "    return 3 * x + twice(x)\n")
    code = ("import importlib.util as u\n"  # progress.py alone: not the whole package, twice
            f"s = u.spec_from_file_location('progress', {str(ROOT / 'slr_ray' / 'progress.py')!r})\n"
            "progress = u.module_from_spec(s); s.loader.exec_module(progress); phase = progress.phase\n"
            "import kernels\n"
            "with phase('a step', after=0.0):\n    kernels.twice(1); kernels.thrice(2.0); kernels.twice(3.0)\n")
    first, again = _python(code, tmp_path), _python(code, tmp_path)
    assert first.returncode == again.returncode == 0, first.stderr + again.stderr
    assert first.stderr.count(COMPILING) == 1 and "compiling" not in again.stderr
    assert "a step: " in again.stderr


# --- 15. help that is whole, a warning nobody can act on silenced, the shipped tables as --sensor-file ----------

def _actions():
    import argparse

    from slr_ray.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name, parser in sub.choices.items():
        for action in parser._actions:
            yield name, action


def test_every_flags_help_is_whole_and_true_false_flags_show_their_values():
    from slr_ray.cli.arguments import _boolean

    bools = 0
    for command, action in _actions():
        text = action.help or ""
        assert text.count("(") == text.count(")"), (command, action.option_strings, text)
        if action.type is _boolean:
            bools += 1
            assert action.metavar == "{true,false}" and re.search(r"default (true|false)\)$", text), text
    assert bools >= 2  # --primary-image, --silhouettes


def test_numbas_old_tbb_warning_does_not_reach_users(tmp_path):
    code = ("import slr_ray, warnings\nfrom numba.core.errors import NumbaWarning\n"
            "warnings.warn(NumbaWarning('The TBB threading layer requires TBB version 2021 update 6 or later i.e., "
            "TBB_INTERFACE_VERSION >= 12060. Found TBB_INTERFACE_VERSION = 12050. The TBB threading layer is "
            "disabled.'))\nwarnings.warn(NumbaWarning('another numba warning'))\n")
    res = _python(code, tmp_path)
    assert res.returncode == 0 and "TBB" not in res.stderr and "another numba warning" in res.stderr


def test_sensor_file_takes_a_shipped_table(tmp_path, capsys):
    from slr_ray.sensors import SENSORS_DIR, read_sensor_file, sensor

    for name in ("velodyne_vlp16", "ouster_os1_64"):
        p = read_sensor_file(SENSORS_DIR / f"{name}.json", columns=900)
        q = sensor(name, columns=900)
        assert (p.elevation_deg, p.azimuth_offset_deg, p.columns, p.max_range) == \
               (q.elevation_deg, q.azimuth_offset_deg, q.columns, q.max_range)
    rng = np.random.default_rng(0)
    np.save(tmp_path / "c.npy", rng.normal(size=(3000, 3)) * 10)
    args = ["scan", str(tmp_path / "c.npy"), "--origin", "0", "0", "0", "--quiet", "-o"]
    assert main(args + [str(tmp_path / "a.npy"), "--sensor-file", str(SENSORS_DIR / "velodyne_vlp16.json")]) == 0
    assert main(args + [str(tmp_path / "b.npy"), "--sensor", "velodyne_vlp16"]) == 0
    a, b = (json.loads(line) for line in capsys.readouterr().out.splitlines())
    assert a["points_out"] == b["points_out"] > 0
    (tmp_path / "x.json").write_text("{}")
    assert main(args + [str(tmp_path / "d.npy"), "--sensor-file", str(tmp_path / "x.json")]) == 2
    assert "elevation_deg" in capsys.readouterr().err  # what it takes, said


# --- 16. Ctrl-C: a convert worker leaves it to the parent ------------------------------------------------------

def test_a_convert_worker_ignores_sigint_and_lets_the_parent_stop_it(tmp_path):
    code = ("import signal\nimport slr_ray.sequence.convert as c\nc._init = lambda *a: None\n"
            "signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})  # as the pool starts it\n"
            "c._init_worker(None, None, None)\n"
            "assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN\n"
            "assert not signal.pthread_sigmask(signal.SIG_BLOCK, set()) & {signal.SIGINT, signal.SIGTERM}\n"
            "signal.raise_signal(signal.SIGINT)\nprint('still here')\n")
    res = _python(code, tmp_path)
    assert res.returncode == 0 and res.stdout.strip() == "still here" and not res.stderr, res.stderr


# --- 16. an --input-format a command would not use is refused, not ignored -----------------------------------

def test_input_format_for_a_kitti_directory_is_refused_unless_bin(tmp_path, capsys):
    from slr_ray.sequence import read_sequence
    from slr_ray.sequence.synthetic import synthetic_drive

    synthetic_drive(tmp_path / "seq", n_frames=2, sensor="velodyne_vlp16", step=0.8)
    assert len(read_sequence(tmp_path / "seq", input_format="bin")) == 2
    rc = main(["sequence", "convert", str(tmp_path / "seq"), "--input-format", "ply", "--sensor", "velodyne_vlp16",
               "-o", str(tmp_path / "out"), "--quiet"])
    assert rc == 2 and "--input-format 'ply' does not apply" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


# --- 15. a long phase says where it is ---------------------------------------------------------------------------

def test_a_named_phase_says_each_step_once_and_nothing_before_it_is_named(capsys):
    import time

    from slr_ray.progress import phase, step

    step("outside any phase")
    with phase("quick", after=5.0):
        step("neighbours", 0.5)
    with phase("embree: preparing 9 points", after=0.05):
        step("neighbours", 0.0)
        time.sleep(0.2)  # named now, with the step it is in
        step("neighbours", 0.5)
        step("neighbours", 1.0)
        step("BVH")
    err = capsys.readouterr().err
    assert "outside" not in err and "quick" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines[0] == "embree: preparing 9 points ..." and lines[-1].startswith("embree: preparing 9 points: 0.")
    assert lines[1:-1] == ["embree: preparing 9 points: neighbours ...", "embree: preparing 9 points: BVH ..."]
