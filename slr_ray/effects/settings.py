"""What every effect's options share: the base of each stage's options
(:class:`EffectOptions`: its fields, their checks, bounds and the options they
need) and of :class:`~slr_ray.effects.Effects`, the one object of all of them
(:class:`EffectsBase`: read from a mapping or a file, checked, resolved).

:class:`~slr_ray.effects.Effects` itself is made from the stages
(:data:`~slr_ray.effects.stages.STAGES`): the fields of every stage's options
and ``seed``, so that a new effect's options are its own module's.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from ..errors import InputValueError, dataclass_from_mapping

__all__ = ["EffectOptions", "EffectsBase", "SeedOptions", "RETURN_KINDS", "INTENSITY_MODES", "MOTION_FRAMES",
           "positive", "integral", "merged", "effects_class"]

#: Which returns of a pulse a multiple-return scan reports.
RETURN_KINDS = ("first", "last", "strongest", "all")
#: What happens to the primary point's intensity.
INTENSITY_MODES = ("carry", "correct")
#: The frame a scan with motion is written in: the end pose's (compensated), or each column's (raw).
MOTION_FRAMES = ("sensor-end", "firing")


def positive(name, v, allow_zero=False, bounds=None):
    """``float(v)``, refused unless a finite number > 0 (>= 0 with ``allow_zero``) and at most
    ``bounds[name]`` (what a sensor can be)."""
    if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            and (v >= 0 if allow_zero else v > 0)):
        raise InputValueError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {v!r}")
    top = (bounds or {}).get(name)
    if top is not None and v > top:
        raise InputValueError(f"{name} must be at most {top:g} (what a sensor can be; docs/effects.md), got {v!r}")
    return float(v)


def integral(v, lo=None, hi=None):
    """Whether ``v`` is a whole number (an int, or a float with no fraction; not a bool, not a string) in [lo, hi]."""
    if isinstance(v, bool) or not isinstance(v, (numbers.Integral, float)):
        return False
    if isinstance(v, float) and not v.is_integer():  # also refuses nan and inf
        return False
    return (lo is None or v >= lo) and (hi is None or v <= hi)


@dataclass(frozen=True)
class EffectOptions:
    """Base of one effect's options: a frozen dataclass of its fields (each off or
    neutral by default), described in its docstring's Attributes, checked by
    :meth:`check`, with the class's bounds and needs below."""

    #: the largest value of each effect size: what a sensor can be (docs/effects.md says why each)
    SIZE_BOUNDS: ClassVar[dict] = {}
    #: options that tune another effect -> the option that turns it on (set while it is off: refused)
    NEEDS: ClassVar[dict] = {}
    #: fields that may be 'sensor' -> the key of a sensor's table they are read from
    SENSOR: ClassVar[dict] = {}

    def check(self) -> None:
        """Refuse a bad value (:class:`~slr_ray.errors.InputValueError` naming the field); a
        value may be set to its normal form with ``object.__setattr__`` (frozen)."""


@dataclass(frozen=True)
class SeedOptions(EffectOptions):
    """The seed every stage draws from.

    Attributes
    ----------
    seed : int
        Seed of every random draw (noise, drop); the same seed, the same scan.
    """

    seed: int = 0

    def check(self):
        if not integral(self.seed, 0):  # numpy's generators take no negative seed
            raise InputValueError(f"seed must be an integer >= 0, got {self.seed!r}")


def _classes(cls) -> list:
    """The effect options classes ``cls`` is made of, in field order."""
    return [k for k in reversed(cls.__mro__) if issubclass(k, EffectOptions) and k is not EffectOptions
            and not issubclass(k, EffectsBase)]


def merged(cls, attribute: str) -> dict:
    """One class attribute (``SIZE_BOUNDS``, ``NEEDS``, ``SENSOR``) of every options class of ``cls``."""
    out = {}
    for k in _classes(cls):
        out.update(k.__dict__.get(attribute, {}))
    return out


