"""The stages' common parts: :class:`Stage` (an effect: its options, its flags,
:meth:`~Stage.on`, and what it changes), the :class:`Returns` it changes, the
:class:`Rays` plan its :meth:`~Stage.rays` leaves, the :class:`Context` it reads
and the :class:`Flag` s the command line is generated from. Each stage is a module
of its own in this package, importing this one; the package's ``__init__`` lists
them in :data:`~slr_ray.effects.stages.STAGES` (see its docstring)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ...backends.embree import estimate_normals

__all__ = ["Returns", "Rays", "Flag", "Stage", "Context", "SCAN_SECTORS"]

#: Sectors of columns a scanner that casts no rays scans one by one under motion (each a whole scan).
SCAN_SECTORS = 72


@dataclass
class Returns:
    """The returns of a scan as they pass through the stages: one row per return,
    in pulse order (the returns of a pulse contiguous)."""

    v: np.ndarray
    h: np.ndarray
    range: np.ndarray
    index: np.ndarray
    dir: np.ndarray
    fire: np.ndarray
    share: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    intensity: np.ndarray | None = None

    @classmethod
    def from_columns(cls, columns: dict) -> "Returns":
        """From the geometry's columns (extra ones, as ``strength``, are left out)."""
        return cls(**{f.name: columns[f.name] for f in dataclasses.fields(cls) if f.name in columns})

    def __len__(self) -> int:
        return len(self.v)

    def take(self, rows) -> "Returns":
        """The returns at ``rows`` (a mask or indices)."""
        return Returns(**{f.name: None if getattr(self, f.name) is None else getattr(self, f.name)[rows]
                          for f in dataclasses.fields(self)})


@dataclass
class Rays:
    """What the geometry casts, as the stages' :meth:`Stage.rays` leave it: by
    default nothing beyond the ideal scan (one ray a pulse from the origin).

    ``offsets``, ``weights``: each pulse's sub-rays and their shares of the
    footprint (:func:`~slr_ray.effects.returns.footprint_samples`); ``subrays``:
    whether they replace the pulse's own ray; ``separation``, ``min_share``,
    ``returns``: how a pulse's hits group into returns and which it reports.
    ``sectors``: ``(starts, stops, rotations, origins)`` of the column sectors
    that fire from their own poses, and ``n_sectors`` the number asked for (the
    firing frames are made with it).
    """

    offsets: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((1, 2)))
    weights: np.ndarray = dataclasses.field(default_factory=lambda: np.ones(1))
    subrays: bool = False
    separation: float = 1.0
    min_share: float = 0.0
    returns: tuple = ("all",)
    sectors: tuple | None = None
    n_sectors: int | None = None

    @property
    def ideal(self) -> bool:
        """Nothing to cast here: the scanner's own scan is the geometry."""
        return not self.subrays and self.sectors is None


class Flag(NamedTuple):
    """A command-line flag of one :class:`~slr_ray.effects.Effects` field.

    ``kind``: ``'number-or-sensor'``, ``'int'`` or ``'text'``; ``choices`` and
    ``nargs`` as argparse's."""

    field: str
    flag: str
    metavar: str | None
    help: str
    kind: str = "text"
    choices: tuple | None = None
    nargs: str | None = None


@dataclass
class Context:
    """What the stages read beside the returns (the scan's settings, resolved once)."""

    effects: object
    scanner: object
    pattern: object
    origin: np.ndarray
    intensity: np.ndarray | None
    normals: np.ndarray | None
    primary_origin: object
    rng: dict
    info: dict
    #: sensor-to-world poses over the sweep (motion), or None
    poses: np.ndarray | None = None
    #: what the geometry cast (the stages' :meth:`Stage.rays`), once made
    rays: Rays | None = None
    #: the frame the returns' points are in (:class:`~slr_ray.effects.EffectScan`'s ``frame``)
    frame: str = "world"

    def incidence_cos(self, r: Returns, rows) -> np.ndarray:
        """|cos| of each return's incidence on its point's normal (the given normals,
        the scanner's own, or estimated once)."""
        if self.normals is None:
            own = self.scanner.normals
            self.normals = (np.asarray(own, np.float64) if own is not None
                            else estimate_normals(self.scanner.points, k=10, primary_origin=self.origin))
        nrm = self.normals[r.index[rows]]
        return np.abs(np.einsum("ij,ij->i", nrm, r.dir[rows])) / np.linalg.norm(nrm, axis=1)

    def keep(self, r: Returns, mask, what: str) -> Returns:
        """The returns of ``mask``; the number removed goes to ``info`` as ``removed_{what}``."""
        self.info[f"removed_{what}"] = int(np.count_nonzero(~mask))
        return r.take(mask)


class Stage:
    """One effect: its options (``options``, whose fields are ``fields``), its
    flags, :meth:`on`, and what it changes (module docstring: :meth:`rays`,
    :meth:`apply`, :meth:`place`; each unchanged by default). ``name`` keys its
    seconds in the result's ``info``."""

    name: str = ""
    #: its options: a frozen :class:`~slr_ray.effects.settings.EffectOptions` dataclass, whose fields
    #: :class:`~slr_ray.effects.Effects` takes (a scene's ``[effects]`` table and JSON name them)
    options: type | None = None
    #: the Effects fields it owns (its options' fields)
    fields: tuple = ()
    #: its command-line flags (the rest of its fields through --effects FILE)
    flags: tuple = ()

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if cls.__dict__.get("options") is not None:
            cls.fields = tuple(f.name for f in dataclasses.fields(cls.options))

    def on(self, ctx: Context) -> bool:
        """Whether the stage runs with these effects."""
        raise NotImplementedError

    def rays(self, plan: Rays, ctx: Context) -> Rays:
        """What the geometry casts after this effect (before any work: refusals go here)."""
        return plan

    def apply(self, r: Returns, ctx: Context) -> Returns:
        """The returns after this effect."""
        return r

    def place(self, points: np.ndarray, r: Returns, ctx: Context) -> np.ndarray:
        """Where the returns land after this effect (``(m, 3)``, one row a return)."""
        return points
