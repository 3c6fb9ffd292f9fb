"""Exceptions raised by slr_ray.

Every error the library raises on purpose derives from :class:`SlrError`, and
also from the built-in class a numpy user expects (``ValueError`` for a bad
value or shape, ``TypeError`` for the wrong kind of data), so both
``except SlrError`` and ``except ValueError`` work.
"""


class SlrError(Exception):
    """Base class of every error raised on purpose by slr_ray."""


class InputValueError(SlrError, ValueError):
    """An argument has the right type but an impossible shape or value."""


class InputTypeError(SlrError, TypeError):
    """An argument is of the wrong kind (complex or object dtype, not an array...)."""


class FormatError(SlrError, ValueError):
    """A file could not be read or written: unknown extension, corrupt content..."""


class MissingDependencyError(SlrError, ImportError):
    """An optional dependency needed for this call is not installed."""


class StateError(SlrError, RuntimeError):
    """An object was asked for something its state no longer allows (tables already released...)."""


class EngineError(SlrError, RuntimeError):
    """The ray engine (the Embree library) reported an error."""
