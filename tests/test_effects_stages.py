"""An effect is one module of slr_ray/effects/stages/ (its Stage and options, importing
the package's base only) and one line in STAGES: a toy effect's module written and
registered here runs inside simulate, its options fields of the Effects its
registry makes, with its own flag; and divergence and motion are stages like the
others."""

import dataclasses
import importlib

import numpy as np
import pytest

import slr_ray
from slr_ray.effects import Effects, simulate
from slr_ray.effects import stages as registry
from slr_ray.effects.settings import effects_class

TOY_STAGE = '''
"""A toy effect, as a new one is written: one module of slr_ray/effects/stages/ that imports
its base, never the package (docs/architecture.md)."""

import dataclasses

from slr_ray.effects.settings import EffectOptions, positive
from slr_ray.effects.stages.base import Flag, Stage


@dataclasses.dataclass(frozen=True)
class RangeBiasOptions(EffectOptions):
    """A constant range bias.

    Attributes
    ----------
    range_bias : float
        Metres added to every range.
    """

    SIZE_BOUNDS = {"range_bias": 1.0}

    range_bias: float = 0.0

    def check(self):
        positive("range_bias", self.range_bias, allow_zero=True, bounds=self.SIZE_BOUNDS)


class RangeBias(Stage):
    """A constant bias added to every range (a toy: one file's worth)."""

    name = "range_bias"
    options = RangeBiasOptions
    flags = (Flag("range_bias", "--range-bias", "M", "a constant range bias (m)"),)

    def on(self, ctx):
        return bool(getattr(ctx.effects, "range_bias", 0.0))

    def apply(self, r, ctx):
        r.range = r.range + ctx.effects.range_bias
        return r
'''


def test_a_registered_toy_effect_runs_in_simulate(monkeypatch, tmp_path):
    (tmp_path / "toy_stage.py").write_text(TOY_STAGE)  # its module...
    monkeypatch.syspath_prepend(str(tmp_path))
    RangeBias = importlib.import_module("toy_stage").RangeBias
    pts = np.random.default_rng(0).uniform(-5, 5, (400, 3))
    scanner = slr_ray.prepare(pts)
    ideal = simulate(scanner, [0, 0, 0], 2.0)
    stages = (*registry.STAGES, RangeBias())  # ...and its line in STAGES (stages/__init__.py)...
    monkeypatch.setattr(registry, "STAGES", stages)
    ToyEffects = effects_class(stages)  # ...and the Effects it makes (registry.Effects, at import)
    assert RangeBias.fields == ("range_bias",) and "range_bias" in {f.name for f in dataclasses.fields(ToyEffects)}
    assert ToyEffects.from_dict({"range_bias": 0.5, "range_noise": 0.01}).range_bias == 0.5  # a scene table
    with pytest.raises(slr_ray.InputValueError, match="range_bias must be at most 1"):
        ToyEffects(range_bias=2.0)  # its checks and bounds are its own
    assert not ToyEffects().any and ToyEffects(range_bias=0.5).any
    es = simulate(scanner, [0, 0, 0], 2.0, ToyEffects(range_bias=0.5))
    assert np.array_equal(es.indices, ideal.indices)
    assert np.allclose(es.ranges, ideal.ranges + 0.5)
    # the points land at the new ranges (not the ideal scan's points kept because the count is the same)
    assert np.allclose(np.linalg.norm(es.points, axis=1), ideal.ranges + 0.5)
    assert "range_bias" in es.info["seconds"] and es.info["effects"]["range_bias"] == 0.5
    # off, the toy leaves the scan as it was
    assert np.array_equal(simulate(scanner, [0, 0, 0], 2.0, ToyEffects()).ranges, ideal.ranges)


def test_every_stage_is_a_module_of_its_own_importing_the_base_not_the_package():
    import ast
    from pathlib import Path

    modules = [type(stage).__module__ for stage in registry.STAGES]
    assert len(set(modules)) == len(modules) and all(m.startswith("slr_ray.effects.stages.") for m in modules)
    for mod in modules:
        tree = ast.parse(Path(importlib.import_module(mod).__file__).read_text())
        froms = {(n.level, n.module) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert (1, None) not in froms and (0, "slr_ray.effects.stages") not in froms, mod  # no cycle


def test_divergence_and_motion_are_stages_that_plan_the_rays():
    by_name = {s.name: s for s in registry.STAGES}
    div, mot = by_name["divergence"], by_name["motion"]
    assert "divergence_mrad" in div.fields and "motion_sectors" in mot.fields
    assert registry.EFFECT_FLAGS["divergence_mrad"] == "--divergence-mrad"
    pts = np.random.default_rng(1).uniform(-5, 5, (300, 3))
    scanner = slr_ray.prepare(pts)
    ctx = registry.Context(effects=Effects(motion=True).resolve(None), scanner=scanner,
                           pattern=slr_ray.ScanPattern(10.0), origin=np.zeros(3), intensity=None, normals=None,
                           primary_origin=None, rng={}, info={}, poses=np.stack([np.eye(4), np.eye(4)]))
    assert mot.on(ctx) and not div.on(ctx)
    plan = mot.rays(registry.Rays(), ctx)
    assert not plan.ideal and plan.n_sectors == registry.SCAN_SECTORS  # binning casts no rays: whole sectors
    with pytest.raises(slr_ray.InputValueError, match="casts rays .casts_rays: .*binning keeps one point"):
        div.rays(registry.Rays(), dataclasses.replace(ctx, effects=Effects(divergence_mrad=2.0)))


def test_effects_are_resolved_once():
    vls = slr_ray.sensor("velodyne_vls128")
    eff = Effects(divergence_mrad="sensor").resolve(vls)
    assert eff.resolved and isinstance(eff.divergence_mrad, float)
    assert eff.resolve(vls) is eff and eff.with_seed(3).resolved and eff.with_seed(3).seed == 3
    assert not Effects(divergence_mrad="sensor").resolved
    assert not dataclasses.replace(eff, divergence_mrad="sensor").resolved  # a copy changed is resolved again
    with pytest.raises(slr_ray.InputValueError, match="returns needs divergence_mrad"):
        Effects(returns=("last",)).resolve(vls)  # resolving checks the options that need another
