"""The sequence methods' registry (slr_ray.sequence.methods): a toy method registered by the recipe of
docs/architecture.md reaches `sequence evaluate`, `sequence convert` and the tables; the sequence
command's flags come from the methods' options; its refusals and warnings are one line each."""

import json
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

from slr_ray.errors import InputValueError
from slr_ray.io import read_cloud
from slr_ray.sequence import methods as M
from slr_ray.sequence.estimators import nearest_returns
from slr_ray.sequence.holdout import HoldoutOptions, evaluate_holdout
from slr_ray.sequence import read_sequence
from slr_ray.sequence.synthetic import synthetic_drive
from conftest import CliRun


@dataclass(frozen=True)
class ToyOptions(M.MethodOptions):
    """The toy's settings.

    Attributes
    ----------
    shrink : float
        Each return moved this share of its range towards the sensor.
    """

    PREFIX: ClassVar[str] = "toy"
    shrink: float = 0.0

    def check(self):
        if not 0 <= self.shrink < 1:
            raise InputValueError(f"--toy-shrink must be in [0, 1), got {self.shrink}")


class Toy(M.SequenceMethod):
    """The recipe's method: the nearest rule, each return pulled towards the sensor."""

    name = "toy"
    label = "toy: nearest, pulled in"
    options = ToyOptions

    def returns(self, points, pattern, options):
        ret = nearest_returns(points, pattern)
        ret.points = ret.points * (1 - options.shrink)
        ret.ranges = ret.ranges * (1 - options.shrink)
        return ret


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setitem(M.REGISTRY, "toy", Toy())  # the recipe's one line
    return M.REGISTRY["toy"]


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("drive") / "seq"
    synthetic_drive(root, n_frames=3, sensor="velodyne_vlp16", step=0.8)
    return root


_Run = CliRun


def test_the_registry_holds_every_method_once_with_its_capabilities():
    assert list(M.REGISTRY) == ["zbuffer", "adjacent", "nearest", "fpa", "rays", "embree-knn", "embree-sources",
                                "tsdf", "embree-rays"]
    assert M.methods_with("default") == ["zbuffer", "adjacent", "nearest", "fpa", "rays"]
    assert M.methods_with("convert") == ["nearest", "fpa", "rays", "embree-knn", "embree-sources", "tsdf",
                                         "embree-rays"]
    assert M.methods_with("needs_source_sensor") == ["embree-sources", "embree-rays"]
    assert M.option_keys()["fpa_gap"][2] == ["fpa", "rays"]   # fpa's and rays' gap: one setting, one flag
    assert M.method_options() == {"fpa_gap": 0.1, "rays_neighbours": 64, "rays_max_shift": 0.3, "tsdf_voxel": 0.05,
                                  "tsdf_truncation": 0.25, "tsdf_xy_bound": 50.0, "tsdf_z_bound": 5.0,
                                  "embree_rays_gap": 0.2, "embree_rays_max_ratio": 0.3, "embree_rays_weak_ratio": 0.1,
                                  "embree_rays_fill": 0, "embree_rays_fill_around": 0,
                                  "embree_rays_porous": 0.5, "embree_rays_porous_window": 0,
                                  "embree_rays_porous_beyond": 20.0}
    with pytest.raises(InputValueError, match="known: \\['embree_rays_fill', .*'fpa_gap', "):
        M.method_options({"fpa_gapp": 0.2})
    with pytest.raises(InputValueError, match="fpa given twice"):
        M.check_methods(("fpa", "nearest", "fpa"), "holdout")
    with pytest.raises(InputValueError, match="choose from"):
        M.method("zbuffer", "convert")   # scores only


