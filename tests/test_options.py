"""Long calls take an options object or their old keywords (issue #39): the
same call either way, an unknown name refused with the known ones listed."""

import dataclasses
import inspect

import numpy as np
import pytest

import slr_ray
from slr_ray.compare import CompareOptions, compare_backends
from slr_ray.demo import DemoOptions, run_demo
from slr_ray.distances import StudyOptions, distance_study
from slr_ray.errors import InputTypeError, InputValueError
from slr_ray.evaluate import EvaluateOptions, evaluate_pair
from slr_ray.meshscan import MeshOptions, scan_mesh
from slr_ray.options import Options
from slr_ray.positions import CellOptions, PositionOptions, candidate_cells, select_positions
from slr_ray.sequence.convert import ConvertOptions, convert_sequence
from slr_ray.sequence.holdout import HoldoutOptions, evaluate_holdout

#: each function's keywords before its options object (issue #39), and the class that now holds them
OLD_KEYWORDS = {
    select_positions: (PositionOptions, "seed cell_size min_ground_points ground_count_radius ground_height_radius "
                                        "scanner_height profile allow_fewer cells return_cells progress"),
    candidate_cells: (CellOptions, "cell_size min_ground_points ground_count_radius profile scanner_height "
                                   "ground_height_radius progress"),
    evaluate_pair: (EvaluateOptions, "a_beams b_beams sensor methods transform seen_threshold thresholds "
                                     "min_fitness max_rmse progress"),
    distance_study: (StudyOptions, "origin heights positions seed resolution max_range scanner_height "
                                   "min_ground_points ground progress"),
    compare_backends: (CompareOptions, "tolerance bands progress"),
    run_demo: (DemoOptions, "n_rectangles n_positions seed quick primary_resolution backends force progress"),
    scan_mesh: (MeshOptions, "mode supersample spacing face_labels rays_per_batch progress band_pulses"),
    convert_sequence: (ConvertOptions, "estimator half radius offset poses drop_moving fmt fpa_gap workers block "
                                       "progress inputs"),
    evaluate_holdout: (HoldoutOptions, "sensor methods half radius drop_moving thresholds seen_threshold fpa_gap cache"),
}


@pytest.mark.parametrize("fn", list(OLD_KEYWORDS), ids=lambda f: f.__name__)
def test_every_old_keyword_is_still_a_parameter_or_an_option(fn):
    cls, old = OLD_KEYWORDS[fn]
    params = inspect.signature(fn).parameters
    fields = {f.name for f in dataclasses.fields(cls)}
    assert issubclass(cls, Options) and cls.__dataclass_params__.frozen
    assert "options" in params and any(p.kind is p.VAR_KEYWORD for p in params.values())
    assert [k for k in old.split() if k not in params and k not in fields] == []
    assert set(cls.describe()) == fields  # every field described in the docstring's Attributes


def test_holdout_options_take_gap_its_old_name_with_a_deprecation():
    with pytest.warns(DeprecationWarning, match="fpa_gap"):
        assert HoldoutOptions.of(gap=0.2).fpa_gap == 0.2
    with pytest.warns(DeprecationWarning, match="fpa_gap"):
        assert HoldoutOptions.of({"gap": 0.3}).fpa_gap == 0.3


def test_options_of_merges_keywords_and_refuses_unknown_names():
    base = PositionOptions(min_ground_points=50)
    assert PositionOptions.of(base) is base
    assert PositionOptions.of(base, cell_size=4.0) == PositionOptions(min_ground_points=50, cell_size=4.0)
    assert PositionOptions.of({"allow_fewer": True}).allow_fewer
    assert type(CellOptions.of(base, cell_size=3.0)) is PositionOptions  # a subclass stays one
    assert PositionOptions.of(CellOptions(cell_size=3.0), allow_fewer=True) == PositionOptions(cell_size=3.0,
                                                                                              allow_fewer=True)
    with pytest.raises(InputTypeError, match="CellOptions"):
        CellOptions.of(EvaluateOptions())  # another call's options
    with pytest.raises(InputValueError, match="min_ground_point.*known.*min_ground_points"):
        PositionOptions.of(None, min_ground_point=1)
    with pytest.raises(InputTypeError, match="PositionOptions.*got float.*keywords"):
        PositionOptions.of(2.0)  # an old positional cell_size lands here: said, not misread, the way out named


def test_an_options_object_and_the_old_keywords_are_the_same_call():
    pts = np.random.default_rng(0).uniform(0, 20, (2000, 3))
    pts[:, 2] = 0.0
    g = np.ones(len(pts), bool)
    a = select_positions(pts, g, 3, 0, PositionOptions(min_ground_points=50))
    assert np.array_equal(a, select_positions(pts, g, 3, seed=0, min_ground_points=50))
    assert np.array_equal(a, slr_ray.select_positions(pts, g, 3, 0, {"min_ground_points": 50}))


@pytest.mark.parametrize("cls", [v[0] for v in OLD_KEYWORDS.values()], ids=lambda c: c.__name__)
def test_options_travel_pickled_and_round_trip_through_json(cls):
    import json
    import pickle

    o = cls()
    assert pickle.loads(pickle.dumps(o)) == o and hash(pickle.loads(pickle.dumps(o))) == hash(o)
    assert dataclasses.replace(o) == o and repr(o).startswith(cls.__name__)
    back = cls.from_dict(json.loads(json.dumps(o.to_dict())))  # a config file's lists: the same options
    assert back == o and hash(back) == hash(o)


def test_options_holding_a_profile_compare_and_hash_by_value():
    import pickle

    from slr_ray.positions import default_profile

    o = PositionOptions(profile=default_profile())
    back = pickle.loads(pickle.dumps(o))  # as a worker process gets it
    assert back == o and hash(back) == hash(o)  # was: ValueError (the profile's counts compared as arrays)
    assert PositionOptions(profile=dataclasses.replace(o.profile, counts=o.profile.counts + 1)) != o


def test_the_holdout_entry_points_default_to_the_same_sensor():
    """#46: ``evaluate_sequence`` defaults to ``"auto"``; ``HoldoutOptions`` (so ``evaluate_holdout``) and
    ``simulate_holdout`` defaulted to the HDL-64E's table: a frame scored one way, simulated another."""
    import inspect

    from slr_ray.sequence.holdout import evaluate_sequence, simulate_holdout
    from slr_ray.sequence.terrestrial import AUTO

    defaults = {inspect.signature(f).parameters["sensor"].default for f in (evaluate_sequence, simulate_holdout)}
    assert defaults == {HoldoutOptions().sensor} == {HoldoutOptions.of().sensor} == {AUTO}
    assert HoldoutOptions(sensor="velodyne_hdl64e_s2").sensor == "velodyne_hdl64e_s2"  # naming it still works
