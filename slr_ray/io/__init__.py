"""Input and output: point-cloud files, output planning and streamed reads.

- :mod:`~slr_ray.io.files`: :func:`read_cloud`, :func:`write_cloud`,
  :func:`check_format` (the format table is there);
- one module a format (``npy``, ``ply``, ``las``, ``kitti``, ``xyz``, ``e57``,
  ``pcd``), each with its :class:`~slr_ray.io.format.Format` entries, and the
  registry :data:`slr_ray.io.formats.REGISTRY` that lists them;
- :mod:`~slr_ray.io.cloud`: :class:`PointCloud`, :class:`LasRecords`;
- :mod:`~slr_ray.io.atomic`: :func:`atomic_path`, the atomic write;
- :mod:`~slr_ray.io.outputs`: :class:`~slr_ray.io.outputs.OutputPlan`, every
  path a command reads and writes (``slr_ray.outputs`` names it too);
- :mod:`~slr_ray.io.streaming`: LAS/LAZ files read in chunks (the streamed
  scans built on them are :mod:`slr_ray.streaming`'s).
"""

from .atomic import atomic_path
from .cloud import LasRecords, PointCloud, gather
from .e57 import read_e57_scans
from .files import check_format, read_cloud, write_cloud
from .formats import FORMATS, REGISTRY
from .kitti import KITTI_TOLERANCE
from .las import check_las_size
from .outputs import label_path

__all__ = ["PointCloud", "LasRecords", "read_cloud", "write_cloud", "read_e57_scans", "check_format",
           "check_las_size", "label_path", "FORMATS", "REGISTRY", "atomic_path", "gather", "KITTI_TOLERANCE"]
