"""The registry of point-cloud formats: extension -> :class:`~slr_ray.io.format.Format`.

A new format is one module of ``slr_ray/io/`` (its reader, writer and a tuple
``FORMATS`` of its entries) and its name in the line below; the command
line's ``--format`` choices, :func:`~slr_ray.io.check_format`,
:func:`~slr_ray.io.read_cloud` and :func:`~slr_ray.io.write_cloud` read the
registry.
"""

from __future__ import annotations

from . import e57, kitti, las, npy, nuscenes, pcd, ply, xyz

__all__ = ["REGISTRY", "FORMATS"]

#: extension -> Format, in the order the command line lists them
REGISTRY = {f.extension: f for module in (npy, ply, las, kitti, xyz, e57, pcd, nuscenes) for f in module.FORMATS}
#: the extensions slr_ray reads and writes
FORMATS = tuple(REGISTRY)
