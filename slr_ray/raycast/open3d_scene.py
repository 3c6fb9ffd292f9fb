"""Triangles in Open3D's ``RaycastingScene``: the embree backend's ``engine='open3d'``.

Open3D is another front end to Embree; casting the same polygon fans there
cross-checks slr_ray's own casting (:class:`~slr_ray.raycast.RayScene`) and
its discs (the tests measure how far the engines agree). Open3D has no filter
callback, so there is no tie rule, and discs that hold the scanner are skipped
by starting every ray beyond the farthest of them.
"""

from __future__ import annotations

import math

import numpy as np

from ..arrays import as_origin, bounds
from ..errors import MissingDependencyError
from ..threads import default_threads
from .scene import RayHits

__all__ = ["Open3DScene"]


class Open3DScene:
    """Triangles in one Open3D ``RaycastingScene``, each owned by a point.

    Parameters
    ----------
    vertices : (m, 3) float
    faces : (f, 3) int
        Triangles; ``prims_per_owner`` consecutive triangles belong to one owner.
    owner_centres : (n, 3) float
        The owners (points): a ray from an origin within ``reach * radius`` of
        one starts beyond it.
    owner_radii : (n,) float
    prims_per_owner : int
    reach : float
    centre : (3,) float, optional
        Geometry is recentred on it in float64 before it becomes float32
        (default the middle of the vertices' bounds).

    Raises
    ------
    MissingDependencyError
        without open3d (with the install command).
    """

    def __init__(self, vertices, faces, owner_centres, owner_radii, prims_per_owner: int = 1, reach: float = 1.0,
                 centre=None):
        try:
            import open3d as o3d
        except (ImportError, OSError) as exc:  # OSError: its system library libusb-1.0 missing
            raise MissingDependencyError("engine='open3d' needs open3d: pip install open3d "
                                         "(and its system library: apt-get install libusb-1.0-0)") from exc
        self._o3d = o3d
        v = np.asarray(vertices, np.float64)
        if centre is None:
            centre = 0.5 * np.add(*bounds(v)) if len(v) else np.zeros(3)
        self.centre = np.asarray(centre, np.float64)
        self.scene = o3d.t.geometry.RaycastingScene()
        v32 = (v - self.centre).astype(np.float32)
        f32 = np.asarray(faces).astype(np.uint32)
        if len(f32):
            self.scene.add_triangles(o3d.core.Tensor(v32), o3d.core.Tensor(f32))
        self.nbytes = v32.nbytes + f32.nbytes
        self._owner_centres = np.asarray(owner_centres, np.float64)
        self._owner_reach = np.asarray(owner_radii) * float(reach)  # float32 radii: as Embree has them
        self.prims_per_owner = int(prims_per_owner)
        self._start = (None, 0.0)  # (origin, start) of the last query

    def _start_beyond_containing(self, origin) -> float:
        """How far rays from ``origin`` start: beyond every owner whose reach holds it."""
        if self._start[0] is None or not np.array_equal(self._start[0], origin):
            d = np.linalg.norm(self._owner_centres - origin, axis=1)
            inside = d <= self._owner_reach
            self._start = (origin.copy(), float((d + self._owner_reach)[inside].max(initial=0.0)))
        return self._start[1]

    def intersect(self, origin, directions, *, tfar: float = math.inf, skip_containing: bool = True,
                  n_threads: int | None = None) -> RayHits:
        """The first triangle each ray from ``origin`` along ``directions`` (unit,
        ``(m, 3)``) meets within ``tfar``; ``skip_containing``: rays start beyond
        the owners whose reach holds the origin."""
        o3d = self._o3d
        o = as_origin(origin)
        dirs = np.asarray(directions, np.float64)
        start = self._start_beyond_containing(o) if skip_containing else 0.0
        rays = np.empty((len(dirs), 6), np.float32)
        rays[:, :3] = (o - self.centre) + start * dirs
        rays[:, 3:] = dirs
        ans = self.scene.cast_rays(o3d.core.Tensor(rays), nthreads=int(n_threads or default_threads()))
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        t = ans["t_hit"].numpy().astype(np.float64) + start
        miss = (prim == o3d.t.geometry.RaycastingScene.INVALID_ID) | ~(t <= tfar)
        prim = np.where(miss, -1, prim)
        return RayHits(prim, np.where(miss, -1, prim // self.prims_per_owner), np.where(miss, np.inf, t))
