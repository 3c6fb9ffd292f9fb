"""The registration gate (issue #48, item 8): ICP aligns any two clouds, and a KITTI street frame
registered onto an indoor scan was scored as a pair. ``slr_ray.registration`` refuses a registration
whose fitness, reverse fitness, inlier RMSE or tilt is not what overlapping frames give, in
``evaluate`` and ``sequence --register``, naming the check, its figure and its bound."""

import json
import math

import numpy as np
import pytest

from slr_ray.errors import InputValueError
from slr_ray.evaluate import evaluate_pair
from slr_ray.io import PointCloud, write_cloud
from slr_ray.registration import (REGISTRATION_BOUNDS, Registration, check_registration, register,
                                  registration_checks)
from slr_ray.sensors import BeamPattern

from conftest import DATA
from test_evaluate import room as _room  # the room scene the pair tests register

SMALL = BeamPattern(np.linspace(2.0, -24.0, 16), 360, max_range=120.0, name="small")


def _pose(tilt_deg=0.0, turn_deg=0.0):
    a, b = math.radians(tilt_deg), math.radians(turn_deg)
    tilt = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    turn = np.array([[math.cos(b), -math.sin(b), 0], [math.sin(b), math.cos(b), 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = turn @ tilt
    return T


def _reg(fitness=0.9, reverse=0.9, rmse=0.07, tilt=0.0, turn=0.0):
    return Registration(_pose(tilt, turn), fitness, rmse, 0.2, "identity", 0.0, reverse)


def test_each_check_fails_past_its_bound_alone_and_names_its_figure_and_bound():
    b = REGISTRATION_BOUNDS
    assert registration_checks(_reg()) == []
    assert registration_checks(_reg(turn=179.0)) == []  # a turn about the vertical is no tilt
    cases = {"fitness": _reg(fitness=b["min_fitness"] - 0.01),
             "reverse fitness": _reg(reverse=b["min_reverse_fitness"] - 0.01),
             "inlier RMSE": _reg(rmse=b["max_rmse_share"] * 0.2 + 0.005),
             "tilt": _reg(tilt=b["max_tilt_deg"] + 1)}
    for name, reg in cases.items():
        failed = registration_checks(reg)
        assert [n for n, _ in failed] == [name]
        with pytest.raises(InputValueError, match=f"^registration refused: B registered to A fails the check {name} ") \
                as err:
            check_registration(reg)
        assert "\n" not in str(err.value) and "do the frames overlap?" in str(err.value)
    assert "reverse fitness 0.490 < 0.5" in registration_checks(cases["reverse fitness"])[0][1]
    assert "tilt 31.0 deg > 30 deg" in registration_checks(cases["tilt"])[0][1]
    # at the bound: accepted; a figure not measured (NaN): refused; a bound loosened: accepted
    assert registration_checks(_reg(fitness=b["min_fitness"], reverse=b["min_reverse_fitness"],
                                    tilt=b["max_tilt_deg"] - 1e-6)) == []
    assert [n for n, _ in registration_checks(_reg(reverse=math.nan))] == ["reverse fitness"]
    assert registration_checks(cases["tilt"], {"max_tilt_deg": 90}) == []
    for bad in ({"max_tilt": 90}, {"min_fitness": math.nan}, {"min_fitness": -1}, {"min_fitness": True}):
        with pytest.raises(InputValueError, match="bounds: "):
            registration_checks(_reg(), bad)


def _street():
    """Open ground with twelve buildings: another scene than the room, whose floor ICP slides onto."""
    trimesh = pytest.importorskip("trimesh")
    ground = trimesh.creation.box(extents=[200, 200, 0.2])
    ground.apply_translation([0, 0, -4.1])
    parts, rng = [ground], np.random.default_rng(0)
    for _ in range(12):
        b = trimesh.creation.box(extents=rng.uniform([2, 2, 2], [8, 8, 12]))
        b.apply_translation([rng.uniform(-40, 40), rng.uniform(-40, 40), 0])
        parts.append(b)
    return trimesh.util.concatenate(parts)


@pytest.fixture(scope="module")
def scenes():
    from slr_ray import scan_mesh

    room = _room()
    return {"room": scan_mesh(room, [0.0, 0, 0], SMALL).points,
            "room moved": scan_mesh(room, [0.5, 0.2, 0.0], SMALL).points - [0.5, 0.2, 0.0],
            "street": scan_mesh(_street(), [0.0, 0, 0], SMALL).points}


def test_an_overlapping_synthetic_pair_passes_the_gate(scenes):
    reg = register(scenes["room moved"], scenes["room"])
    assert registration_checks(reg) == [], reg.to_dict()
    assert reg.reverse_fitness >= 0.7 and reg.tilt_deg < 1
    np.testing.assert_allclose(reg.transform[:3, 3], [0.5, 0.2, 0.0], atol=0.05)


@pytest.fixture(scope="module")
def unrelated(scenes):
    """The street registered onto the room (once: the wiring tests below reuse it)."""
    return register(scenes["street"], scenes["room"])


def test_unrelated_synthetic_clouds_fail_the_gate(unrelated):
    """The street registered onto the room: fitness 0.32 and inlier RMSE 0.05 m passed the old bounds
    (fitness >= 0.3, RMSE <= 0.12 m); its reverse fitness (0.28: most of the room has no street point
    near it) does not pass."""
    failed = dict(registration_checks(unrelated))
    assert "reverse fitness" in failed, unrelated.to_dict()
    assert unrelated.reverse_fitness < REGISTRATION_BOUNDS["min_reverse_fitness"]


@pytest.fixture
def registers(monkeypatch, unrelated):
    """``register`` as evaluate and register_chain call it, answering the unrelated pair's registration."""
    calls = []

    def fake(b, a, *args, **kwargs):
        calls.append(len(b))
        return unrelated
    monkeypatch.setattr("slr_ray.evaluate.register", fake)
    monkeypatch.setattr("slr_ray.sequence.frames.register", fake)
    return calls


def test_evaluate_pair_refuses_unrelated_clouds_unless_accepted(scenes, registers):
    with pytest.raises(InputValueError, match="^registration refused: B registered to A fails the checks? .*"
                                              "reverse fitness 0.[0-4]") as err:
        evaluate_pair(scenes["room"], scenes["street"], a_beams=None, b_beams=None, sensor=SMALL,
                      methods=("zbuffer",))
    assert "accept_registration=True, --accept-registration" in str(err.value) and "\n" not in str(err.value)
    res = evaluate_pair(scenes["room"], scenes["street"], a_beams=None, b_beams=None, sensor=SMALL,
                        methods=("zbuffer",), accept_registration=True)
    assert res["registration"]["reverse_fitness"] < REGISTRATION_BOUNDS["min_reverse_fitness"]
    assert registers == [len(scenes["street"])] * 2
    with pytest.raises(InputValueError, match="accept_registration must be True or False"):
        evaluate_pair(scenes["room"], scenes["street"], a_beams=None, b_beams=None, sensor=SMALL,
                      methods=("zbuffer",), accept_registration="yes")


def test_cli_evaluate_and_sequence_register_refuse_unrelated_frames_in_one_line(scenes, registers, tmp_path,
                                                                                 capsys):
    from slr_ray.cli import main
    from slr_ray.sequence import read_sequence, register_chain

    files = []
    for name in ("room", "street"):
        files.append(tmp_path / f"{name}.npz")
        write_cloud(files[-1], PointCloud(scenes[name]))
    out = tmp_path / "out"
    rc = main(["evaluate", *map(str, files), "-o", str(out), "--source-sensor", "velodyne_vlp16", "--beams", "none",
               "--methods", "zbuffer", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("slr-ray: error: registration refused: B registered to A fails the check")
    assert "reverse fitness" in err and "--accept-registration" in err and err.count("\n") == 1
    assert not out.exists() or not any(out.iterdir())
    with pytest.raises(InputValueError, match=r"^registration refused: frame 1 \(.*street.npz\) registered to frame "
                                              r"0 \(.*room.npz\) fails .*reverse fitness.*--poses FILE.*"
                                              "--accept-registration"):
        register_chain(read_sequence([str(f) for f in files]))
    seq, regs = register_chain(read_sequence([str(f) for f in files]), accept_registration=True)
    assert len(regs) == 1 and seq.pose_source == "register"
    rc = main(["evaluate", *map(str, files), "-o", str(out), "--transform", str(files[0]), "--accept-registration"])
    assert rc == 2 and "--accept-registration with --transform" in capsys.readouterr().err
    (tmp_path / "eye.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    rc = main(["evaluate", *map(str, files), "-o", str(out), "--transform", str(tmp_path / "eye.txt"),
               "--min-fitness", "0.9", "--source-sensor", "velodyne_vlp16", "--beams", "none", "--quiet"])
    assert rc == 2 and "--min-fitness with --transform" in capsys.readouterr().err  # ignored before


@pytest.mark.skipif(not (DATA / "pump_tls.e57").exists() or not (DATA / "kitti_hdl64_000000.bin").exists(),
                    reason="the shared samples (../shared/data: pump_tls.e57, kitti_hdl64_000000.bin) are absent")
def test_the_indoor_pump_scan_onto_a_kitti_frame_is_refused():
    """The issue's case, the way the old bounds accepted it (fitness 0.589, inlier RMSE 0.098 m,
    a 157 deg turn): refused now by its reverse fitness (0.034) and its tilt (96 deg). Whole clouds
    (a thinned cloud registers otherwise); the other direction, and the other unrelated pairs, are
    benchmarks/registration_gate.py's."""
    from slr_ray.io import read_cloud

    kitti = read_cloud(DATA / "kitti_hdl64_000000.bin").points
    pump = read_cloud(DATA / "pump_tls.e57").points
    reg = register(pump, kitti)
    failed = [name for name, _ in registration_checks(reg)]
    assert "reverse fitness" in failed, json.dumps({k: v for k, v in reg.to_dict().items() if k != "transform"})
