"""Typed options of a long call: frozen dataclasses instead of long parameter lists.

A function with many settings takes its required inputs, an options object
and the old keywords: ``select_positions(points, is_ground, 10,
PositionOptions(cell_size=4))`` and ``select_positions(points, is_ground, 10,
cell_size=4)`` are the same call (:meth:`Options.of` merges them). The same
names and checks serve the library, config files and the command line; an
unknown name is an error that lists the known ones, and the class docstring's
Attributes section is each field's one description (:meth:`Options.describe`,
what the command line's help shows for the backends' options).
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Mapping

from .errors import InputTypeError, dataclass_from_mapping

__all__ = ["Options"]


@dataclasses.dataclass(frozen=True)
class Options:
    """Base of every options class (frozen; unknown keys rejected; a list given for a
    field is kept as a tuple, so that options read from JSON or TOML equal and hash as
    the defaults do)."""

    def __post_init__(self):
        for f in dataclasses.fields(self):
            if isinstance(getattr(self, f.name), list):
                object.__setattr__(self, f.name, tuple(getattr(self, f.name)))

    def to_dict(self) -> dict:
        """The fields, as a plain dict (shallow): JSON-ready where the fields are."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, options: dict | None = None, **more):
        """Options from a mapping (a config file's table, CLI flags) and keywords.

        Raises
        ------
        InputValueError
            naming unknown keys and listing the known ones.
        """
        return dataclass_from_mapping(cls, options, more, f"option(s) for {cls.__name__}:")

    @classmethod
    def of(cls, options=None, /, **keywords):
        """The options of one call: ``options`` (an instance, a mapping or None for the
        defaults; or options of a base class, as :class:`~slr_ray.positions.CellOptions`
        given for :class:`~slr_ray.positions.PositionOptions`, whose fields it takes) with
        ``keywords`` (the call's old keyword arguments) over it.

        Raises
        ------
        InputValueError
            an unknown keyword, naming the known ones.
        InputTypeError
            ``options`` of another type.
        """
        if isinstance(options, cls):
            if not keywords:
                return options
            kind = type(options)  # a subclass stays one
            fields = {f.name: getattr(options, f.name) for f in dataclasses.fields(options)}
            return dataclass_from_mapping(kind, fields, keywords, f"option(s) for {kind.__name__}:")
        if isinstance(options, Options) and issubclass(cls, type(options)):  # a base's: its fields
            options = {f.name: getattr(options, f.name) for f in dataclasses.fields(options)}
        if options is not None and not isinstance(options, Mapping):
            raise InputTypeError(f"options must be {cls.__name__} (or a mapping of its fields, or None), got "
                                 f"{type(options).__name__}: the settings after the required arguments are "
                                 f"keywords or {cls.__name__}'s fields, no longer positions")
        return cls.from_dict(options, **keywords)

    @classmethod
    def describe(cls) -> dict:
        """``{field: (type, description)}`` from the Attributes section (numpydoc) of the
        class docstring, and of its bases' for the fields it inherits: the one description
        the command line's help shows."""
        out = {}
        for klass in reversed(cls.__mro__):
            doc = klass.__dict__.get("__doc__")
            if doc and issubclass(klass, Options):
                out.update(_attributes(inspect.cleandoc(doc)))
        return out


def _attributes(doc: str) -> dict:
    """``{field: (type, description)}`` of a docstring's Attributes section."""
    lines = doc.split("Attributes\n----------\n", 1)[-1].splitlines() if "Attributes" in doc else []
    out, name = {}, None
    for line in lines:
        if line and not line.startswith(" ") and " : " in line:
            name, typ = line.split(" : ", 1)
            out[name.strip()] = [typ.strip(), ""]
        elif line.startswith(" ") and name is not None:
            out[name][1] = (out[name][1] + " " + line.strip()).strip()
        elif not line.strip() and name is not None and out[name][1]:
            name = None
    return {k: tuple(v) for k, v in out.items()}
