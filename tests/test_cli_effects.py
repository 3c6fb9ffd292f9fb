"""Sensor effects on the command line: scan and augment flags, an effects file,
``slr-ray effects fit-drop``, a scene's [effects], and the refusals."""

import json
import warnings

import numpy as np
import pytest
from scipy.spatial import cKDTree

from slr_ray import InputValueError, ScanPattern, prepare
from slr_ray.augment import AugmentConfig, augment
from slr_ray.cli import main
from slr_ray.effects import Effects, RayDropModel, simulate_given
from slr_ray.io import PointCloud, read_cloud, write_cloud
from slr_ray.scan import Scan

from conftest import DATA

KITTI = DATA / "kitti_hdl64_000000.bin"
PATTERN = ["--resolution", "1", "--zenith-range", "80", "100"]


def _wall(step=False):
    """A wall 10 m away (x = 10), 0.04 m spacing; with ``step``, its half y >= 0 at x = 12."""
    y, z = np.meshgrid(np.arange(-5, 5, 0.04), np.arange(-1.5, 1.5, 0.04), indexing="ij")
    x = np.where(step & (y >= 0), 12.0, 10.0)
    return np.column_stack([x.ravel(), y.ravel(), z.ravel()])


@pytest.fixture
def wall(tmp_path):
    pts = _wall()
    path = tmp_path / "wall.npz"
    write_cloud(path, PointCloud(pts, {"intensity": np.linspace(0.1, 0.9, len(pts)),
                                       "label": np.arange(len(pts), dtype=np.int32)}, np.zeros(3)))
    return path


def _scan(src, out, *flags, capsys=None):
    rc = main(["scan", str(src), "-o", str(out), *PATTERN, *flags])
    res = json.loads(capsys.readouterr().out) if capsys is not None and rc == 0 else None
    return rc, res


def test_no_effect_is_the_ideal_scan(wall, tmp_path, capsys):
    assert _scan(wall, tmp_path / "ideal.npz", capsys=capsys)[0] == 0
    rc, res = _scan(wall, tmp_path / "seed.npz", "--effects-seed", "5", capsys=capsys)  # a seed alone: no effect
    assert rc == 0
    a, b = read_cloud(tmp_path / "ideal.npz"), read_cloud(tmp_path / "seed.npz")
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.attributes["label"], b.attributes["label"])
    assert "return_number" not in b.attributes


def test_range_noise_is_seeded_and_of_its_size(wall, tmp_path, capsys):
    _scan(wall, tmp_path / "ideal.npz", capsys=capsys)
    ideal = read_cloud(tmp_path / "ideal.npz")
    outs = {}
    for name, seed in (("a", "1"), ("b", "1"), ("c", "2")):
        rc, res = _scan(wall, tmp_path / f"{name}.npz", "--range-noise", "0.05", "--effects-seed", seed,
                        capsys=capsys)
        assert rc == 0 and res["effects"]["range_noise"] == 0.05 and res["effects"]["seed"] == int(seed)
        outs[name] = read_cloud(tmp_path / f"{name}.npz")
    a, b, c = outs["a"], outs["b"], outs["c"]
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.array_equal(a.points, c.points)
    # the same points of the input (labels follow; the returns in pulse order), moved along their rays by ~5 cm
    order = np.argsort(a.attributes["label"])
    np.testing.assert_array_equal(a.attributes["label"][order], ideal.attributes["label"])
    dr = np.linalg.norm(a.points[order], axis=1) - np.linalg.norm(ideal.points, axis=1)
    assert 0.04 < dr.std() < 0.06 and abs(dr.mean()) < 0.01


