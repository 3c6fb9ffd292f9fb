"""``zbuffer``: no SLR, every point of the union in the held-out frame's view (the baseline)."""

from __future__ import annotations

import numpy as np

from ..estimators import nearest_returns
from .base import HeldOut, SequenceMethod

__all__ = ["ZBuffer", "METHOD"]


class ZBuffer(SequenceMethod):
    """The z-buffer of the union: its image the nearest point per pulse, its points every point of the
    union in the frame's view (no visibility rule). Scores only: nothing to convert."""

    name = "zbuffer"
    label = "no SLR (z-buffer of the union)"
    convert = False
    default = True

    def simulate(self, held: HeldOut, options):
        u, pat = held.u, held.pattern
        ret = nearest_returns(u, pat)
        keys, _ = pat.pulse_ids(u, np.zeros(3))
        return ret, u[keys >= 0], None


METHOD = ZBuffer()
