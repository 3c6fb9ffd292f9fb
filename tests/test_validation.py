import csv
import json
from pathlib import Path

import numpy as np
import pytest

from slr_ray import InputTypeError, InputValueError
from slr_ray.cli import main
from slr_ray.plotting import paper_figure, save_figure, validation_figure
from slr_ray.validation import load_config, load_rows, read_rows, run_validation, stage_summary


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    cfg = load_config("quick")
    cfg.positions = 2
    cfg.backends = ["binning"]
    out = tmp_path_factory.mktemp("val")
    res = run_validation(cfg, out, progress=False)
    return cfg, out, res


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_quick_validation_writes_rows(quick):
    cfg, out, res = quick
    rows = _rows(out / "results.csv")
    assert len(rows) == res["rows"] == 2 * len(cfg.truths)
    for r in rows:
        assert 0 <= float(r["similarity"]) <= 1 and int(r["true_points"]) > 0
    assert set(res["headline"]) == {"binning/center", "binning/nearest"}


def test_resume_adds_only_missing_rows_and_same_seed_same_numbers(quick, tmp_path):
    cfg, out, _ = quick
    before = _rows(out / "results.csv")
    again = run_validation(cfg, out, progress=False)  # everything done: nothing new
    assert again["new_rows"] == 0 and _rows(out / "results.csv") == before
    cfg.positions = 3
    more = run_validation(cfg, out, progress=False)
    assert more["new_rows"] == len(cfg.truths)
    rows = _rows(out / "results.csv")
    assert rows[: len(before)] == before
    # a fresh run of the same config gives the same numbers
    fresh = run_validation(cfg, tmp_path / "fresh", progress=False)
    assert fresh["rows"] == len(rows)
    key = lambda r: (r["position"], r["truth"])  # noqa: E731
    a = {key(r): r["similarity"] for r in rows}
    b = {key(r): r["similarity"] for r in _rows(tmp_path / "fresh" / "results.csv")}
    assert a == b
    cfg.positions = 2


