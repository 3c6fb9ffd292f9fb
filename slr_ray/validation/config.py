"""What a validation runs: :class:`ValidationConfig`, read from a ``[validate]`` TOML table."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

from .. import paper
from ..backends import BACKENDS, Backend, options_for, scanner_class
from ..errors import InputValueError, refuse_memory
from ..meshscan import MESH_MODES
from ..scenes import SCENES_DIR, load_toml_spec, scene_effects

__all__ = ["ValidationConfig", "load_config", "TRUTHS", "PRIMARY_SEMANTICS"]

#: Truth semantics of the secondary scans (:func:`~slr_ray.meshscan.scan_mesh` modes).
TRUTHS = ("center", "nearest")
#: How the primary scans are made (:func:`~slr_ray.meshscan.scan_mesh` modes).
PRIMARY_SEMANTICS = ("dense", "center")
assert set(TRUTHS) | set(PRIMARY_SEMANTICS) <= set(MESH_MODES)


def _backends() -> tuple:
    """The registered backends' names (a backend registered later is one too)."""
    return tuple(str(b) for b in BACKENDS)


@dataclass
class ValidationConfig:
    """What :func:`~slr_ray.validation.run_validation` runs (a ``[validate]`` table in TOML).

    ``scenes``: scene specs (shipped names or paths), each either a string or
    a table ``{scene = "rect-1000", primary_resolutions = [0.0144, 0.00576],
    backends = ["binning"]}`` overriding ``primary_resolutions`` and/or
    ``backends`` for that scene.
    ``primary_resolutions``: one or more (the paper: 0.0144 and 0.00576). The
    secondary positions are drawn on the *first* primary of a scene and the
    true scans are shared by all its primaries, as in the paper (question 3
    reuses question 2's positions and true scans).
    ``positions_resolution``: the primary the positions are drawn on
    (default: a scene's first; scanned for that alone if it is not among the
    scene's primaries).
    ``primary_semantics``: 'dense' (the paper's 5 mm grid) or 'center'.
    ``nearest_every`` / ``embree_every``: the nearest-in-pulse truth and the
    embree backend (both dearer than the rest) only at positions 0, k, 2k,
    ... (1 = every position). ``embree_primary_resolutions``: the primaries
    embree is run on (default: all).
    ``embree_options``: :class:`~slr_ray.backends.EmbreeOptions` fields.
    """

    name: str = "validation"
    scenes: list = field(default_factory=lambda: ["rect-1000"])
    primary_resolutions: list = field(default_factory=lambda: [paper.PRIMARY_RESOLUTION])
    primary_semantics: str = "dense"
    dense_spacing: float = paper.DENSE_SPACING
    positions: int = 100
    seed: int = 0
    secondary_resolution: float = paper.SECONDARY_RESOLUTION
    backends: list = field(default_factory=lambda: ["binning"])
    truths: list = field(default_factory=lambda: ["center"])
    nearest_supersample: int = 3
    nearest_every: int = 1
    embree_every: int = 1
    embree_primary_resolutions: list | None = None
    positions_resolution: float | None = None
    min_ground_points: int = paper.MIN_GROUND_POINTS
    threshold: float = paper.SIMILARITY_THRESHOLD
    embree_options: dict = field(default_factory=dict)

    def check(self) -> "ValidationConfig":
        """Raise :class:`~slr_ray.errors.InputValueError` on any bad field; return self."""
        if self.primary_semantics not in PRIMARY_SEMANTICS:
            raise InputValueError(f"primary_semantics must be one of {PRIMARY_SEMANTICS}, "
                                  f"got {self.primary_semantics!r}")
        for b in self.backends:
            if b not in _backends():
                raise InputValueError(f"unknown backend {b!r} in config; choose from {_backends()}")
        for t in self.truths:
            if t not in TRUTHS:
                raise InputValueError(f"unknown truth semantics {t!r} in config; choose from {TRUTHS}")
        if self.positions < 1 or not self.threshold > 0:
            raise InputValueError("positions must be >= 1 and threshold > 0")
        if self.nearest_every < 1 or self.embree_every < 1:
            raise InputValueError("nearest_every and embree_every must be >= 1")
        # unknown keys named here, not after the primaries; the runner gives each backend what it
        # declares of the primary (its primary_options: embree's origin and resolution), so options
        # that need them are valid
        for b, given in self.backend_options.items():
            options_for(b, {**scanner_class(b).primary_options([0.0, 0.0, 0.0], self.primary_resolutions[0]),
                            **given})
        for entry in self.scenes:
            spec, res = self.scene_entry(entry)
            for b in self.scene_backends(entry):
                if b not in _backends():
                    raise InputValueError(f"unknown backend {b!r} for scene {spec!r}; choose from {_backends()}")
            if not res or any(not (float(r) > 0) for r in res):
                raise InputValueError(f"scene {spec!r}: primary_resolutions must be positive numbers")
            if _requires_effects(spec):
                raise InputValueError(f"scene {spec!r} requires sensor effects (its [effects] table): a validation "
                                      "compares ideal scans, so use a scene without [effects]")
        rows = self.positions * sum(len(self.scene_entry(e)[1]) * len(self.scene_backends(e)) for e in self.scenes)
        # the plan of a run lists every (scene, primary, position) and keeps a row of each pair: about 1 KB a row
        refuse_memory(1024.0 * rows, f"a validation of {self.positions:,} positions ({rows:,} rows, about 1 KB a "
                      "row: its plan and results)", "fewer positions")
        return self

    @property
    def backend_options(self) -> dict:
        """``{backend: options from this config}`` (``embree_options``), beside what each is told of the
        primary (:meth:`~slr_ray.backends.Scanner.primary_options`): the one place the config's keys
        meet backends' names."""
        return {Backend.EMBREE: self.embree_options}

    def scene_entry(self, entry) -> tuple[str, list]:
        """``(spec, primary resolutions)`` of one ``scenes`` entry."""
        if isinstance(entry, str):
            spec, res = entry, self.primary_resolutions
        elif isinstance(entry, dict) and isinstance(entry.get("scene"), str) \
                and set(entry) <= {"scene", "primary_resolutions", "backends"}:
            spec, res = entry["scene"], entry.get("primary_resolutions", self.primary_resolutions)
        else:
            raise InputValueError("a scenes entry is a name or {scene = NAME, primary_resolutions = [...], "
                                  f"backends = [...]}}, got {entry!r}")
        try:
            return spec, [float(r) for r in res]
        except (TypeError, ValueError):
            raise InputValueError(f"scene {spec!r}: primary_resolutions must be numbers, got {res!r}") from None

    def scene_backends(self, entry) -> list:
        """The backends run on one ``scenes`` entry."""
        return list(entry.get("backends", self.backends)) if isinstance(entry, dict) else list(self.backends)

    def wanted(self, resolution, position: int, backends=None):
        """The (backend, truth) rows wanted at one primary and position."""
        emb_res = self.embree_primary_resolutions
        return [(b, t) for b in (self.backends if backends is None else backends) for t in self.truths
                if (t != "nearest" or position % self.nearest_every == 0)
                and (not scanner_class(b).costly_prepare or (position % self.embree_every == 0
                                       and (emb_res is None or float(resolution) in map(float, emb_res))))]


def _requires_effects(spec) -> bool:
    """Whether a scene's file has an ``[effects]`` table with an effect on (a
    spec with no file is reported where the scene is built)."""
    path = Path(spec) if Path(spec).suffix else SCENES_DIR / f"{spec}.toml"
    if not path.is_file():
        return False
    effects = scene_effects(spec)
    return effects is not None and effects.any


def load_config(spec) -> ValidationConfig:
    """A config by path or by shipped name (``validate-<name>.toml``)."""
    data, path = load_toml_spec(spec, "validate", "validation config", prefix="validate-")
    table = data["validate"]
    unknown = sorted(set(table) - {f.name for f in fields(ValidationConfig)})
    if unknown:
        raise InputValueError(f"{path}: unknown key(s) {unknown} in [validate]")
    return ValidationConfig(**table).check()