def test_a_toy_method_reaches_both_commands_and_the_tables(toy, drive, tmp_path, capsys):
    run = _Run(capsys)
    out = tmp_path / "ev"
    r = run("sequence", "evaluate", drive, "--holdout", "1", "--source-sensor", "velodyne_vlp16", "--half", "1",
            "--methods", "nearest", "toy", "--toy-shrink", "0", "-o", out)
    assert r.returncode == 0, r.stderr
    mean = {row["method"]: row for row in json.loads(r.stdout)["mean"]}
    assert mean["toy: nearest, pulled in"] == mean["nearest (binning of the union)"] | {"method": toy.label}
    assert "toy: nearest, pulled in" in (out / "table.md").read_text() and toy.label in r.stderr  # the short table
    assert "--toy-shrink" in run("sequence", "convert", "--help").stdout
    conv = tmp_path / "conv"
    r = run("sequence", "convert", drive, "--target-sensor", "velodyne_vlp16", "--estimator", "toy",
            "--toy-shrink", "0.5", "--half", "1", "-o", conv, "--quiet")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["settings"]["method_options"] == {"toy_shrink": 0.5}
    near = tmp_path / "near"
    assert run("sequence", "convert", drive, "--target-sensor", "velodyne_vlp16", "--half", "1", "-o", near,
               "--quiet").returncode == 0
    a, b = read_cloud(conv / "velodyne" / "000001.bin").points, read_cloud(near / "velodyne" / "000001.bin").points
    assert len(a) == len(b) and np.allclose(a, 0.5 * b, atol=1e-5)   # the toy's own option reached it
    r = run("sequence", "convert", drive, "--target-sensor", "velodyne_vlp16", "--estimator", "toy",
            "--toy-shrink", "2", "-o", tmp_path / "bad", "--quiet")
    assert r.returncode == 2 and "--toy-shrink must be in [0, 1)" in r.stderr and not (tmp_path / "bad").exists()


class Stateful(Toy):
    """The recipe's per-sequence state: built once a run, seen by every held-out frame."""

    name = "stateful"
    label = "stateful: nearest"

    def sequence_state(self, seq, cache, options):
        self.built.append(options)
        return {"targets": []}

    def simulate(self, held, options):
        self.state(held, options)["targets"].append(held.target)
        return super().simulate(held, options)


def test_a_method_builds_its_sequence_state_once_for_every_held_out_frame(drive, monkeypatch):
    # the per-sequence hook (#47): one state a run (the frames cache's), not one a held-out frame;
    # the loose union arguments are one Keep on what a method is given
    from slr_ray.sequence import evaluate_sequence
    from slr_ray.sequence.union import FrameCache, Keep, accumulate

    stateful = Stateful()
    stateful.built = []
    monkeypatch.setitem(M.REGISTRY, "stateful", stateful)
    seq = read_sequence(drive)
    res = evaluate_sequence(seq, [0, 1, 2], "velodyne_vlp16", ("stateful",), half=1)
    assert len(res["frames"]) == 3 and stateful.built == [ToyOptions()]
    assert not hasattr(M.SequenceMethod, "frame_state")
    cache = FrameCache(seq)
    assert stateful.state(M.TargetFrame(seq, [0, 1], seq.poses[0], None, cache), ToyOptions()) == {"targets": []}
    assert len(stateful.built) == 2   # another run (another cache): built again
    a, b = accumulate(seq, [0, 2], Keep(False), cache=cache), accumulate(seq, [0, 2], drop_moving=False)
    assert np.array_equal(a.points, b.points) and a.removed == b.removed
    # held-out targets share a frame's selection where nothing sees through (the excluded frame does
    # not vote there): one mask for frame 0 whichever target is held out; with see-through, one each
    masks = [cache.selection(0, Keep(True, None, (target,)))[0] for target in (1, 2)]
    assert masks[0] is masks[1]  # one mask made, not one a target
    assert Keep(True, None, (1,)).key(0) == Keep(True, None, (2,)).key(0) == Keep(True).key(0)


