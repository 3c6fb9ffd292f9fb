"""Optional sensor effects of a simulated scan, each off by default (docs/effects.md).

>>> import numpy as np, slr_ray
>>> from slr_ray.effects import Effects, simulate
>>> pts = np.array([[5.0, 0, 0], [0, 5.0, 0]])
>>> es = simulate(slr_ray.prepare(pts), [0, 0, 0], 1.0, Effects(range_noise=0.02, seed=1))
>>> len(es), es.return_number.tolist()
(2, [1, 1])

Modules: :mod:`.options` (:class:`Effects`, made from the stages' options
on :mod:`.settings`' base), :mod:`.returns` (beam
divergence, multiple returns), :mod:`.noise` (range noise, blind zone,
maximum range by reflectivity), :mod:`.raydrop` (a drop model fitted from a
real frame), :mod:`.intensity`, :mod:`.motion` (motion during a sweep) and
:mod:`.stages` (every effect as a stage: its options, its flags, what it
changes before the geometry, on the returns and on where they land),
:mod:`.simulate` (the stages' plan, the geometry, then the stages in order)
and :mod:`.scoring` (a scan with effects as range and intensity images,
scored against a real frame).
"""

from .motion import deskew, pose
from .options import Effects
from .raydrop import RayDropModel, fit_ray_drop, frame_pulses, rings_from_scan_order
from .scoring import intensity_metrics, range_image
from .simulate import EffectScan, effect_cloud, ray_count, simulate, simulate_given

__all__ = ["Effects", "EffectScan", "simulate", "simulate_given", "effect_cloud", "ray_count", "RayDropModel", "fit_ray_drop",
           "frame_pulses", "rings_from_scan_order", "pose", "deskew", "range_image", "intensity_metrics"]