def test_figure(quick, tmp_path):
    _, out, _ = quick
    save_figure(validation_figure(load_rows(out / "results.csv")), tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 5000
    # figures read no files (slr_ray.plotting imports no computation): a path is refused, saying what reads it
    with pytest.raises(InputTypeError, match="load_rows"):
        validation_figure(out / "results.csv")
    assert validation_figure(read_rows(out / "results.csv")).axes  # read_rows' rows by key: the same rows


def test_a_resume_with_settings_that_change_rows_is_refused(quick, tmp_path, capsys):
    cfg, out, _ = quick
    before = (out / "results.csv").read_bytes()
    settings = json.loads((out / "settings.json").read_text())
    assert settings["secondary_resolution"] == cfg.secondary_resolution
    for name, value in (("secondary_resolution", cfg.secondary_resolution * 2), ("seed", cfg.seed + 1),
                        ("embree_options", {"ties": 0.0})):
        old = getattr(cfg, name)
        setattr(cfg, name, value)
        try:
            with pytest.raises(InputValueError, match=name):
                run_validation(cfg, out, progress=False)
        finally:
            setattr(cfg, name, old)
    assert (out / "results.csv").read_bytes() == before  # nothing appended
    # a default of this version that differs from the one the rows were made with (an upgrade) is named too;
    # options only one side knows (added by a newer version) are not compared
    assert settings["embree_resolved"]["ties"] == 1.0 and "primary_origin" not in settings["embree_resolved"]
    tampered = {**settings, "embree_resolved": {**settings["embree_resolved"], "ties": 3.0, "gone_option": 1}}
    (out / "settings.json").write_text(json.dumps(tampered))
    try:
        with pytest.raises(InputValueError, match="embree option ties: 3.0 in the run, 1.0 now"):
            run_validation(cfg, out, progress=False)
    finally:
        (out / "settings.json").write_text(json.dumps(settings))
    # what only adds rows is not a change of settings; an old run without the file takes the current ones
    cfg.truths, truths = ["center"], cfg.truths
    try:
        assert run_validation(cfg, out, progress=False)["new_rows"] == 0
    finally:
        cfg.truths = truths
    old = tmp_path / "old"
    old.mkdir()
    (old / "results.csv").write_bytes(before)
    for f in ("positions",):
        (old / f).mkdir()
        for p in (out / f).iterdir():
            (old / f / p.name).write_bytes(p.read_bytes())
    assert run_validation(cfg, old, progress=False)["new_rows"] == 0
    assert json.loads((old / "settings.json").read_text()) == settings
    # the command line says it in one line and exits 2
    cfg_file = tmp_path / "q.toml"
    text = (Path(__file__).parents[1] / "scenes" / "validate-quick.toml").read_text()
    assert "secondary_resolution = 0.36" in text
    cfg_file.write_text(text.replace("secondary_resolution = 0.36", "secondary_resolution = 0.5"))
    assert main(["validate", str(cfg_file), "--quiet", "-o", str(out)]) == 2
    assert "secondary_resolution" in capsys.readouterr().err


def test_configs_and_cli(tmp_path, capsys):
    for name in ("quick", "paper", "paper-hour", "distance", "occlusion", "resolution", "embree"):
        assert load_config(name).positions >= 1
    paper, hour = load_config("paper"), load_config("paper-hour")
    for cfg in (paper, hour):
        entries = [cfg.scene_entry(e) for e in cfg.scenes]
        assert len(entries) == 9 and sum(len(r) for _, r in entries) == 13  # 9 x 0.0144 + 4 x 0.00576
    # validate-paper: embree at every position of every primary; the hour-long one at every 10th
    assert (paper.embree_every, paper.embree_primary_resolutions, paper.backends) == (1, None, ["binning", "embree"])
    assert hour.embree_every == 10
    # the two make the same rows where they overlap (the same settings; the hour-long run is a subset)
    from slr_ray.validation.results import ROW_SETTINGS
    assert all(getattr(paper, k) == getattr(hour, k) for k in ROW_SETTINGS)
    assert load_config("resolution").positions_resolution == 0.0144
    assert main(["validate", "distance", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert cfg["scenes"][0] == "distance-1" and cfg["primary_resolutions"] == [0.0144]
    bad = tmp_path / "bad.toml"
    bad.write_text("[validate]\nbackends = ['magic']\n")
    with pytest.raises(InputValueError, match="magic"):
        load_config(bad)
    assert main(["validate", str(tmp_path / "missing.toml")]) == 2
    quick = (tmp_path / "q.toml")
    text = (Path(__file__).parents[1] / "scenes" / "validate-quick.toml").read_text()
    quick.write_text(text.replace('backends = ["binning", "embree"]', 'backends = ["binning"]'))
    assert main(["validate", str(quick), "--positions", "1", "--quiet", "-o", str(tmp_path / "out")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["rows"] == 2 and len(res["figures"]) == 2  # figure3 and the paper figure (rect-0500 is a paper scene)
    assert "Questions 2 and 3" in (tmp_path / "out" / "report.md").read_text()
    assert json.loads((tmp_path / "out" / "report.json").read_text())["occlusion"]["0.1"]["rect-0500"]["pairs"] == 1


@pytest.fixture(scope="module")
def two_primaries(tmp_path_factory):
    """One scene, two primaries; the nearest truth at every other position."""
    cfg = load_config("quick")
    cfg.scenes = [{"scene": "rect-0500", "primary_resolutions": [0.2, 0.1]}]
    cfg.positions = 3
    cfg.backends = ["binning"]
    cfg.nearest_every = 2
    out = tmp_path_factory.mktemp("two")
    run_validation(cfg, out, progress=False)
    return cfg, out


def test_primaries_of_a_scene_share_positions_and_true_scans(two_primaries):
    cfg, out = two_primaries
    rows = _rows(out / "results.csv")
    by = {}
    for r in rows:
        by.setdefault((r["position"], r["truth"]), {})[float(r["primary_resolution"])] = r
    assert {k for k, _ in by} == {"0", "1", "2"}
    # the nearest truth only at positions 0, 2; centre truth everywhere
    assert sorted(k for k in by if k[1] == "nearest") == [("0", "nearest"), ("2", "nearest")]
    for pair in by.values():
        a, b = pair[0.2], pair[0.1]
        assert (a["x"], a["y"], a["z"]) == (b["x"], b["y"], b["z"])  # drawn once, on the 0.2 primary
        assert a["true_points"] == b["true_points"]  # the same true scan
        assert a["slr_points"] != b["slr_points"]  # from different primaries
    pos = np.loadtxt(out / "positions" / "rect-0500.csv", delimiter=",", ndmin=2)
    assert pos.shape == (3, 3) and float(by[("1", "center")][0.1]["x"]) == pytest.approx(pos[1, 0])
    assert not (out / ".truths" / "rect-0500").exists()  # shared true scans wait on disk until the scene is done
    stages = _rows(out / "stages.csv")
    # the paper's rows (binning vs centre) apart from the extras (the nearest truth)
    assert [s["stage"] for s in stages] == ["primary scan", "positions", "pairs", "extras", "primary scan",
                                            "pairs", "extras", "run"]
    assert all(float(s["peak_rss_gib"]) > 0 for s in stages)
    summary = stage_summary(out / "stages.csv")
    paper = sum(float(s["seconds"]) for s in stages if s["stage"] in ("primary scan", "positions", "pairs"))
    assert summary["paper_seconds"] == pytest.approx(paper, abs=0.2) and summary["extras_seconds"] > 0
    assert summary["sittings"] == 1 and summary["wall_seconds"] >= summary["paper_seconds"]


def test_stage_summary_counts_sittings_that_were_cut_off(tmp_path):
    """A sitting killed before its run row still counts, with its stages as its wall time; a call that
    found nothing to do does not."""
    head = "scene,primary_resolution,stage,seconds,count,peak_rss_gib\n"
    body = ("a,0.1,primary scan,10,5,1\na,0.1,pairs,20,3,1\n"       # sitting 1, killed
            "a,0.1,primary scan,11,5,1\na,0.1,pairs,30,5,2\n(all),,run,50,5,2\n"  # sitting 2, finished
            "(all),,run,0.0,0,0.1\n"                                   # nothing left to do
            "b,0.1,primary scan,7,5,1\n")                               # sitting 3, running or killed
    (tmp_path / "stages.csv").write_text(head + body)
    st = stage_summary(tmp_path / "stages.csv")
    assert (st["sittings"], st["interrupted"]) == (3, 2)
    assert st["wall_seconds"] == pytest.approx(30 + 50 + 7) and st["paper_seconds"] == pytest.approx(78)
    assert st["peak_rss_gib"] == 2


def test_resume_reads_positions_and_skips_their_primary(two_primaries, tmp_path):
    import shutil

    cfg, out = two_primaries
    shutil.copytree(out, tmp_path / "r")
    rows = _rows(tmp_path / "r" / "results.csv")
    kept = [r for r in rows if float(r["primary_resolution"]) == 0.2]
    with open(tmp_path / "r" / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, list(rows[0]))
        w.writeheader()
        w.writerows(kept)
    res = run_validation(cfg, tmp_path / "r", progress=False)
    assert res["new_rows"] == len(rows) - len(kept)
    new_stages = _rows(tmp_path / "r" / "stages.csv")[8:]
    assert [(s["stage"], s["primary_resolution"]) for s in new_stages] == [
        ("primary scan", "0.1"), ("pairs", "0.1"), ("extras", "0.1"), ("run", "")]
    assert stage_summary(tmp_path / "r" / "stages.csv")["sittings"] == 2  # a resumed run says so
    key = lambda r: (r["primary_resolution"], r["position"], r["truth"])  # noqa: E731
    assert {key(r): r["similarity"] for r in rows} == \
        {key(r): r["similarity"] for r in _rows(tmp_path / "r" / "results.csv")}


def test_positions_resolution_outside_the_rows(two_primaries, tmp_path):
    cfg, out = two_primaries
    cfg2 = load_config("quick")
    cfg2.scenes = [{"scene": "rect-0500", "primary_resolutions": [0.1]}]
    cfg2.positions_resolution = 0.2
    cfg2.positions, cfg2.backends, cfg2.truths = 3, ["binning"], ["center"]
    run_validation(cfg2, tmp_path, progress=False)
    rows = _rows(tmp_path / "results.csv")
    assert {float(r["primary_resolution"]) for r in rows} == {0.1}
    np.testing.assert_array_equal(np.loadtxt(tmp_path / "positions" / "rect-0500.csv", delimiter=","),
                                  np.loadtxt(out / "positions" / "rect-0500.csv", delimiter=","))
    ref = {r["position"]: r["similarity"] for r in _rows(out / "results.csv")
           if float(r["primary_resolution"]) == 0.1 and r["truth"] == "center"}
    assert {r["position"]: r["similarity"] for r in rows} == ref


def test_wanted_rows_and_bad_entries():
    cfg = load_config("quick")
    cfg.backends, cfg.truths = ["binning", "embree"], ["center", "nearest"]
    cfg.nearest_every, cfg.embree_every, cfg.embree_primary_resolutions = 3, 2, [0.0144]
    assert cfg.wanted(0.0144, 0) == [("binning", "center"), ("binning", "nearest"),
                                     ("embree", "center"), ("embree", "nearest")]
    assert cfg.wanted(0.0144, 2) == [("binning", "center"), ("embree", "center")]
    assert cfg.wanted(0.0144, 3) == [("binning", "center"), ("binning", "nearest")]
    assert cfg.wanted(0.00576, 0) == [("binning", "center"), ("binning", "nearest")]
    assert cfg.wanted(0.0144, 0, ["binning"]) == [("binning", "center"), ("binning", "nearest")]
    assert cfg.scene_backends({"scene": "x", "backends": ["binning"]}) == ["binning"]
    assert cfg.scene_backends("x") == ["binning", "embree"]
    for bad, msg in (([{"scene": "rect-0500", "resolution": [1]}], "scenes entry"), ([3], "scenes entry"),
                     ([{"scene": "rect-0500", "primary_resolutions": [-1]}], "positive"),
                     ([{"scene": "rect-0500", "primary_resolutions": ["x"]}], "numbers"),
                     ([{"scene": "rect-0500", "backends": ["magic"]}], "magic")):
        cfg.scenes = bad
        with pytest.raises(InputValueError, match=msg):
            cfg.check()
    cfg.scenes, cfg.nearest_every = ["rect-0500"], 0
    with pytest.raises(InputValueError, match="nearest_every"):
        cfg.check()


def test_series_stats_against_hand_counts():
    from slr_ray.validation import series_stats

    d = np.array([1.0, 5.0, 12.0, 17.4, 17.5, 30.0, 40.0])
    s = np.array([0.95, 0.85, 0.91, 0.99, 0.5, 0.81, 0.79])
    st = series_stats(d, s)
    assert st["pairs"] == 7 and st["below_17.5m"]["pairs"] == 4  # 17.5 itself is not below
    assert st["below_17.5m"]["mean"] == pytest.approx((0.95 + 0.85 + 0.91 + 0.99) / 4)
    assert st["below_17.5m"]["min"] == 0.85 and st["below_17.5m"]["share_above_0.9"] == 0.75
    assert st["share_above_0.8"] == pytest.approx(5 / 7)
    assert st["bands"]["0-10"] == {"pairs": 2, "mean": pytest.approx(0.9), "precision": None}
    assert st["bands"]["17.5-25"]["pairs"] == 1 and st["bands"]["35-inf"]["pairs"] == 1
    assert sum(b["pairs"] for b in st["bands"].values()) == 7
    assert st["slope_per_10m"] == pytest.approx(np.polyfit(d, s, 1)[0] * 10)
    # precision: means over the rows that have it (old rows read back as nan)
    p = np.array([0.5, np.nan, 0.7, 0.9, 1.0, 0.6, 0.8])
    sp = series_stats(d, s, p)
    assert sp["precision"] == pytest.approx(np.nanmean(p))
    assert sp["below_17.5m"]["precision"] == pytest.approx((0.5 + 0.7 + 0.9) / 3)
    assert sp["bands"]["0-10"]["precision"] == 0.5
    assert {k: v for k, v in sp.items() if k not in ("precision", "bands", "below_17.5m")} == \
        {k: v for k, v in st.items() if k not in ("precision", "bands", "below_17.5m")}  # coverage untouched
    empty = series_stats([], [])
    assert empty["pairs"] == 0 and empty["mean"] is None and empty["slope_per_10m"] is None


def _fake_rows(path):
    """A results.csv laid out like validate-paper: similarity = 1 - distance/100
    (binning/center), +0.03 for nearest truth, -0.01 for embree."""
    from slr_ray.validation import COLUMNS

    rows = []
    for scene, n_rect, res_list in ([(f"distance-{k}", 1000, [0.0144]) for k in range(1, 6)]
                                    + [("ground-only", 0, [0.0144, 0.00576]), ("rect-2000", 2000, [0.0144, 0.00576])]):
        for res in res_list:
            for i in range(20):
                dist = 1.0 + 2 * i
                for b, t in (("binning", "center"), ("binning", "nearest"), ("embree", "center"),
                             ("embree", "nearest")):
                    if (t == "nearest" or b == "embree") and (i % 5 or res != 0.0144):
                        continue
                    sim = 1 - dist / 100 + (0.03 if t == "nearest" else 0) - (0.01 if b == "embree" else 0)
                    rows.append({"scene": scene, "n_rectangles": n_rect, "scene_seed": 0, "primary_resolution": res,
                                 "position": i, "x": dist, "y": 0, "z": 0, "distance_m": dist, "backend": b,
                                 "truth": t, "similarity": sim, "true_points": 10, "slr_points": 10, "seconds": 0})
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, COLUMNS)
        w.writeheader()
        w.writerows(rows)


def test_paper_report_groups_the_questions(tmp_path):
    from slr_ray.validation import paper_report, paper_report_markdown

    _fake_rows(tmp_path / "r.csv")
    rep = paper_report(tmp_path / "r.csv")
    q1 = rep["q1"]["0.0144"]
    assert q1["all"]["pairs"] == 100 and set(q1["by_scene"]) == {f"distance-{k}" for k in range(1, 6)}
    assert set(rep["q1"]) == {"0.0144"} and set(rep["occlusion"]) == {"0.0144", "0.00576"}
    assert set(rep["occlusion"]["0.00576"]) == {"ground-only", "rect-2000"}
    assert rep["occlusion"]["0.00576"]["rect-2000"]["pairs"] == 20
    assert q1["all"]["slope_per_10m"] == pytest.approx(-0.1)
    sem = rep["semantics"]["0.0144"]
    assert set(sem) == {"binning/center", "binning/nearest", "embree/center", "embree/nearest"}
    assert all(v["pairs"] == 7 * 4 for v in sem.values())  # the same pairs in every series
    assert sem["binning/nearest"]["mean"] - sem["binning/center"]["mean"] == pytest.approx(0.03)
    assert sem["embree/center"]["mean"] - sem["binning/center"]["mean"] == pytest.approx(-0.01)
    assert "0.00576" not in rep["semantics"]  # a single series there: nothing to compare
    # embree beside binning where both ran against pulse-centre truth (other truths present or not)
    cross = rep["cross_check"]["0.0144"]["embree"]
    assert set(cross) == {f"distance-{k}" for k in range(1, 6)} | {"ground-only", "rect-2000", "all"}
    assert cross["all"]["binning"]["pairs"] == cross["all"]["embree"]["pairs"] == 7 * 4
    assert cross["rect-2000"]["embree"]["mean"] - cross["rect-2000"]["binning"]["mean"] == pytest.approx(-0.01)
    assert "0.00576" not in rep["cross_check"]  # no embree rows there
    md = paper_report_markdown(rep)
    assert md.count("| distance-") == 5 + 10 and "0.00576° primaries" in md and "embree/nearest" in md
    assert "| all, embree | 28 |" in md
    save_figure(paper_figure(load_rows(tmp_path / "r.csv"), backend="embree"), tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 5000


def test_miss_breakdown_matches_the_shadow_of_a_wall():
    """Ground and one wall at x = 5; primary at the origin, secondary behind the
    wall. Missed points are hidden exactly when the segment from the origin
    crosses the wall (worked out by hand), and hidden + visible == missed."""
    import trimesh

    from slr_ray.meshscan import scan_mesh
    from slr_ray import simulate_scan
    from slr_ray.validation import miss_breakdown

    v = np.array([[-20, -20, -1], [20, -20, -1], [20, 20, -1], [-20, 20, -1],
                  [5, -2, -1], [5, 2, -1], [5, 2, 3], [5, -2, 3]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])

    class Scene:
        mesh = trimesh.Trimesh(v, f, process=False)

    labels = np.array([0, 0, 1, 1])
    primary = scan_mesh(Scene.mesh, [0, 0, 0], 0.05, mode="center", face_labels=labels)
    secondary = scan_mesh(Scene.mesh, [10, 0.5, 0], 0.5, mode="center", face_labels=labels)
    slr = primary.points[simulate_scan(primary.points, [10, 0.5, 0], 0.5).indices]
    out = miss_breakdown(Scene, secondary, slr)
    for part in [out["all"], out["ground"], out["objects"], *out["by_range"].values()]:
        assert part["hidden"] + part["visible"] == part["missed"] <= part["true"]
    assert out["all"]["true"] == len(secondary) and out["ground"]["true"] + out["objects"]["true"] == len(secondary)
    assert sum(p["true"] for p in out["by_range"].values()) == len(secondary)
    # with no SLR point every true point is missed; the hidden ones are the wall's shadow
    empty = miss_breakdown(Scene, secondary, np.empty((0, 3)))
    p = secondary.points
    with np.errstate(divide="ignore", invalid="ignore"):
        s = 5.0 / p[:, 0]
        y, z = s * p[:, 1], s * p[:, 2]
    behind = (p[:, 0] > 5 + 1e-6) & (secondary.labels == 0)
    shadow = behind & (np.abs(y) < 2) & (z > -1) & (z < 3)
    clear = ~behind | (np.abs(y) > 2.01)
    assert empty["all"]["missed"] == len(p) and empty["objects"]["hidden"] == 0  # a wall is seen from both sides
    assert empty["all"]["hidden"] >= shadow[clear | shadow].sum() > 100
    assert empty["all"]["hidden"] <= shadow.sum() + (~clear & ~shadow).sum()
    # the SLR scan misses the shadow (hidden) and little else
    assert out["all"]["hidden"] > 0.9 * empty["all"]["hidden"]
    assert out["all"]["visible"] < 0.1 * out["all"]["true"]
    # SLR = the true scan itself: nothing missed
    assert miss_breakdown(Scene, secondary, secondary.points)["all"]["missed"] == 0


def test_results_written_before_precision_resume_with_their_own_header(tmp_path):
    """A results.csv of an older version (no precision columns) is appended
    to with its own header, never a mixed one; read back, its rows have empty
    precision; a file with columns this version does not know is refused."""
    from slr_ray.validation.results import COLUMNS, ResultsWriter, read_rows

    old_cols = [c for c in COLUMNS if c not in ("precision", "fscore")]
    path = tmp_path / "results.csv"
    row = {c: "1" for c in COLUMNS} | {"scene": "s", "backend": "binning", "truth": "center", "position": "0"}
    path.write_text(",".join(old_cols) + "\n" + ",".join(row[c] for c in old_cols) + "\n")
    with ResultsWriter(path) as w:
        w.add(row | {"position": "1"})
    lines = path.read_text().splitlines()
    assert lines[0] == ",".join(old_cols) and all(len(x.split(",")) == len(old_cols) for x in lines)
    rows = read_rows(path)
    assert len(rows) == 2 and all(r["precision"] == "" for r in rows.values())
    path.write_text("scene,mystery\n")
    with pytest.raises(ValueError, match="mystery"):
        ResultsWriter(path)


def test_unknown_config_keys_are_named(tmp_path):
    bad = tmp_path / "v.toml"
    bad.write_text("[validate]\nscenes = ['rect-1000']\npositons = 3\n")
    with pytest.raises(ValueError, match="positons"):
        load_config(bad)
    bad.write_text("[validate]\nembree_options = {radius_scal = 2}\n")
    with pytest.raises(ValueError, match="radius_scal"):
        load_config(bad)


def test_spill_primary_maps_the_points_only_when_memory_is_short(tmp_path):
    from slr_ray.validation.runner import spill_primary

    pts = np.random.default_rng(0).normal(size=(1000, 3))
    assert spill_primary(pts, tmp_path, 67, available=1e12) is pts
    mapped = spill_primary(pts, tmp_path, 67, available=0.0)
    assert isinstance(mapped, np.memmap) and not mapped.flags.writeable
    np.testing.assert_array_equal(mapped, pts)
    assert list(tmp_path.iterdir()) == []  # unlinked once mapped: nothing left behind


def test_a_large_primary_is_mapped_even_when_it_fits(tmp_path, monkeypatch):
    """From MAPPED_PRIMARY_POINTS points on, the primary becomes file pages (the kernel
    may drop them; the embree build and binning scans release them) whatever the
    free memory: 24 B a point less of the run's own memory at its peak."""
    import slr_ray.validation.runner as runner

    pts = np.random.default_rng(0).normal(size=(1000, 3))
    monkeypatch.setattr(runner, "MAPPED_PRIMARY_POINTS", 1000)
    mapped = runner.spill_primary(pts, tmp_path, 67, available=1e12)
    assert isinstance(mapped, np.memmap)
    np.testing.assert_array_equal(mapped, pts)
    monkeypatch.setattr(runner, "MAPPED_PRIMARY_POINTS", 1001)
    assert runner.spill_primary(pts, tmp_path, 67, available=1e12) is pts


def test_a_run_whose_primary_does_not_fit_gives_the_same_rows(tmp_path, monkeypatch):
    """With too little memory for the primary and its discs, the points go to a
    memory-mapped file (a stage of its own in stages.csv) and every row is
    the same as in memory."""
    import slr_ray.validation.runner as runner

    cfg = load_config("quick")
    cfg.positions = 1
    cfg.truths = ["center"]
    in_memory = run_validation(cfg, tmp_path / "mem", progress=False)
    monkeypatch.setattr(runner, "available_memory", lambda: 0.0)
    mapped = run_validation(cfg, tmp_path / "mapped", progress=False)
    assert mapped["rows"] == in_memory["rows"] == len(cfg.backends) == 2
    drop = ("seconds",)
    a = [{k: v for k, v in r.items() if k not in drop} for r in _rows(tmp_path / "mem" / "results.csv")]
    b = [{k: v for k, v in r.items() if k not in drop} for r in _rows(tmp_path / "mapped" / "results.csv")]
    assert a == b
    stages = [r["stage"] for r in _rows(tmp_path / "mapped" / "stages.csv")]
    assert "primary to a mapped file" in stages
    assert "primary to a mapped file" not in [r["stage"] for r in _rows(tmp_path / "mem" / "stages.csv")]
    assert not [f for f in (tmp_path / "mapped").iterdir() if f.name.startswith(".primary")]


def test_a_scene_spec_edited_in_place_is_not_resumed(tmp_path):
    from slr_ray.validation.config import ValidationConfig
    from slr_ray.validation.results import check_settings

    spec = tmp_path / "scene.toml"
    spec.write_text("[scene]\nn_rectangles = 3\nseed = 1\n")
    cfg = ValidationConfig(name="x", scenes=[str(spec)], positions=1).check()
    (tmp_path / "out").mkdir()
    check_settings(tmp_path / "out", cfg)
    spec.write_text("[scene]\nn_rectangles = 3\nseed = 2\n")  # same name, same size: another scene
    with pytest.raises(InputValueError, match=r"scene spec .*\(content digest\)"):  # was: its rows mixed in
        check_settings(tmp_path / "out", cfg)


def test_a_validation_that_fails_before_its_first_row_leaves_nothing(tmp_path, capsys):
    spec = tmp_path / "scene.toml"
    spec.write_text("[scene]\nn_rectangles = 3\nno_such_argument = 1\n")  # found, read, refused inside the run
    config = tmp_path / "v.toml"
    config.write_text(f'[validate]\nname = "x"\nscenes = ["{spec}"]\npositions = 1\nbackends = ["binning"]\n')
    assert main(["validate", str(config), "-o", str(tmp_path / "out"), "--quiet"]) == 2
    assert "no_such_argument" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # was: results.csv, stages.csv and settings.json left behind


@pytest.mark.parametrize("content", ["{bad", "[1]"])
def test_a_settings_json_of_another_program_is_a_one_line_error(tmp_path, content):
    from slr_ray.errors import FormatError
    from slr_ray.validation.results import check_settings

    (tmp_path / "settings.json").write_text(content)  # was a JSONDecodeError / AttributeError traceback
    with pytest.raises(FormatError, match="not a settings.json of slr_ray"):
        check_settings(tmp_path, load_config("quick"))
    assert (tmp_path / "settings.json").read_text() == content


def test_reports_are_made_under_the_runs_lock(tmp_path):
    # validate's reports were written after the run released its directory lock: a second
    # run starting in that window could add rows the reports then mixed in
    from slr_ray.errors import OutputError
    from slr_ray.outputs import OutputPlan
    from slr_ray.validation.config import ValidationConfig

    spec = tmp_path / "scene.toml"
    spec.write_text("[scene]\nn_rectangles = 3\nseed = 1\n")
    # a coarse pulse-centre primary: the lock, not the scan, is under test (the paper's 0.0144 deg
    # dense primary took a minute)
    cfg = ValidationConfig(name="x", scenes=[str(spec)], positions=1, backends=["binning"],
                           primary_resolutions=[0.2], primary_semantics="center",
                           secondary_resolution=0.5, min_ground_points=50).check()
    seen = []

    def then(out, res):
        other = OutputPlan()
        other.directory(out)
        with pytest.raises(OutputError, match="in use by another slr-ray run"):
            with other:
                pass
        seen.append(res["new_rows"])

    res = run_validation(cfg, tmp_path / "out", progress=False, then=then)
    assert seen == [res["new_rows"]] and seen[0] > 0
    free = OutputPlan()  # released afterwards
    free.directory(tmp_path / "out")
    with free:
        pass


def test_a_validation_whose_plan_would_exhaust_memory_is_refused_first(tmp_path, capsys):
    # `validate --positions 1000000000` built a plan of 10**9 positions a primary for minutes
    assert main(["validate", "quick", "--positions", "1000000000", "-o", str(tmp_path / "v"), "--quiet"]) == 2
    assert "would need about" in capsys.readouterr().err
    assert not (tmp_path / "v").exists()
