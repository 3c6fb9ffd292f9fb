"""Exceptions raised by slr_ray.

Every error the library raises on purpose derives from :class:`SlrError`, and
also from the built-in class a numpy user expects (``ValueError`` for a bad
value or shape, ``TypeError`` for the wrong kind of data), so both
``except SlrError`` and ``except ValueError`` work. A message that names a
library argument (``allow_fewer=True``) carries the flag a command-line user
types instead (``--allow-fewer``): :meth:`SlrError.for_cli`.

What slr_ray decided on the caller's behalf, or a result short of what was
asked, is said as a warning (:class:`SlrWarning`, :class:`SlrNote`), which
``slr-ray`` prints as one ``slr-ray: warning: ...`` (or ``note:``) line.

:func:`refuse_memory` turns a setting that would exhaust memory into an
:class:`InputValueError` with the figure, before the work.
"""

import dataclasses
import os


class SlrError(Exception):
    """Base class of every error raised on purpose by slr_ray.

    ``flags`` maps words of the message that name library arguments to what
    a command-line user types instead (``{"allow_fewer=True": "--allow-fewer"}``);
    :meth:`for_cli` is the message in those words.
    """

    def __init__(self, *args, flags: dict | None = None):
        super().__init__(*args)
        self.flags = dict(flags or {})

    def for_cli(self) -> str:
        """The message as a command-line user should read it: flags, not arguments."""
        text = str(self)
        for word, flag in self.flags.items():
            text = text.replace(word, flag)
        return text


class SlrWarning(UserWarning):
    """A result short of what was asked, accepted (fewer positions than ``n``
    with ``allow_fewer``), or one that is probably not what was meant (a scan
    that returns almost nothing of a large cloud)."""


class SlrNote(SlrWarning):
    """What slr_ray decided on the caller's behalf (ground labelled by CSF):
    said, so that it is never silent."""


class InputValueError(SlrError, ValueError):
    """An argument has the right type but an impossible shape or value."""


class InputTypeError(SlrError, TypeError):
    """An argument is of the wrong kind (complex or object dtype, not an array...)."""


class FormatError(SlrError, ValueError):
    """A file could not be read or written: unknown extension, corrupt content..."""


class MissingDependencyError(SlrError, ImportError):
    """An optional dependency needed for this call is not installed."""


class OutputError(SlrError, OSError):
    """An output cannot be written safely: it is an input (or the same file as
    another output), it exists and ``force`` was not given, it is not a
    regular file, or its directory is locked by another run."""


def physical_memory() -> int:
    """Bytes of physical memory of this machine (0 where it cannot be read)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 0


def refuse_memory(nbytes: float, what: str, hint: str = "") -> None:
    """Raise :class:`InputValueError` before the work when ``what`` would need
    ``nbytes`` of memory, more than the machine has (the figure in the message)."""
    have = physical_memory()
    if have and nbytes > have:
        raise InputValueError(f"{what} would need about {nbytes / 2**30:,.1f} GiB of memory, more than this "
                              f"machine's {have / 2**30:,.1f} GiB{': ' + hint if hint else ''}")
class StateError(SlrError, RuntimeError):
    """An object was asked for something its state no longer allows (tables already released...)."""


class EngineError(SlrError, RuntimeError):
    """The ray engine (the Embree library) reported an error."""


def dataclass_from_mapping(cls, options: dict | None, more: dict, what: str):
    """``cls(**options, **more)`` for a dataclass, refusing unknown keys.

    Raises
    ------
    InputValueError
        naming the unknown keys of ``what`` and listing the known ones.
    """
    merged = {**(options or {}), **more}
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(merged) - known)
    if unknown:
        raise InputValueError(f"unknown {what} {unknown}; known: {sorted(known)}")
    return cls(**merged)