def test_an_effects_file_toml_or_json_and_a_flag_over_it(wall, tmp_path, capsys):
    (tmp_path / "e.toml").write_text("range_noise = 0.05\nmin_range = 10.3\nseed = 3\n")
    (tmp_path / "e.json").write_text(json.dumps({"effects": {"range_noise": 0.05, "min_range": 10.3, "seed": 3}}))
    _, ideal = _scan(wall, tmp_path / "ideal.npz", capsys=capsys)
    _, ft = _scan(wall, tmp_path / "t.npz", "--effects", str(tmp_path / "e.toml"), capsys=capsys)
    _, fj = _scan(wall, tmp_path / "j.npz", "--effects", str(tmp_path / "e.json"), capsys=capsys)
    np.testing.assert_array_equal(read_cloud(tmp_path / "t.npz").points, read_cloud(tmp_path / "j.npz").points)
    assert ft["removed_range_limits"] > 0 and ft["points_out"] == ideal["points_out"] - ft["removed_range_limits"]
    # the flag wins over the file: no noise, the file's blind zone kept
    _, fo = _scan(wall, tmp_path / "o.npz", "--effects", str(tmp_path / "e.toml"), "--range-noise", "0",
                  capsys=capsys)
    o = read_cloud(tmp_path / "o.npz")
    assert fo["effects"]["range_noise"] == 0 and fo["effects"]["min_range"] == 10.3
    assert np.all(o.points[:, 0] == 10.0) and np.linalg.norm(o.points, axis=1).min() >= 10.3
    # --print-config shows the resolved effects and writes nothing
    assert main(["scan", str(wall), "-o", str(tmp_path / "p.npz"), *PATTERN, "--effects", str(tmp_path / "e.toml"),
                 "--range-noise", "0.01", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert cfg["effects"]["range_noise"] == 0.01 and cfg["effects"]["min_range"] == 10.3
    assert not (tmp_path / "p.npz").exists()


def test_divergence_gives_multiple_returns_in_the_standard_las_fields(tmp_path, capsys):
    pts = _wall(step=True)
    src = tmp_path / "step.las"
    write_cloud(src, PointCloud(pts, {"intensity": np.full(len(pts), 1000, np.uint16)}))
    rc, res = _scan(src, tmp_path / "out.las", "--origin", "0", "0", "0", "--backend", "embree",
                    "--divergence-mrad", "20", "--returns", "all", "--intensity", "carry", capsys=capsys)
    assert rc == 0 and res["effects"]["divergence_mrad"] == 20 and res["effects"]["returns"] == ["all"]
    out = read_cloud(tmp_path / "out.las")
    rn, nr = out.attributes["return_number"], out.attributes["number_of_returns"]
    assert res["returns_in_multi_return_pulses"] > 0 and nr.max() == 2  # the step's edge: wall at 10 and at 12 m
    assert np.all((rn >= 1) & (rn <= nr))
    # intensity: the share of each return's footprint, in the input's integer type
    assert out.attributes["intensity"].dtype == np.uint16 and out.attributes["intensity"].max() <= 1000
    assert out.attributes["intensity"][nr == 2].min() < 1000
    # npz keeps them as arrays
    assert _scan(src, tmp_path / "out.npz", "--origin", "0", "0", "0", "--backend", "embree",
                 "--divergence-mrad", "20", capsys=capsys)[0] == 0
    assert read_cloud(tmp_path / "out.npz").attributes["number_of_returns"].max() == 2


def ring_frame(n_rings=8, n_cols=720, drop=0.1, seed=0):
    """A spinning sensor's frame of a cylinder (radius 10 m), ring after ring, azimuth increasing; more
    pulses are dropped on the lower rings (further along the slanted ray)."""
    rng = np.random.default_rng(seed)
    step = 360.0 / n_cols
    pts = []
    for k in range(n_rings):
        keep = rng.random(n_cols) >= drop * (1 + k / 2)
        keep[0] = keep[-1] = True
        phi = np.radians((np.flatnonzero(keep) + 0.5) * step)
        el = np.radians(2.0 - 2 * k)
        pts.append(np.column_stack([10 * np.cos(phi), 10 * np.sin(phi), np.full(len(phi), 10 * np.tan(el))]))
    return np.vstack(pts)


def test_fit_drop_writes_the_model_that_ray_drop_reads(wall, tmp_path, capsys):
    frame = tmp_path / "frame.npz"
    write_cloud(frame, PointCloud(ring_frame(), {}, np.zeros(3)))
    model_path = tmp_path / "drop.json"
    assert main(["effects", "fit-drop", str(frame), "-o", str(model_path)]) == 0
    res = json.loads(capsys.readouterr().out)
    model = RayDropModel.from_dict(json.loads(model_path.read_text()))
    assert not model.uses_intensity and res["uses_intensity"] is False
    assert 0.1 < res["drop_rate"] < 0.4 and model.info["rings_counted"] == 8
    assert Effects(ray_drop=str(model_path)).ray_drop == model
    # the model applied to a scan: fewer points, the same with the same seed
    _, ideal = _scan(wall, tmp_path / "ideal.npz", capsys=capsys)
    _, a = _scan(wall, tmp_path / "a.npz", "--ray-drop", str(model_path), capsys=capsys)
    _, b = _scan(wall, tmp_path / "b.npz", "--ray-drop", str(model_path), capsys=capsys)
    assert 0 < a["removed_ray_drop"] < ideal["points_out"] and a["points_out"] == b["points_out"]
    np.testing.assert_array_equal(read_cloud(tmp_path / "a.npz").points, read_cloud(tmp_path / "b.npz").points)
    # a relative ray_drop in an effects file is read from the file's directory
    (tmp_path / "e.toml").write_text('ray_drop = "drop.json"\n')
    assert Effects.load(tmp_path / "e.toml").ray_drop == model
    # the output goes through the plan: no overwriting without --force, the input never
    assert main(["effects", "fit-drop", str(frame), "-o", str(model_path)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["effects", "fit-drop", str(frame), "-o", str(model_path), "--force"]) == 0
    capsys.readouterr()
    assert main(["effects", "fit-drop", str(frame), "-o", str(tmp_path / "drop.txt")]) == 2
    assert ".json" in capsys.readouterr().err
    frame_json = tmp_path / "frame.json"
    frame_json.write_text("{}")
    assert main(["effects", "fit-drop", str(frame_json), "-o", str(frame_json), "--input-format", ".npz",
                 "--force"]) == 2
    assert frame_json.read_text() == "{}"
    capsys.readouterr()
    np.save(tmp_path / "no_origin.npy", ring_frame())
    assert main(["effects", "fit-drop", str(tmp_path / "no_origin.npy"), "-o", str(tmp_path / "m.json")]) == 2
    assert "--origin" in capsys.readouterr().err
    assert main(["effects", "fit-drop", str(tmp_path / "no_origin.npy"), "-o", str(tmp_path / "m.json"),
                 "--origin", "0", "0", "0"]) == 0


@pytest.mark.skipif(not KITTI.exists(), reason="../shared/data/kitti_hdl64_000000.bin is absent")
def test_fit_drop_on_the_kitti_frame_and_its_sensor_table(tmp_path, capsys):
    model_path = tmp_path / "kitti_drop.json"
    assert main(["effects", "fit-drop", str(KITTI), "-o", str(model_path)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["uses_intensity"] and res["rings"] == "the scan order" and 0.01 < res["drop_rate"] < 0.1
    assert main(["scan", str(KITTI), "-o", str(tmp_path / "b.bin"), "--sensor", "velodyne_hdl64e_s2",
                 "--origin", "1", "0", "0", "--ray-drop", str(model_path), "--range-noise", "sensor",
                 "--intensity", "carry"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["removed_ray_drop"] > 0 and res["effects"]["range_noise"] == pytest.approx(0.02)


@pytest.mark.parametrize("flags, says", [
    (["--range-noise", "-1"], "--range-noise"),
    (["--range-noise", "abc"], "--range-noise"),
    (["--range-noise", "sensor"], "range_noise='sensor'"),
    (["--divergence-mrad", "3"], "--divergence-mrad"),
    (["--divergence-mrad", "0", "--backend", "embree"], "--divergence-mrad"),
    (["--returns", "second"], "--returns"),
    (["--intensity", "invent"], "--intensity"),
    (["--ray-drop", "missing.json"], "--ray-drop"),
    (["--ray-drop", "{garbage}"], "not valid JSON"),
    (["--effects", "missing.toml"], "no effects file"),
    (["--effects", "{unknown}"], "unknown.toml: unknown effect option"),  # the file named
    (["--effects", "{motion}"], "motion"),
    (["--effects", "{badtoml}"], "not valid TOML"),
    (["--range-noise", "0.1", "--png", "x.png"], "--png"),
    # wrong types in a file or a model, a negative seed: one line, not a traceback
    (["--effects", "{types}"], "types.toml: returns must be"),
    (["--effects", "{seedstr}"], "seed must be an integer"),
    (["--effects", "{rings}"], "beam_rings must be"),
    (["--effects-seed", "-3", "--range-noise", "0.1"], "--effects-seed: seed must be an integer >= 0"),
    (["--ray-drop", "{coefstr}"], "'coef' is a list of numbers"),
    (["--ray-drop", "{coefitems}"], "coef must be 5 finite numbers"),
    (["--effects", ""], "no effects file"),  # an unset $EFFECTS: not silently the ideal scan
    (["--ray-drop", ""], "no model file given"),  # an unset $MODEL: it said "no model file '.'"
    (["--range-noise", "1e308"], "at most 1"),  # not a file of infinite points that read_cloud refuses
    # effect sizes beyond a sensor's (1e9 mrad gave more returns than points, 1e300 m of noise coordinates of
    # 3e300), options that another would ignore, duplicate returns, a model whose logit overflows
    (["--backend", "embree", "--divergence-mrad", "1e9"], "--divergence-mrad: divergence_mrad must be at most 50"),
    (["--range-noise", "1e300"], "--range-noise: range_noise must be at most 1"),
    (["--effects", "{pct}"], "max_range_at reflectivity must be at most 1"),
    (["--returns", "all"], "--returns needs --divergence-mrad"),
    (["--effects", "{slope}"], "slope.toml: range_noise_slope needs --range-noise"),
    (["--effects", "{slope}", "--effects-seed", "2"], "slope.toml: range_noise_slope needs --range-noise"),
    (["--backend", "embree", "--divergence-mrad", "2", "--returns", "first", "first"], "first given twice"),
    (["--backend", "embree", "--divergence-mrad", "2", "--returns", "all", "last"], "'all' already holds last"),
    (["--ray-drop", "{hugecoef}"], "coef must lie within"),
    (["--ray-drop", "{names}"], "'names'"),  # six names for five weights: the file disagrees with itself
])
def test_bad_effects_are_one_line_errors(wall, tmp_path, capsys, flags, says):
    (tmp_path / "garbage.json").write_text("{not json")
    (tmp_path / "unknown.toml").write_text("noise = 0.1\n")
    (tmp_path / "motion.toml").write_text("motion = true\n")
    (tmp_path / "badtoml.toml").write_text("range_noise = = 1\n")
    (tmp_path / "types.toml").write_text("returns = 3\n")
    (tmp_path / "seedstr.toml").write_text("range_noise = 0.1\nseed = 'a'\n")
    (tmp_path / "rings.toml").write_text("beam_rings = 'x'\n")
    (tmp_path / "coefstr.json").write_text('{"coef": "x"}')
    (tmp_path / "coefitems.json").write_text('{"coef": [1, 2, 3, "x", 5]}')
    (tmp_path / "hugecoef.json").write_text('{"coef": [1e308, 1e308, -1e308, 1, 1]}')
    (tmp_path / "names.json").write_text('{"coef": [1, 1, 1, 1, 1], "names": ["intercept", "range", "range^2", '
                                         '"incidence", "incidence^2", "intensity"]}')
    (tmp_path / "pct.toml").write_text("max_range_at = [50, 10]\n")  # 10 %, written as a percentage
    (tmp_path / "slope.toml").write_text("range_noise_slope = 0.01\n")
    names = {"{garbage}": "garbage.json", "{unknown}": "unknown.toml", "{motion}": "motion.toml",
             "{badtoml}": "badtoml.toml", "missing.json": "missing.json", "missing.toml": "missing.toml",
             "x.png": "x.png", "{types}": "types.toml", "{seedstr}": "seedstr.toml", "{rings}": "rings.toml",
             "{coefstr}": "coefstr.json", "{coefitems}": "coefitems.json", "{hugecoef}": "hugecoef.json",
             "{pct}": "pct.toml", "{slope}": "slope.toml", "{names}": "names.json"}
    flags = [str(tmp_path / names[f]) if f in names else f for f in flags]
    out = tmp_path / "out.npz"
    assert main(["scan", str(wall), "-o", str(out), *PATTERN, *flags]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("slr-ray: error:") and says in err, err
    assert not out.exists() and not (tmp_path / "x.png").exists()


@pytest.fixture
def small_laz(tmp_path):
    rng = np.random.default_rng(0)
    g = np.column_stack([rng.uniform(-10, 10, (40_000, 2)), rng.normal(0, 0.02, 40_000)])
    o = np.column_stack([rng.uniform(-10, 10, (8_000, 2)), rng.uniform(0.5, 5, 8_000)])
    cls = np.r_[np.full(40_000, 2, np.uint8), np.ones(8_000, np.uint8)]
    path = tmp_path / "small.laz"
    write_cloud(path, PointCloud(np.vstack([g, o]), {"classification": cls,
                                                     "intensity": np.arange(48_000, dtype=np.uint16)}))
    return path


def test_augment_records_its_effects_and_refuses_a_resume_with_others(small_laz, tmp_path, capsys):
    out = tmp_path / "aug"
    base = ["augment", str(small_laz), "--n", "2", "-o", str(out), "--min-ground-points", "500", "--resolution",
            "1", "--workers", "1", "--quiet"]
    assert main(base + ["--range-noise", "0.03", "--intensity", "carry"]) == 0
    assert json.loads(capsys.readouterr().out)["scans"] == 2
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["settings"]["effects"]["range_noise"] == 0.03 and manifest["effects"]["intensity"] == "carry"
    files = {p.name: p.read_bytes() for p in out.iterdir() if p.suffix == ".laz"}
    # the same effects resume (nothing to do); other effects, or none, are refused with the difference named
    assert main(base + ["--range-noise", "0.03", "--intensity", "carry"]) == 0
    assert json.loads(capsys.readouterr().out)["new_scans"] == 0
    for other, says in ((["--range-noise", "0.04", "--intensity", "carry"], "effects.range_noise: 0.03 -> 0.04"),
                        ([], "effects:")):
        assert main(base + other) == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.suffix == ".laz"} == files
    # the scans have noise (not the input's points), each scan its own draw, attributes carried
    src = read_cloud(small_laz)
    tree = cKDTree(src.points)
    dists = []
    for name in sorted(files):
        c = read_cloud(out / name)
        d, idx = tree.query(c.points)
        assert 0.01 < np.median(d) < 0.05
        np.testing.assert_array_equal(c.attributes["classification"][d < 1e-6],
                                      src.attributes["classification"][idx[d < 1e-6]])
        dists.append(d)
    assert not np.array_equal(dists[0][:100], dists[1][:100])


def test_augment_never_writes_the_effects_file_it_read(small_laz, tmp_path, capsys):
    """An effects file (or ray-drop model) is an input: the run's manifest may
    not be one, even though a manifest holds an [effects]-like table."""
    out = tmp_path / "aug"
    base = ["augment", str(small_laz), "--n", "2", "-o", str(out), "--min-ground-points", "500", "--resolution",
            "1", "--workers", "1", "--quiet"]
    assert main(base + ["--range-noise", "0.03"]) == 0
    capsys.readouterr()
    manifest = out / "manifest.json"
    before = manifest.read_bytes()
    assert main(base[:3] + ["3"] + base[4:] + ["--effects", str(manifest)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "manifest.json" in err, err
    assert manifest.read_bytes() == before


def test_augment_config_refuses_effects_it_cannot_make(small_laz, tmp_path):
    for effects, chunk, says in (({"divergence_mrad": 3.0}, None, "embree"), ({"range_noise": 0.1}, 10_000, "stream"),
                                 ({"motion": True}, None, "poses"), ({"noise": 1}, None, "unknown"),
                                 ({"intensity": "correct"}, None, "no scanner origin")):
        with pytest.raises(InputValueError, match=says):
            augment(small_laz, tmp_path / "a", AugmentConfig(n=1, effects=effects, chunk_size=chunk,
                                                             min_ground_points=500), progress=False)
        assert not (tmp_path / "a").exists()


def test_scene_scan_applies_the_scenes_effects_and_validate_refuses_them(tmp_path, capsys):
    spec = tmp_path / "noisy.toml"
    spec.write_text("[scene]\nn_rectangles = 20\nseed = 1\n\n[effects]\nrange_noise = 0.05\nmin_range = 3.0\n")
    args = ["scene", "scan", str(spec), "--origin", "0", "0", "0", "--resolution", "2", "--quiet"]
    assert main(args + ["-o", str(tmp_path / "e.npz")]) == 0
    eff = json.loads(capsys.readouterr().out)
    assert main(args + ["-o", str(tmp_path / "i.npz"), "--no-effects"]) == 0
    ideal = json.loads(capsys.readouterr().out)
    assert "effects" not in ideal and eff["effects"]["range_noise"] == 0.05
    assert eff["points_out"] == ideal["points_out"] - eff["removed_range_limits"] > 0
    e, i = read_cloud(tmp_path / "e.npz"), read_cloud(tmp_path / "i.npz")
    assert e.attributes["range"].min() > 3.0 - 6 * 0.05 and i.attributes["range"].min() < 2.5  # noise after the cut
    # divergence is not a mesh scan's
    spec.write_text("[scene]\nn_rectangles = 20\n\n[effects]\ndivergence_mrad = 3.0\n")
    assert main(args + ["-o", str(tmp_path / "d.npz")]) == 2
    assert "--no-effects" in capsys.readouterr().err and not (tmp_path / "d.npz").exists()
    # a validation compares ideal scans: a scene that requires effects is refused, in one line
    cfg = tmp_path / "v.toml"
    cfg.write_text(f'[validate]\nname = "t"\nscenes = ["{spec}"]\npositions = 1\n')
    assert main(["validate", str(cfg), "-o", str(tmp_path / "v"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "requires sensor effects" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "v").exists()


def test_simulate_given_takes_a_scan_made_elsewhere():
    pts = _wall()
    pattern = ScanPattern(1.0, zenith_range=(80, 100))
    ideal = prepare(pts).scan([0, 0, 0], pattern)
    given = Scan(np.arange(len(ideal)), ideal.ranges, ideal.pulses, ideal.origin, pattern, backend="mesh")
    same = simulate_given(given, pts[ideal.indices])
    np.testing.assert_array_equal(np.sort(same.indices), np.arange(len(ideal)))
    noisy = simulate_given(given, pts[ideal.indices], Effects(range_noise=0.05, min_range=10.2, seed=1))
    assert 0 < len(noisy) < len(ideal) and noisy.info["removed_range_limits"] == len(ideal) - len(noisy)
    with pytest.raises(InputValueError, match="divergence"):
        simulate_given(given, pts[ideal.indices], Effects(divergence_mrad=3.0))


def test_fit_drop_refuses_a_frame_that_is_not_a_scan_and_normals_from_too_few_neighbours(tmp_path, capsys):
    """A shuffled frame read in scan order gave thousands of 'rings' and a 68 deg column step, a
    random cloud thousands of rings, a ring field of random floats was truncated; -k 1 took a normal
    from one neighbour and -k 1000000000 said 'too few points'."""
    pts = ring_frame()
    rng = np.random.default_rng(3)
    frames = {"shuffled": PointCloud(pts[rng.permutation(len(pts))], {}, np.zeros(3)),
              "random": PointCloud(rng.uniform(-20, 20, (3000, 3)), {}, np.zeros(3)),
              "float_ring": PointCloud(pts, {"ring": rng.random(len(pts))}, np.zeros(3)),
              "random_ring": PointCloud(pts, {"ring": rng.integers(0, 8, len(pts)).astype(np.int32)}, np.zeros(3)),
              "good": PointCloud(pts, {}, np.zeros(3))}
    cases = [("shuffled", [], "--rings auto"), ("random", ["--rings", "scan-order"], "rings"),
             ("float_ring", [], "integers"), ("random_ring", [], "not a scan's rings"), ("good", ["-k", "1"], "-k 1"),
             ("good", ["-k", "1000000000"], "-k 1000000000"), ("good", ["--column-step-deg", "90"], "--column-step"),
             ("good", ["--intensity-scale", "1e-300"], "--intensity-scale")]
    for name, flags, says in cases:
        path = tmp_path / f"{name}.npz"
        if not path.exists():
            write_cloud(path, frames[name])
        out = tmp_path / "m.json"
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            rc = main(["effects", "fit-drop", str(path), "-o", str(out), *flags])
        err = capsys.readouterr().err
        assert rc == 2 and says in err and err.count("\n") == 1 and not out.exists(), (name, flags, err)


def test_a_ray_drop_model_never_overflows():
    big = RayDropModel((1e6, 1e6, -1e6, 1e6, 1e6))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = big.probability([1e300, 10.0], [45.0, 45.0])
    assert p.tolist() == [0.0, 1.0]  # -1e6 rho^2 dominates at 1e300 m
    with pytest.raises(InputValueError, match="within"):
        RayDropModel((1e308, 0, 0, 0, 0))


def test_fit_drop_on_a_frame_with_nothing_to_fit_names_the_frame(wall, tmp_path, capsys):
    rc = main(["effects", "fit-drop", str(wall), "-o", str(tmp_path / "m.json")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "wall.npz" in err, err
    assert not (tmp_path / "m.json").exists()
