"""A backend is one class and one registry line: a toy backend registered here runs
through scan, augment, effects and evaluate with no other change, and the rules on
what a backend can do (rays, streaming) read its capabilities, never its name."""

import dataclasses
import json
import math

import numpy as np
import pytest

from slr_ray import InputValueError
from slr_ray.augment import AugmentConfig, augment
from slr_ray.backends import BACKENDS, BackendEntry, BackendOptions, BinningOptions, Scanner, prepare, scanner_class
from slr_ray.backends.binning import BinningScanner
from slr_ray.effects import simulate
from slr_ray.evaluate import evaluate_pair, evaluation_table
from slr_ray.io import PointCloud, write_cloud
from slr_ray.sensors import BeamPattern


@dataclasses.dataclass(frozen=True)
class ToyOptions(BackendOptions):
    """Options of the toy backend (none)."""


class ToyScanner(Scanner):
    """The binning rule behind another name, and none of the capabilities."""

    backend = "toy"

    def __init__(self, points, options=None):
        super().__init__(points, options or ToyOptions())
        self._inner = BinningScanner(points, BinningOptions())

    def scan(self, origin, pattern):
        return dataclasses.replace(self._inner.scan(origin, pattern), backend=self.backend)


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setitem(BACKENDS, "toy", BackendEntry(ToyScanner, ToyOptions))


