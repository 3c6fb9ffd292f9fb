"""The layouts sequences come in, one module a layout, each a :class:`~.base.FrameSource` with its
``detect``; :func:`~.base.detect` picks the one a path is in (an ambiguous path is an error naming
the candidates), :func:`slr_ray.sequence.read_sequence` opens it.

``kitti``
    KITTI odometry / SemanticKITTI directories (``velodyne/``, ``labels/``, ``poses.txt``, ``calib.txt``).
``files``
    a list of frame files with a trajectory (KITTI or TUM form), pose files, or their origins.
``e57``
    an E57 file of several scans, each with its pose.
``scans``
    one file of several scans (a campaign's LAS/LAZ) split by a per-point field.
``pcd``
    a directory of PCD frames with a CSV of 4 x 4 poses (BALM's), or none.
``ouster``
    a directory of Ouster ``.npz`` frames, the sensor's metadata and a KITTI-form trajectory.

A new layout is one module here and its name in the tuple below (docs/architecture.md, Extension recipes).
"""

from . import e57, files, kitti, ouster, pcd, scans
from .base import REGISTRY, Frame, FrameSource, Sequence, SequenceInputs, detect, layout_class

__all__ = ["REGISTRY", "Frame", "FrameSource", "Sequence", "SequenceInputs", "detect", "layout_class", "LAYOUTS"]

REGISTRY.update((m.LAYOUT.name, m.LAYOUT) for m in (kitti, files, e57, scans, pcd, ouster))
#: the layouts' names, in the order ``--layout`` lists them
LAYOUTS = tuple(REGISTRY)
