"""The pulse geometry every part of slr_ray uses.

- :mod:`slr_ray.core.protocol`: :class:`Pattern`, what every scan pattern offers;
- :mod:`slr_ray.core.grid`: pulse keys and ranges of a uniform grid, the
  exact angle kernels (numba);
- :mod:`slr_ray.core.beams`: pulse keys of a beam table (numba);
- :mod:`slr_ray.core.tables`: :class:`BinTables`, the per-pulse minimum of
  (range, index) that the binning backend, streamed scans and mesh ground
  truths reduce points with (its slot tables in :mod:`slr_ray.core.slots`,
  its winners in index order, without a sort, in :mod:`slr_ray.core.order`).

The pulse index has one name: the *pulse id* ``row * columns + column``
(``v * n_azimuth + h`` for a uniform grid; :attr:`slr_ray.Scan.pulse_ids`,
:meth:`Pattern.ravel`). The kernels call a point's id, or its -1 / -2
sentinel, its *key*.

Nothing here imports a backend, a pattern class or any module above it:
backends, mesh scans, streaming and the pattern modules import the core.
"""

from .grid import grid_keys, ranges_of
from .protocol import Pattern
from .tables import BinTables

__all__ = ["Pattern", "BinTables", "pulse_ids", "grid_keys", "ranges_of"]


def pulse_ids(points, origin, pattern: Pattern):
    """Pulse id ``row * columns + column`` and range of every point
    (``pattern.pulse_ids``): -1 where the point is not seen, -2 where it is
    not finite.

    The same compiled arithmetic as every scan, so a point on a bin edge
    falls on the same side here as in a scan.
    """
    return pattern.pulse_ids(points, origin)
