"""The sequence methods, one module a method, and their registry :data:`REGISTRY`.

A new method is one module here (a :class:`~.base.SequenceMethod` subclass with its name, label,
capabilities and options class, and ``METHOD``, an instance) and its entry in the tuple of
:data:`REGISTRY` below (docs/architecture.md, "Extension recipes"). ``sequence evaluate``
(:func:`~slr_ray.sequence.holdout.evaluate_holdout`, its ``--methods``), ``sequence convert``
(:func:`~slr_ray.sequence.convert.convert_sequence`, its ``--estimator``), the tables' labels and
the flags of the methods' options read the registry; no other module compares a method's name.
"""

from __future__ import annotations

from collections.abc import Mapping

from ...errors import InputValueError
from . import adjacent, embree_knn, embree_rays, embree_sources, fpa, nearest, rays, tsdf, zbuffer
from .adjacent import adjacent_frame
from .base import FirstPeakOptions, HeldOut, MethodOptions, NoOptions, RaysOptions, SequenceMethod, TargetFrame
from .rays import holdout_ray_model

__all__ = ["REGISTRY", "LABELS", "SequenceMethod", "MethodOptions", "NoOptions", "FirstPeakOptions", "RaysOptions", "HeldOut",
           "TargetFrame", "method", "methods_with", "check_methods", "method_options", "options_classes", "option_keys",
           "adjacent_frame", "holdout_ray_model"]

#: name -> method, in the order of the tables' rows
REGISTRY: dict[str, SequenceMethod] = {m.name: m for m in (zbuffer.METHOD, adjacent.METHOD, nearest.METHOD,
                                                           fpa.METHOD, rays.METHOD, embree_knn.METHOD,
                                                           embree_sources.METHOD, tsdf.METHOD,
                                                           embree_rays.METHOD)}


class _Labels(Mapping):
    """name -> the tables' label, read from the registry (a method registered later has its own)."""

    def __getitem__(self, name):
        return REGISTRY[name].label

    def __iter__(self):
        return iter(REGISTRY)

    def __len__(self):
        return len(REGISTRY)


#: name -> label in the tables
LABELS = _Labels()


def methods_with(capability: str) -> list[str]:
    """The registered methods that have ``capability`` (``"holdout"``, ``"convert"``, ``"default"``...)."""
    return [name for name, m in REGISTRY.items() if getattr(m, capability)]


def method(name: str, capability: str | None = None, what: str = "method") -> SequenceMethod:
    """The registered method ``name``, refused (naming the choices) when unknown or, with
    ``capability``, without it."""
    choices = methods_with(capability) if capability else list(REGISTRY)
    if name not in choices:
        raise InputValueError(f"unknown {what} {name!r}; choose from {choices}")
    return REGISTRY[name]


def check_methods(names, capability: str, what: str = "method(s)") -> tuple[str, ...]:
    """``names`` checked: at least one, each registered with ``capability``, none twice."""
    names = (names,) if isinstance(names, str) else tuple(names)
    choices = methods_with(capability)
    if not names:
        raise InputValueError(f"{what}: none given; choose from {choices}")
    unknown = [m for m in names if m not in choices]
    if unknown:
        raise InputValueError(f"unknown {what} {unknown}; choose from {choices}")
    twice = sorted({m for m in names if names.count(m) > 1})
    if twice:
        raise InputValueError(f"{what}: {', '.join(twice)} given twice (each method is one row)")
    return names


def options_classes() -> dict:
    """Each options class of the registered methods (once, in the registry's order) and the methods
    that take it."""
    out: dict = {}
    for name, m in REGISTRY.items():
        out.setdefault(m.options, []).append(name)
    return out


def option_keys() -> dict:
    """Every flat key of the registered methods' options (a key two classes share once): ``{key: (options
    class, field, the methods that take it)}``, in the registry's order."""
    out: dict = {}
    for cls, names in options_classes().items():
        for key, field in cls.keys().items():
            if key in out:
                out[key][2].extend(names)
            else:
                out[key] = (cls, field, list(names))
    return out


def method_options(values: Mapping | None = None) -> dict:
    """The flat keys of every registered method's options (``fpa_gap``...) and their values in ``values``
    (default: the defaults); an unknown key is refused naming the known ones."""
    known = {key: getattr(cls(), field) for key, (cls, field, _) in option_keys().items()}
    unknown = sorted(set(values or {}) - set(known))
    if unknown:
        raise InputValueError(f"unknown method option(s) {unknown}; known: {sorted(known)}")
    flat = known | {k: v for k, v in (values or {}).items() if v is not None}
    for cls in options_classes():
        cls.from_flat(flat)  # each class's check(): a bad value refused whichever method is run
    return flat