def cloud(n=4000, seed=0):
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(-10, 10, (n, 2)), rng.normal(0, 0.02, n)])
    boxes = np.column_stack([rng.uniform(-10, 10, (n // 4, 2)), rng.uniform(0.5, 3, n // 4)])
    return np.vstack([ground, boxes])


def test_capabilities_are_read_on_the_class_and_the_shipped_backends_declare_theirs():
    assert scanner_class("binning").streamable and not scanner_class("binning").casts_rays
    assert scanner_class("embree").casts_rays and not scanner_class("embree").streamable
    assert scanner_class("binning").primary_options([0, 0, 0], 0.1) == {}
    assert scanner_class("embree").primary_options([0, 0, 0], 0.1) == {"primary_origin": [0, 0, 0],
                                                                        "primary_resolution": 0.1}


def test_a_registered_toy_backend_scans_simulates_and_is_refused_by_capability(toy):
    pts = cloud()
    scanner = prepare(pts, "toy")
    ref = prepare(pts, "binning").scan([0, 0, 1.5], 1.0)
    sc = scanner.scan([0, 0, 1.5], 1.0)
    assert sc.backend == "toy"
    np.testing.assert_array_equal(sc.indices, ref.indices)
    es = simulate(scanner, [0, 0, 1.5], 1.0, {"range_noise": 0.01, "seed": 1})
    assert len(es) == len(ref) and es.info["backend"] == "toy"
    # the one rule of effects that need rays, and of streamed scans, by capability
    with pytest.raises(InputValueError, match="needs a backend that casts rays.*toy keeps one point"):
        simulate(scanner, [0, 0, 1.5], 1.0, {"divergence_mrad": 3.0})
    with pytest.raises(InputValueError, match="needs a backend that casts rays"):
        AugmentConfig(n=1, backend="toy", effects={"divergence_mrad": 3.0}).check()
    with pytest.raises(InputValueError, match="streamable backend .binning.*got backend toy"):
        AugmentConfig(n=1, backend="toy", chunk_size=1000).check()
    with pytest.raises(InputValueError, match="casts no rays"):
        scanner.cast(np.zeros(3), np.array([[1.0, 0, 0]]))


def test_a_registered_toy_backend_augments_as_binning_does(toy, tmp_path):
    pts = cloud() + [100.0, 200.0, 10.0]
    cls = np.r_[np.full(4000, 2, np.uint8), np.ones(1000, np.uint8)]
    src = tmp_path / "in.laz"
    write_cloud(src, PointCloud(pts, {"classification": cls}))
    out = {}
    for b in ("binning", "toy"):
        augment(src, tmp_path / b, AugmentConfig(n=2, backend=b, workers=1, min_ground_points=50, resolution=1.0),
                progress=False)
        out[b] = json.loads((tmp_path / b / "manifest.json").read_text())
    assert [s["points"] for s in out["toy"]["scans"]] == [s["points"] for s in out["binning"]["scans"]]


def test_a_registered_toy_backend_is_an_evaluate_method(toy):
    pattern = BeamPattern(np.linspace(2.0, -24.0, 8), 90, max_range=60.0, name="tiny")
    rows = []
    for beam in range(8):
        el = math.radians(pattern.elevation_deg[beam])
        az = (np.arange(90) + 0.5) * 2 * math.pi / 90
        rows.append(np.column_stack([20 * np.cos(el) * np.cos(az), 20 * np.cos(el) * np.sin(az),
                                     np.full(90, 20 * np.sin(el))]))
    a = np.vstack(rows)
    res = evaluate_pair(a, a, a_beams=None, b_beams=None, sensor=pattern, transform=np.eye(4),
                        methods=("binning", "toy"))
    binning, toy_row = evaluation_table(res)
    assert toy_row["method"] == "toy"
    def same(row):
        return repr({k: v for k, v in row.items() if k not in ("method", "label") and "seconds" not in k})
    assert same(toy_row) == same(binning)


class RayToy(Scanner):
    """A backend that casts rays (embree's discs behind another name), with only the protocol's
    scan_and_rays: the default one, from scan and cast."""

    backend = "raytoy"
    casts_rays = True

    def __init__(self, points, options=None):
        super().__init__(points, options or ToyOptions())
        self._inner = prepare(points, "embree", radius=0.05)

    def scan(self, origin, pattern):
        return self._inner.scan(origin, pattern)

    def cast(self, origin, directions, max_range=math.inf):
        return self._inner.cast(origin, directions, max_range)


def test_a_registered_ray_caster_is_compared_and_named_by_its_capability(monkeypatch):
    from slr_ray.compare import compare_backends, compared_backends

    monkeypatch.setitem(BACKENDS, "raytoy", BackendEntry(RayToy, ToyOptions))
    rng = np.random.default_rng(0)
    pts = np.vstack([np.column_stack([np.full(3000, 5.0), rng.uniform(-1, 1, (3000, 2))]),
                     np.column_stack([np.full(3000, 9.0), rng.uniform(-2, 2, (3000, 2))])])
    assert compared_backends() == ("binning", "embree")  # the first of each kind in the registry
    ref = compare_backends(pts, [0, 0, 0], 2.0, ray_options={"radius": 0.05})["positions"][0]
    toy = compare_backends(pts, [0, 0, 0], 2.0, backends=("binning", "raytoy"))["positions"][0]
    assert toy["raytoy"] == ref["embree"] and toy["see_through"] == ref["see_through"]
    assert [b["only_raytoy"] for b in toy["bands"]] == [b["only_embree"] for b in ref["bands"]]
    with pytest.raises(InputValueError, match="casts rays .casts_rays: embree, raytoy"):
        simulate(prepare(pts), [0, 0, 0], 2.0, {"divergence_mrad": 2.0})


def test_augment_shares_threads_only_with_backends_that_take_them(toy):
    """augment's workers share the cores through ``n_threads``: a backend whose options
    have no such field (the recipe asks for none) gets its options as given."""
    from slr_ray.augment import share_threads

    jobs = [{"options": {}}, {"options": {}}]
    assert share_threads(jobs, ToyOptions(), {}, 2) == jobs
    assert {j["options"]["n_threads"] for j in share_threads(jobs, BinningOptions(), {}, 2)} >= {1}
    assert share_threads(jobs, BinningOptions(), {"n_threads": 3}, 2) == jobs  # the user's count kept
