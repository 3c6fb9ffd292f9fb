"""The protocol of a sequence method (:class:`SequenceMethod`), its options and what it is given.

A method makes one return per pulse of a target sensor from the other frames
of a sequence: for a held-out frame (``slr-ray sequence evaluate``,
:func:`~slr_ray.sequence.holdout.evaluate_holdout`: :meth:`SequenceMethod.simulate`
with a :class:`HeldOut`) and for every frame of a conversion (``slr-ray
sequence convert``, :func:`~slr_ray.sequence.convert.convert_sequence`:
:meth:`SequenceMethod.convert_frame` with a :class:`TargetFrame`). What a
method can do is a capability on its class, read by the callers (never its
name):

- ``holdout``, ``convert``: it works in the leave-one-out evaluation, in a conversion;
- ``default``: it is among ``sequence evaluate``'s default methods;
- ``needs_source_sensor``: it needs the frames' own sensor (``source_why`` says why);
- ``info``: the key of what it reports about a held-out frame (``None``: nothing; the
  frame's result holds the key whether or not the method ran).

What a method builds once for a whole sequence (meshes of its frames, a fitted model) is its
``sequence_state(seq, cache, options)``; :meth:`SequenceMethod.state` gives it, built on first
use and held by the run's :class:`~slr_ray.sequence.union.FrameCache`
(:meth:`~slr_ray.sequence.union.FrameCache.method_state`): one for all the held-out frames of a
``sequence evaluate``, one for all the frames a ``sequence convert`` worker converts. What is
built per frame (a frame's kept points, its discs) goes on the cache with the frame.

Its settings are a frozen :class:`MethodOptions` subclass (``options``): the docstring's
Attributes describe each field; ``PREFIX`` names its flags (``--PREFIX-FIELD``) and the flat
keys of the callers' ``method_options`` (``PREFIX_FIELD``); a field two classes share names one
key in ``KEYS`` (``rays`` takes the first peak's ``gap`` as ``fpa`` does, ``fpa_gap``: one flag).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...errors import InputValueError
from ...options import Options
from ..estimators import FPA_GAP, PulseReturns
from ..frames import Sequence
from ..rays import MAX_SHIFT, RAY_NEIGHBOURS
from ..sources import SeeThrough
from ..union import FrameCache, Keep, Union, accumulate, to_frame

__all__ = ["MethodOptions", "NoOptions", "FirstPeakOptions", "RaysOptions", "HeldOut", "TargetFrame",
           "SequenceMethod"]


@dataclass(frozen=True)
class MethodOptions(Options):
    """Base of a sequence method's options (module docstring): ``PREFIX`` names the flags and keys."""

    PREFIX: ClassVar[str] = ""
    #: a field's flat key where it is not ``PREFIX_FIELD``: a setting two classes share (one flag)
    KEYS: ClassVar[dict] = {}

    def check(self) -> None:
        """Refuse impossible values (``InputValueError`` naming the flag)."""

    @classmethod
    def keys(cls) -> dict:
        """``{flat key: field}``: ``PREFIX_FIELD`` for each field (or its entry of ``KEYS``)."""
        return {cls.KEYS.get(f.name, f"{cls.PREFIX}_{f.name}"): f.name for f in dataclasses.fields(cls)}

    @classmethod
    def from_flat(cls, values: Mapping):
        """The options from the flat keys found in ``values`` (others ignored; a missing one its default),
        checked."""
        o = cls(**{name: values[key] for key, name in cls.keys().items() if values.get(key) is not None})
        o.check()
        return o


@dataclass(frozen=True)
class NoOptions(MethodOptions):
    """A method without settings."""


@dataclass(frozen=True)
class FirstPeakOptions(MethodOptions):
    """The first peak along a pulse (``fpa``'s average, ``rays``' cluster along each ray).

    Attributes
    ----------
    gap : float
        The first-peak average's gap: the largest step between ranges in a pulse's first cluster (m).
    """

    PREFIX: ClassVar[str] = "fpa"
    gap: float = FPA_GAP

    def check(self) -> None:
        if not (isinstance(self.gap, (int, float)) and self.gap > 0):
            raise InputValueError(f"the fpa gap must be > 0 m, got {self.gap}")


