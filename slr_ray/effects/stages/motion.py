"""Motion during the sweep as a stage (:mod:`slr_ray.effects.motion`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ...errors import InputValueError
from ..motion import column_sectors, interpolate_poses, to_firing_frames, to_frame
from ..settings import MOTION_FRAMES, EffectOptions, integral
from .base import SCAN_SECTORS, Stage

__all__ = ["MotionOptions", "Motion"]


@dataclass(frozen=True)
class MotionOptions(EffectOptions):
    """Motion during the sweep.

    Attributes
    ----------
    motion : bool
        The scan needs poses (motion during the sweep): :func:`simulate`
        refuses a call without them.
    motion_sectors : int, optional
        Azimuth sectors with one pose each (default: every column with a
        backend that casts rays, 72 with one that does not, as binning,
        which scans once per sector).
    sweep_start_deg : float
        Azimuth (``atan2(y, x)``, degrees) where the sweep starts (KITTI: 180).
    sweep_clockwise : bool
        The sweep turns clockwise seen from above (Velodyne units, KITTI);
        default counter-clockwise (:mod:`slr_ray.effects.motion`).
    motion_frame : {'sensor-end', 'firing'}
        With motion: every return in the sensor frame at the sweep's end (a
        motion-compensated frame) or in the frame of the pose its column fired
        from (a raw frame, as KITTI raw's).
    """

    motion: bool = False
    motion_sectors: int | None = None
    sweep_start_deg: float = 0.0
    sweep_clockwise: bool = False
    motion_frame: str = "sensor-end"

    def check(self):
        if not isinstance(self.motion, bool):
            raise InputValueError(f"motion must be true or false, got {self.motion!r}")
        if self.motion_sectors is not None and not integral(self.motion_sectors, 1):
            raise InputValueError(f"motion_sectors must be an integer >= 1, got {self.motion_sectors!r}")
        if not (isinstance(self.sweep_start_deg, (int, float)) and not isinstance(self.sweep_start_deg, bool)
                and -360 <= self.sweep_start_deg <= 360):
            raise InputValueError(f"sweep_start_deg must be an angle in degrees in [-360, 360], got "
                                  f"{self.sweep_start_deg!r}")
        if not isinstance(self.sweep_clockwise, bool):
            raise InputValueError(f"sweep_clockwise must be true or false, got {self.sweep_clockwise!r}")
        if self.motion_frame not in MOTION_FRAMES:
            raise InputValueError(f"motion_frame must be one of {MOTION_FRAMES}, got {self.motion_frame!r}")


class Motion(Stage):
    """Motion during the sweep (:mod:`.motion`): each sector of columns fires from
    its own pose (every column, where the scanner casts rays; else
    :data:`SCAN_SECTORS` sectors, each scanned whole), and the returns are written
    in the sensor's frame at the sweep's end, or each in its firing pose's. On
    when ``simulate`` is given poses."""

    name = "motion"
    options = MotionOptions

    def on(self, ctx):
        return ctx.poses is not None

    def rays(self, plan, ctx):
        eff, nh = ctx.effects, ctx.pattern.shape[1]
        n = eff.motion_sectors or (nh if ctx.scanner.casts_rays else SCAN_SECTORS)
        starts, stops, times = column_sectors(nh, n, eff.sweep_start_deg, eff.sweep_clockwise)
        rotations, origins = interpolate_poses(ctx.poses, times)
        return dataclasses.replace(plan, sectors=(starts, stops, rotations, origins), n_sectors=n)

    def place(self, points, r, ctx):
        eff = ctx.effects
        if eff.motion_frame == "firing":
            ctx.frame = "firing"
            return to_firing_frames(points, r.h, ctx.pattern.shape[1], ctx.poses, ctx.rays.n_sectors,
                                    eff.sweep_start_deg, eff.sweep_clockwise)
        ctx.frame = "sensor-end"
        return to_frame(points, ctx.poses[-1])