def test_the_library_takes_method_options_and_refuses_a_method_twice(drive):
    seq = read_sequence(drive)
    a = evaluate_holdout(seq, 1, sensor="velodyne_vlp16", half=1, methods=("fpa",), fpa_gap=0.3)
    b = evaluate_holdout(seq, 1, HoldoutOptions(sensor="velodyne_vlp16", half=1, methods=("fpa",),
                                                method_options={"fpa_gap": 0.3}))
    assert a["fpa_gap_m"] == b["fpa_gap_m"] == 0.3 and a["table"] == b["table"]
    with pytest.raises(InputValueError, match="given twice"):
        evaluate_holdout(seq, 1, sensor="velodyne_vlp16", half=1, methods=("fpa", "fpa"))


@pytest.mark.parametrize("flags, message", [
    (["evaluate", "--holdout", "1", "--methods", "fpa", "nearest", "fpa"], "--methods: fpa given twice"),
    (["evaluate", "--protocol", "lidar4d", "--half", "1"], "--half / --radius with --protocol lidar4d"),
    (["evaluate", "--holdout", "1", "--visibility-margin", "0.5"], "--visibility-margin without visibility removal"),
    (["evaluate", "--holdout", "1", "--remove-moving", "visibility", "--visibility-votes", "5"],
     "--visibility-votes 5: at most 4 frames vote"),
    (["convert", "--target-sensor", "velodyne_vlp16", "--visibility-votes", "2"],
     "--visibility-votes without visibility removal"),
    (["convert"], "name the target sensor (--target-sensor NAME)"),
    (["evaluate", "--holdout", "1", "--methods", "nearest", "--fpa-gap", "0"], "the fpa gap must be > 0 m"),
    (["convert", "--target-sensor", "velodyne_vlp16", "--rays-neighbours", "2"], "--rays-neighbours: a plane takes 3"),
    (["evaluate", "--holdout", "1", "--methods", "tsdf", "--tsdf-truncation", "0.01"],
     "--tsdf-truncation (0.01 m) must be at least one voxel"),
    (["convert", "--sensor", "velodyne_vlp16", "--target-sensor", "velodyne_vlp16"], "--sensor and --target-sensor"),
    (["convert", "--target-sensor", "velodyne_vlp16", "--estimator", "embree-sources"],
     "--estimator embree-sources needs the frames' sensor (--source-sensor)"),
    (["convert", "--target-sensor", "velodyne_vlp16", "--estimator", "embree-rays"],
     "--estimator embree-rays needs the frames' sensor (--source-sensor)"),
    (["evaluate", "--holdout", "1", "--methods", "embree-rays", "--embree-rays-gap", "0"],
     "--embree-rays-gap must be > 0"),
    (["evaluate", "--holdout", "1", "--methods", "embree-rays", "--embree-rays-weak-ratio", "0.3"],
     "--embree-rays-weak-ratio (0.3) must be under --embree-rays-max-ratio (0.3)"),
    (["evaluate", "--holdout", "1", "--methods", "zbuffer", "nearest", "--tsdf-voxel", "0.1"],
     "--tsdf-voxel does not apply to --methods zbuffer nearest (it sets tsdf)"),
    (["convert", "--target-sensor", "velodyne_vlp16", "--embree-rays-fill", "1"],
     "--embree-rays-fill does not apply to --estimator nearest (it sets embree-rays)"),
    (["evaluate", "--holdout", "1", "--target-sensor", "velodyne_vlp16"],
     "--target-sensor velodyne_vlp16 without --source-sensor"),
    (["evaluate", "--holdout", "1", "--source-sensor", "velodyne_vlp16", "--target-sensor", "velodyne_vlp16",
      "--grid-from", "others"], "--grid-from others with --target-sensor"),
    (["evaluate", "--holdout", "1", "--source-sensor", "velodyne_vlp16", "--target-sensor", "no_such_card.json"],
     "--target-sensor: no_such_card.json: no such sensor card"),
    (["convert", "--target-sensor", "no_such_card.json"], "--target-sensor: no_such_card.json: no such sensor card"),
])
def test_flags_that_would_be_ignored_or_unreachable_are_refused_in_one_line(drive, tmp_path, capsys, flags,
                                                                            message):
    r = _Run(capsys)("sequence", flags[0], drive, *flags[1:], "-o", tmp_path / "out", "--quiet")
    assert r.returncode == 2 and message in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "out").exists()


