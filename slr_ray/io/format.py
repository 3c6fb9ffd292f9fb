"""What a point-cloud format is to slr_ray: :class:`Format`, one entry of the
registry :data:`slr_ray.io.formats.REGISTRY` (trimesh's ``exchange`` loaders, by
extension). A format module (``npy``, ``ply``, ``las``...) defines its readers
and writers and a tuple ``FORMATS`` of its entries."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


def any_name(name: str) -> bool:
    """Every attribute name is spellable (the default)."""
    return True


@dataclass(frozen=True)
class Format:
    """One point-cloud format.

    Attributes
    ----------
    extension : str
        ``'.las'``: what :func:`~slr_ray.io.check_format` accepts.
    read : callable
        ``read(path) -> PointCloud``.
    write : callable
        ``write(path, cloud, binary)``: a whole file at ``path`` (a temporary
        that :func:`~slr_ray.io.write_cloud` renames).
    reserved : frozenset
        Attribute names the format keeps for itself: written as ``NAME_value``.
    booleans : bool
        Whether it has a boolean type (if not, booleans are written as uint8, with a warning).
    flags : frozenset
        Its own one-bit fields, which take booleans as they are.
    spellable : callable
        ``spellable(name) -> bool``: whether it can name an attribute ``name``.
    spelling : str
        The rule ``spellable`` checks, for the message of a name it refuses.
    before : callable or None
        ``before(path, cloud) -> state``: checks (and warnings) before any file is written.
    after : callable or None
        ``after(path, state)``: sidecar files, once the file is written.
    """

    extension: str
    read: Callable
    write: Callable
    reserved: frozenset = frozenset()
    booleans: bool = True
    flags: frozenset = frozenset()
    spellable: Callable = any_name
    spelling: str = ""
    before: Callable | None = None
    after: Callable | None = None


def spellable_ascii(name: str) -> bool:
    """ASCII without blanks (PLY, PCD)."""
    return name.isascii() and name.isprintable() and len(name.split()) == 1 and name == name.strip()
