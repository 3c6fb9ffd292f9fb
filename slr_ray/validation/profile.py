"""The shipped azimuth profile, remade from synthetic scenes: :func:`build_synthetic_profile`.

The paper's azimuth test compares a position's histogram with the minimum
profile of reference scans (Yang and Purves' dataset); slr_ray ships one made
from exact scans of the validation's synthetic scenes instead
(:func:`slr_ray.positions.default_profile`), and ``slr-ray profile build``
remakes it here, beside the scenes and the true scans the validation uses.
"""

from __future__ import annotations

import numpy as np

from ..meshscan import scan_mesh
from ..paper import SECONDARY_RESOLUTION
from ..pattern import ScanPattern
from ..positions import AzimuthProfile, minimum_profile
from ..scenes import scene_from_spec

__all__ = ["build_synthetic_profile"]


def build_synthetic_profile(scenes=("distance-1", "distance-2", "distance-3", "distance-4", "distance-5"),
                            positions_per_scene: int = 4, seed: int = 0,
                            pattern: ScanPattern | None = None) -> AzimuthProfile:
    """The minimum profile of true scans of synthetic scenes (how the shipped one was made).

    For each scene, ``positions_per_scene`` scanner positions 2-15 m from the
    scene centre at 1.65 m above the ground, each scanned exactly (pulse
    centres) at ``pattern`` (0.144 deg): these stand in for the paper's
    reference scans (Yang and Purves' dataset, 0.144 deg).
    """
    pattern = pattern or ScanPattern(SECONDARY_RESOLUTION)
    rng = np.random.default_rng(seed)
    scans = []
    for name in scenes:
        scene = scene_from_spec(name)
        for _ in range(positions_per_scene):
            r, a = rng.uniform(2, 15), rng.uniform(0, 2 * np.pi)
            o = np.array([r * np.cos(a), r * np.sin(a), 0.0])
            scans.append((scan_mesh(scene, o, pattern).points, o))
    return minimum_profile(scans, pattern, meta={
        "name": "synthetic", "scenes": list(scenes), "positions_per_scene": positions_per_scene,
        "seed": seed, "made_by": "slr-ray profile build (slr_ray.validation.build_synthetic_profile)"})