@dataclass(frozen=True)
class EffectsBase:
    """The methods of :class:`~slr_ray.effects.Effects` (its fields come from the stages)."""

    def __post_init__(self):
        for k in _classes(type(self)):
            if "check" in k.__dict__:
                k.__dict__["check"](self)

    @classmethod
    def from_dict(cls, options: dict | None = None, *, relative_to=None, **more):
        """Effects from a mapping (a scene's ``[effects]`` table) and keywords.

        ``relative_to``: the directory a relative ``ray_drop`` path of
        ``options`` is read from (the file's that holds them; default the
        working directory).

        Raises
        ------
        InputValueError
            naming unknown keys and listing the known ones.
        """
        options = dict(options or {})
        drop = options.get("ray_drop")
        if relative_to is not None and isinstance(drop, str) and not Path(drop).is_absolute():
            options["ray_drop"] = str(Path(relative_to) / drop)
        return dataclass_from_mapping(cls, options, more, "effect option(s)")

    @classmethod
    def load(cls, path):
        """Effects from a TOML or JSON file (by its extension) of :class:`Effects`
        fields, at the top level or in an ``[effects]`` table (a scene file's);
        a relative ``ray_drop`` path is read from the file's directory.

        Raises
        ------
        InputValueError
            a missing or unreadable file, or bad fields; the message names the file.
        """
        path = Path(path)
        if not path.is_file():
            raise InputValueError(f"no effects file {str(path)!r}")
        suffix = path.suffix.lower()
        if suffix not in (".toml", ".json"):
            raise InputValueError(f"{path}: an effects file is .toml or .json, got {suffix!r}")
        try:
            data = tomllib.loads(path.read_text()) if suffix == ".toml" else json.loads(path.read_text())
        except (tomllib.TOMLDecodeError, ValueError) as exc:
            raise InputValueError(f"{path}: not valid {suffix[1:].upper()}: {exc}") from None
        if not isinstance(data, dict):
            raise InputValueError(f"{path}: expected a table of effect options, got {type(data).__name__}")
        table = data["effects"] if isinstance(data.get("effects"), dict) else data
        if table is not data:  # fields beside the table would be ignored: say so instead
            stray = sorted(set(data) & {f.name for f in dataclasses.fields(cls)} - {"seed"})
            if stray:
                raise InputValueError(f"{path}: effect option(s) {stray} lie outside its [effects] table, "
                                      "where they would be ignored: move them into it")
        try:
            return cls.from_dict(table, relative_to=path.parent)
        except InputValueError as exc:
            raise InputValueError(f"{path}: {exc}") from None

    def check_needs(self):
        """``self``, refused when an option that tunes another effect (``NEEDS``) is set away from
        its default while that effect is off: it would be ignored. Checked where the effects are used
        (:func:`~slr_ray.effects.simulate`, the command line), not by each part: a file may set
        ``returns`` for a ``--divergence-mrad`` given beside it."""
        defaults = {f.name: f.default for f in dataclasses.fields(self)}
        for name, on in merged(type(self), "NEEDS").items():
            if getattr(self, name) != defaults[name] and not getattr(self, on):
                raise InputValueError(f"{name} needs {on} (without it, {name} would be ignored)")
        return self

    @property
    def any(self) -> bool:
        """Whether any effect is on."""
        return self != type(self)(seed=self.seed)

    def to_dict(self) -> dict:
        """Plain-JSON description."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = v.to_dict() if hasattr(v, "to_dict") else list(v) if isinstance(v, tuple) else v
        return out

    @property
    def resolved(self) -> bool:
        """Whether these are the settings a scan runs with: made by :meth:`resolve`
        (checked, no 'sensor' value left), which :func:`~slr_ray.effects.simulate`
        then takes as they are instead of resolving them again."""
        return getattr(self, "_resolved", False)

    def with_seed(self, seed: int):
        """A copy with another ``seed`` (one scan's own stream), still :attr:`resolved` if this is."""
        out = dataclasses.replace(self, seed=seed)
        if self.resolved:
            object.__setattr__(out, "_resolved", True)
        return out

    def resolve(self, pattern):
        """The settings a scan of ``pattern`` runs with, done once: :meth:`check_needs`, then a
        copy with every 'sensor' value read from ``pattern``'s table, marked :attr:`resolved`.

        Raises
        ------
        InputValueError
            an option that needs another, off; or a 'sensor' value when the pattern is not a
            sensor's or its table lacks the field.
        """
        if self.resolved:
            return self
        self.check_needs()
        meta = getattr(pattern, "meta", None)
        changes = {}
        for name, key in merged(type(self), "SENSOR").items():
            if getattr(self, name) != "sensor":
                continue
            if meta is None or meta.get(key) is None:
                who = getattr(pattern, "name", None) or type(pattern).__name__
                raise InputValueError(f"{name}='sensor': the pattern {who!r} has no {key!r} in its table; "
                                      f"give {name} as a number")
            v = meta[key]
            changes[name] = tuple(v[0]) if name == "max_range_at" else float(v)
        out = dataclasses.replace(self, **changes)
        object.__setattr__(out, "_resolved", True)  # not a field: equality and to_dict are the same
        return out


def effects_class(stages, name: str = "Effects", module: str | None = None) -> type:
    """The Effects class of ``stages``: a frozen dataclass of every stage's options fields
    (``stage.options``, in the stages' order) and ``seed``, with :class:`EffectsBase`'s methods."""
    classes = [s.options for s in stages if getattr(s, "options", None) is not None]
    bases = (EffectsBase, SeedOptions, *reversed(classes))  # dataclass fields follow the reversed MRO
    namespace = {"__doc__": effects_doc([*classes, SeedOptions])}
    if module is not None:
        namespace["__module__"] = module
    return dataclasses.make_dataclass(name, [], bases=bases, frozen=True, namespace=namespace)


def effects_doc(classes) -> str:
    """The docstring of an Effects class made of ``classes``: each one's Attributes, in order."""
    parts = []
    for k in classes:
        doc = k.__dict__.get("__doc__") or ""
        text = doc.split("Attributes\n    ----------\n", 1)
        if len(text) == 2:
            parts.append(text[1].rstrip())
    return ("Sensor effects of a simulated scan (:mod:`slr_ray.effects.options`); all off by default: the\n"
            "options of every stage of :data:`~slr_ray.effects.stages.STAGES`, and ``seed``.\n\n"
            "    Attributes\n    ----------\n" + "\n".join(parts) + "\n    ")
