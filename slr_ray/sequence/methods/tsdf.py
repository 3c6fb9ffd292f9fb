"""``tsdf``: lidar_transfer's TSDF-mesh converter (Langer et al., IROS 2020), the published non-learned
peer: the union's range image from the target's pose fused into a TSDF, cast with the target's rays
(:mod:`slr_ray.sequence.tsdf`, whose docstring follows their code step by step)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ...errors import InputValueError
from ..tsdf import TSDF_TRUNCATION, TSDF_VOXEL, TSDF_XY_BOUND, TSDF_Z_BOUND, tsdf_returns
from .base import MethodOptions, SequenceMethod

__all__ = ["Tsdf", "TsdfOptions", "METHOD"]


@dataclass(frozen=True)
class TsdfOptions(MethodOptions):
    """The ``tsdf`` method's settings, lidar_transfer's defaults (``config/lidar_transfer.yaml``).

    Attributes
    ----------
    voxel : float
        The TSDF's voxel edge (m): their voxel_size.
    truncation : float
        The TSDF's truncation (m), at least one voxel: theirs is five voxels.
    xy_bound : float
        The volume's half-width in x and y about the target (m): their voxel_bounds; no return beyond.
    z_bound : float
        The volume's half-height in z about the target (m): their voxel_bounds.
    """

    PREFIX: ClassVar[str] = "tsdf"
    voxel: float = TSDF_VOXEL
    truncation: float = TSDF_TRUNCATION
    xy_bound: float = TSDF_XY_BOUND
    z_bound: float = TSDF_Z_BOUND

    def check(self) -> None:
        for name in ("voxel", "truncation", "xy_bound", "z_bound"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise InputValueError(f"--tsdf-{name.replace('_', '-')} must be metres > 0, got {value!r}")
        if self.truncation < self.voxel:
            raise InputValueError(f"--tsdf-truncation ({self.truncation} m) must be at least one voxel "
                                  f"(--tsdf-voxel {self.voxel} m): a thinner band has no voxel centre behind the "
                                  f"surface to change sign")


class Tsdf(SequenceMethod):
    """The union's range image from the target's pose fused into a TSDF (projectively, along the image's
    rays) and cast with the target's rays to its zero crossing; a return carries the union point nearest
    its hit. A rule on the union: both commands take it as it is."""

    name = "tsdf"
    label = "TSDF of the union's image (lidar_transfer)"
    options = TsdfOptions

    def returns(self, points, pattern, options: TsdfOptions):
        return tsdf_returns(points, pattern, voxel=options.voxel, truncation=options.truncation,
                            xy_bound=options.xy_bound, z_bound=options.z_bound)


METHOD = Tsdf()
