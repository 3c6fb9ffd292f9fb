"""Which grid a held-out frame is scored on: a spinning unit's beam table, or a terrestrial scanner's own grid.

A held-out frame is scored on its sensor's grid (every method fills it; the target is the frame's
points in its view). Two kinds of sensor (:data:`KINDS`):

``spinning``
    A unit of beams (a Velodyne, Ouster, Hesai... or a card): its beam table fitted to the frame
    (:func:`slr_ray.sensors.fitted_pattern`) where the frame's beams are known (a ``ring`` field,
    the scan order of a KITTI ``.bin``). Named by ``sensor`` (``--source-sensor``).
``terrestrial``
    A terrestrial laser scanner: one uniform angular grid about its origin, fitted to the frame's
    own points (:func:`terrestrial_grid`: the embree backend's primary fit,
    :func:`slr_ray.backends.embree.fit.fit_primary_pattern`, as ``slr-ray scan`` and ``augment``
    fit a primary; its zenith rows cut to those the frame fired), never a spinning unit's table. The frame has no beams: methods that need the
    frames' beam table (``needs_source_sensor``) are refused, and ``rays`` casts the grid's pulse
    centres (:func:`slr_ray.sequence.rays.cast_grid_rays`).

``sensor="auto"`` (:data:`AUTO`; ``sequence evaluate`` without ``--source-sensor``) decides for
each held-out frame (:func:`sensor_kind`): a frame with a ``ring`` field or in the scan order of
:data:`DEFAULT_SPINNING` (KITTI's) is spinning, on that table, as before; any other frame is
terrestrial. A frame that is neither (no ring, no scan order, no uniform grid holds it as a scan)
is refused, naming ``--source-sensor``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backends.embree.fit import FIT_MIN_SINGLE, fit_primary_pattern
from ..errors import InputValueError
from .sources import known_beams

__all__ = ["AUTO", "SPINNING", "TERRESTRIAL", "KINDS", "DEFAULT_SPINNING", "ScoringGrid", "sensor_kind",
           "terrestrial_grid", "is_terrestrial"]

#: decide the kind from each held-out frame (``--source-sensor`` not given)
AUTO = "auto"
SPINNING, TERRESTRIAL = "spinning", "terrestrial"
KINDS = (SPINNING, TERRESTRIAL)
#: the spinning unit taken where none is named and a frame is in its scan order (KITTI's)
DEFAULT_SPINNING = "velodyne_hdl64e_s2"


@dataclass(frozen=True)
class ScoringGrid:
    """A held-out frame's scoring grid: its ``kind`` (:data:`KINDS`), the ``pattern`` every method
    fills, the frame's ``beams`` (spinning, where known), the frames' beam table ``base`` (spinning;
    None for a terrestrial scanner) and ``how``, one line saying which grid and why."""

    kind: str
    pattern: object
    beams: np.ndarray | None
    base: object | None
    how: str

    def to_dict(self) -> dict:
        return {"kind": self.kind, "how": self.how}


def is_terrestrial(sensor) -> bool:
    """Whether ``sensor`` (a held-out evaluation's ``sensor``) asks for the terrestrial grid."""
    return isinstance(sensor, str) and sensor == TERRESTRIAL


def sensor_kind(points, attributes, base) -> str:
    """:data:`SPINNING` where the frame's beams are known in ``base``'s table (a ``ring`` field, its
    scan order), else :data:`TERRESTRIAL`."""
    return SPINNING if known_beams(points, attributes, base) is not None else TERRESTRIAL


def terrestrial_grid(points, what: str) -> tuple:
    """``(pattern, how)``: the uniform grid fitted to ``points`` (the scanner at the origin, its axes
    the frame's) and a line saying so, with the fit's quality (the share of occupied pulses holding
    one point). Refused, naming ``what`` and ``--source-sensor``, where the points show no grid or
    the fitted one holds them as no scan would (under :data:`~slr_ray.backends.embree.fit.FIT_MIN_SINGLE`)."""
    p = np.asarray(points, np.float64)
    why = None
    try:
        pattern, _, quality = fit_primary_pattern(p, np.zeros(3), min_quality=0.0)
    except InputValueError:
        why = "its points show no grid of rows and columns about its origin"
    else:
        if getattr(pattern, "has_beams", False):  # in the fit's beam-table scan order: a spinning unit's
            why = "it is stored ring after ring as a spinning unit's frame"
        elif not quality >= FIT_MIN_SINGLE:
            why = (f"the uniform grid fitted to it holds one point in {quality:.0%} of its occupied pulses "
                   f"(a scan's: {FIT_MIN_SINGLE:.0%} or more)")
    if why is not None:
        raise InputValueError(f"{what}: not a terrestrial scan ({why}) and no spinning unit's beams known (no ring "
                              "field, not in a shipped table's scan order): name the frames' sensor "
                              "(--source-sensor NAME or card.json)")
    pattern = _zenith_extent(pattern, p)
    how = (f"terrestrial: a uniform grid fitted to the frame, {pattern.zenith_resolution:.5g} deg (zenith) x "
           f"{pattern.azimuth_resolution:.5g} deg (azimuth), zenith {pattern.zenith_range[0]:.4g} to {pattern.zenith_range[1]:.4g} deg; one "
           f"point in {quality:.1%} of its occupied pulses")
    return pattern, how


def _zenith_extent(pattern, points):
    """``pattern`` (a uniform grid fitted to ``points``) cut to the zenith rows the scan fired: from its
    highest row that holds a point to its lowest, whole rows (the grid's rows unmoved). A scanner fires
    no pulse above its field of view (30 deg from the zenith, say): a grid from the zenith would score
    the other setups' points there as returns the frame dropped."""
    keys, _ = pattern.pulse_ids(points, np.zeros(3))
    rows = keys[keys >= 0] // pattern.shape[1]
    if not len(rows):
        return pattern
    lo, hi = pattern.zenith_range
    step = pattern.zenith_resolution
    return pattern.with_(zenith_range=(lo + int(rows.min()) * step, min(hi, lo + (int(rows.max()) + 1) * step)),
                         name="fitted to the frame")