@dataclass(frozen=True)
class RaysOptions(MethodOptions):
    """The ``rays`` method's settings (:func:`~slr_ray.sequence.rays.cast_rays`).

    Attributes
    ----------
    gap : float
        The first cluster's gap along each ray (m): ``--fpa-gap``, the one fpa takes.
    neighbours : int
        Union points whose plane a ray meets (3 or more).
    max_shift : float
        How far before the first cluster a ray's hit on the plane may lie (m).
    """

    PREFIX: ClassVar[str] = "rays"
    KEYS: ClassVar[dict] = {"gap": "fpa_gap"}
    gap: float = FPA_GAP
    neighbours: int = RAY_NEIGHBOURS
    max_shift: float = MAX_SHIFT

    def check(self) -> None:
        FirstPeakOptions(self.gap).check()
        if not (isinstance(self.neighbours, (int, np.integer)) and self.neighbours >= 3):
            raise InputValueError(f"--rays-neighbours: a plane takes 3 or more neighbours, got {self.neighbours}")
        if not (isinstance(self.max_shift, (int, float)) and self.max_shift >= 0):
            raise InputValueError(f"--rays-max-shift must be metres >= 0, got {self.max_shift}")


class _KeepRead:
    """``drop_moving`` and ``see_through`` read from the ``keep`` of what a method is given (the
    old fields' names)."""

    keep: Keep

    @property
    def drop_moving(self) -> bool:
        return self.keep.drop_moving

    @property
    def see_through(self) -> SeeThrough | None:
        return self.keep.see_through


@dataclass
class HeldOut(_KeepRead):
    """What a method may use for a held-out frame: never its points (its pattern is the table
    fitted to them, or to the others', as every method's grid)."""

    seq: Sequence
    target: int
    others: list
    union: Union
    u: np.ndarray       # the union in the target's frame
    pattern: object     # the grid every method fills and is scored on
    base: object        # the frames' sensor (a shipped beam table)
    cache: FrameCache
    pose: np.ndarray    # the held-out frame's pose (where its pulses start)
    keep: Keep = Keep()  # which points of each frame the union keeps (its exclude: the target)
    target_base: object = None  # the held-out frame's own unit where it is not ``base`` (a target sensor)


@dataclass
class TargetFrame(_KeepRead):
    """A frame of a conversion: its window's frames, the target sensor's pose and pattern."""

    seq: Sequence
    frames: list        # the window, the frame itself included
    pose: np.ndarray    # the target sensor's pose (world)
    pattern: object     # the target sensor
    cache: FrameCache
    keep: Keep = Keep()     # which points of each frame the union keeps
    source: object = None   # the frames' own sensor (a beam table), where given

    def union(self) -> Union:
        """The window's union (world frame)."""
        return accumulate(self.seq, self.frames, self.keep, cache=self.cache)


class SequenceMethod:
    """A sequence method (module docstring). A subclass sets ``name``, ``label`` and its
    capabilities, and implements :meth:`returns` (a rule on a union in the sensor's frame), or
    :meth:`simulate` and :meth:`convert_frame` where it needs more than the union."""

    #: its name (``--methods``, ``--estimator``, rows' ``method``) and its label in the tables
    name: ClassVar[str] = ""
    label: ClassVar[str] = ""
    options: ClassVar[type] = NoOptions
    holdout: ClassVar[bool] = True
    convert: ClassVar[bool] = True
    default: ClassVar[bool] = False
    needs_source_sensor: ClassVar[bool] = False
    source_why: ClassVar[str] = ""
    info: ClassVar[str | None] = None

    def source_problem(self, points, attributes, base, options) -> str | None:
        """Why the method can do nothing with a frame (``points`` in its own axes, its ``attributes``)
        of the source sensor ``base`` (None: it can): a conversion checks its first frame with it before
        any frame is cast (``needs_source_sensor`` methods)."""
        return None

    def sequence_state(self, seq: Sequence, cache: FrameCache, options):
        """What the method builds once for the sequence ``seq`` (module docstring); None: nothing."""
        return None

    def state(self, given: HeldOut | TargetFrame, options):
        """This method's :meth:`sequence_state` for the run ``given`` belongs to, built once."""
        return given.cache.method_state(self, options)

    def returns(self, points, pattern, options) -> PulseReturns:
        """One return per pulse of ``pattern`` from ``points`` (float64, the scanner at the origin)."""
        raise NotImplementedError(f"{self.name}: no rule on a union (it implements simulate / convert_frame)")

    def simulate(self, held: HeldOut, options) -> tuple[PulseReturns, np.ndarray, dict | None]:
        """The held-out frame's returns, the points scored (its simulation) and what it reports
        (``info``), from ``held``."""
        ret = self.returns(held.u, held.pattern, options)
        return ret, ret.points, None

    def convert_frame(self, frame: TargetFrame, options) -> tuple[PulseReturns, dict]:
        """A converted frame's returns and the attributes each return carries."""
        union = frame.union()
        ret = self.returns(to_frame(union.points, frame.pose), frame.pattern, options)
        return ret, {n: v[ret.index] for n, v in union.attributes.items()}