def test_a_held_out_frame_posed_away_from_its_window_is_refused_not_scored_empty(drive, tmp_path, capsys):
    rows = np.loadtxt(drive / "poses.txt").reshape(-1, 12)
    rows[1, [3, 7, 11]] += 5000.0  # frame 1 posed 8.7 km from the others: nothing of theirs in its view
    np.savetxt(tmp_path / "far.txt", rows)
    r = _Run(capsys)("sequence", "evaluate", drive, "--poses", tmp_path / "far.txt", "--holdout", "1", "--half", "1",
                     "--source-sensor", "velodyne_vlp16", "--methods", "nearest", "-o", tmp_path / "out", "--quiet")
    assert r.returncode == 2 and "frame 000001: at its pose none of the" in r.stderr, r.stderr
    assert "the frames do not overlap there" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out" / "evaluation.json").exists()


def test_the_old_sensor_flag_works_with_a_line_and_a_wrong_source_sensor_is_said(drive, tmp_path, capsys):
    run = _Run(capsys)
    r = run("sequence", "convert", drive, "--sensor", "velodyne_vlp16", "--half", "1", "-o", tmp_path / "c",
            "--quiet")
    assert r.returncode == 0 and "slr-ray: warning: sequence convert --sensor is --target-sensor now" in r.stderr
    r = run("sequence", "evaluate", drive, "--holdout", "1", "--half", "1", "--methods", "nearest",
            "--source-sensor", "velodyne_hdl64e_s2", "-o", tmp_path / "e", "--quiet")
    assert r.returncode == 0, r.stderr
    # a VLP-16's frames named an HDL-64E's: not in its scan order (a ring field: on 16 of its 64 beams)
    assert "warning: frame 000001" in r.stderr and "another sensor (--source-sensor)" in r.stderr


def test_convert_says_when_the_frames_seem_not_of_the_source_sensor(drive, tmp_path, capsys):
    r = _Run(capsys)("sequence", "convert", drive, "--target-sensor", "velodyne_vlp16", "--half", "1",
                     "--source-sensor", "velodyne_hdl64e_s2", "--remove-moving", "visibility", "-o", tmp_path / "c",
                     "--quiet")
    assert r.returncode == 0, r.stderr
    assert "warning: frame 000000: not in velodyne_hdl64e_s2's scan order" in r.stderr and "--source-sensor" in r.stderr
    r = _Run(capsys)("sequence", "convert", drive, "--target-sensor", "velodyne_hdl64e_s2", "--half", "1",
                     "--source-sensor", "velodyne_vlp16", "--remove-moving", "visibility", "-o", tmp_path / "d",
                     "--quiet")
    assert r.returncode == 0 and "scan order" not in r.stderr, r.stderr   # the right one: nothing said of it
    assert r.stderr.count("warning") == 1 and "lie outside what the source frames saw" in r.stderr  # (#45 item 5)


def test_a_ring_field_on_few_of_the_sensors_beams_is_a_problem_of_the_named_sensor():
    from slr_ray.sensors import sensor
    from slr_ray.sequence.sources import source_sensor_problem
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(320, 3)) * 10
    ring = {"ring": np.repeat(np.arange(16), 20)}
    assert "on 16 of velodyne_hdl64e_s2's 64 beams" in source_sensor_problem(pts, ring, sensor("velodyne_hdl64e_s2"))
    assert source_sensor_problem(pts, ring, sensor("velodyne_vlp16")) is None
    assert "scan order" in source_sensor_problem(pts, {}, sensor("velodyne_vlp16"))
