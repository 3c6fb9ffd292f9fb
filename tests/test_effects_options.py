"""Effects options (slr_ray.effects.options): unknown keys rejected, values checked, off by default."""

import pytest

from slr_ray import InputValueError
from slr_ray.effects import Effects
from slr_ray.pattern import ScanPattern


def test_unknown_keys_listed():
    with pytest.raises(InputValueError, match="known:"):
        Effects.from_dict({"range_nosie": 0.02})


@pytest.mark.parametrize("bad", [{"range_noise": -1}, {"returns": ("second",)}, {"beam_rings": 0},
                                 {"min_share": 2}, {"intensity": "invent"}, {"max_range_at": (50,)},
                                 {"ray_drop": "/no/such/model.json"}, {"motion": "yes"}])
def test_bad_values(bad):
    with pytest.raises(InputValueError):
        Effects.from_dict(bad)


def test_off_by_default_and_sensor_values_need_a_table():
    assert not Effects().any and Effects(range_noise=0.01).any
    with pytest.raises(InputValueError, match="table"):
        Effects(range_noise="sensor").resolve(ScanPattern(1.0))
    assert Effects.from_dict({"returns": "first", "divergence_mrad": 2.0}).returns == ("first",)
    # an option that tunes an effect that is off would be ignored: refused (issue #40)
    for tuning in ({"returns": "first"}, {"beam_rings": 5}, {"min_share": 0.2}, {"return_separation": 2.0},
                   {"range_noise_slope": 0.01}, {"reflectivity_scale": 255.0}):
        with pytest.raises(InputValueError, match="needs"):
            Effects.from_dict(tuning).check_needs()
    # sizes no sensor has
    for size in ({"divergence_mrad": 1e9}, {"range_noise": 1e300}, {"range_noise_slope": 1.0},
                 {"return_separation": 1e9, "divergence_mrad": 2.0}, {"min_range": 1e9},
                 {"max_range_at": (50.0, 10.0)}, {"max_range_at": (1e9, 0.1)}, {"reflectivity_scale": 1e300},
                 {"sweep_start_deg": 1e300}):
        with pytest.raises(InputValueError, match="at most|in \\[-360, 360\\]"):
            Effects.from_dict(size)


def test_scene_toml_says_which_effects_it_requires(tmp_path):
    from slr_ray.scenes import scene_effects

    spec = tmp_path / "noisy.toml"
    spec.write_text('[scene]\nn_rectangles = 3\n\n[effects]\nrange_noise = 0.02\nmin_range = 1.0\n'
                    'divergence_mrad = 2.0\nreturns = ["first", "last"]\n')
    eff = scene_effects(spec)
    assert eff.range_noise == 0.02 and eff.min_range == 1.0 and eff.returns == ("first", "last")
    assert scene_effects("rect-0500") is None
    spec.write_text("[scene]\nn_rectangles = 3\n\n[effects]\nnoise = 1\n")
    with pytest.raises(InputValueError, match="noisy.toml"):
        scene_effects(spec)


def test_an_effects_file_refuses_fields_beside_its_effects_table(tmp_path):
    f = tmp_path / "e.toml"
    f.write_text("range_noise = 0.5\nseed = 3\n[effects]\nrange_noise = 0.01\n")
    with pytest.raises(InputValueError, match="outside its \\[effects\\] table"):
        Effects.load(f)
    f.write_text("seed = 3\nname = 'scene'\n[effects]\nrange_noise = 0.01\n")  # a scene's own keys are fine
    assert Effects.load(f).range_noise == 0.01



def test_every_effect_option_belongs_to_one_stage_and_the_flags_come_from_the_stages(capsys):
    """A new effect is one Stage: its fields are its options, its flags generate the command line's."""
    import dataclasses

    from slr_ray.cli import main
    from slr_ray.effects.stages import EFFECT_FLAGS, STAGES

    owned = [name for stage in STAGES for name in stage.fields]
    assert sorted(owned) == sorted(f.name for f in dataclasses.fields(Effects) if f.name != "seed")
    assert len(owned) == len(set(owned))
    assert [s.name for s in STAGES] == ["divergence", "motion", "ray_drop", "range_limits", "range_noise",
                                        "intensity"]
    assert main(["scan", "--help"]) == 0
    text = capsys.readouterr().out
    assert all(flag in text for flag in EFFECT_FLAGS.values())
    assert EFFECT_FLAGS["range_noise"] == "--range-noise" and EFFECT_FLAGS["seed"] == "--effects-seed"
