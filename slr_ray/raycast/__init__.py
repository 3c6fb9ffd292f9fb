"""Ray casting: the one place of slr_ray that casts rays.

Everything that casts rays (ground-truth scans of meshes, the embree backend's
discs, the occlusion diagnostics of the validation) goes through
:class:`RayScene` (Embree, :mod:`slr_ray.raycast.scene`), or, for the embree
backend's ``engine='open3d'`` cross-check, :class:`Open3DScene` (the same
polygons in Open3D's ``RaycastingScene``, :mod:`slr_ray.raycast.open3d_scene`).
:class:`RayScene` owns

* the lookup of the Embree 4 shared library (:func:`embree_library`, :mod:`slr_ray.raycast.library`): the
  ``libembree4`` that the ``embreex`` wheel ships, or one named by the
  environment variable ``SLR_RAY_EMBREE``; a clear
  :class:`~slr_ray.errors.MissingDependencyError` when there is none;
* the float32 boundary: geometry is recentred on a float64 ``centre`` before it
  becomes float32, and rays start from the scanner recentred the same way;
* the cast loop: compiled (numba, ``nogil``), calling ``rtcIntersect1/4/8/16``
  through their C function pointers (ray packets, below), rays split into tasks
  of 32,768 to 131,072 (eight a thread in between) that the threads take in
  turn (a signal stops a cast after the running tasks, not after all of it);
  a ray that misses the scene's padded bounding box is answered without the
  call (a float64 slab test: most rays of a scan from
  outside a cloud's bounds miss it, and a call costs as much as a short
  traversal), and so is a ray whose direction meets none of the boxes of the
  scene's occupied voxels (a cube map of directions made for each cast from
  its origin, :mod:`slr_ray.raycast.cull`: rays that enter the bounds and
  meet nothing, towards the sky or past a cloud seen from outside);
* two refinements that make results independent of float32 noise: for
  triangles, the hit distance recomputed in float64 on the hit triangle's plane
  (``exact=True``); for discs, the deterministic tie rule (``ties``, below).

Geometry kinds
--------------
``RayScene.triangles(vertices, faces)``
    A triangle mesh (``RTC_GEOMETRY_TYPE_TRIANGLE``).
``RayScene.discs(centres, radii, normals)``
    Embree's own disc primitives: with normals, ``ORIENTED_DISC_POINT`` (a
    disc in the plane normal to each normal); without, ``DISC_POINT`` (each
    disc faces the ray that meets it: billboards without a BVH per position).
    The exact disc, not a polygon: no tessellation, 28 bytes a point handed to
    Embree (float4 centre and radius, float3 normal).

Ties (discs)
------------
Overlapping discs of one surface are hit at nearly the same distance, and which
comes first is decided by float32 rounding: the same cloud moved by 10^6 m
could return a neighbouring point. With ``ties = w > 0`` every disc hit within
``w`` times the depth the first disc spans along the ray (its radius over the
cosine of the incidence, at most 20 radii) beyond the first hit is a
candidate, and the answer is the one whose centre lies nearest the ray,
computed in float64 from the input coordinates, then the lowest index. One
query collects them: an Embree filter callback keeps each candidate within
the window of the nearest hit met so far and accepts it with the ray's end
moved to twice that window (Embree keeps a filter's tfar for an accepted
hit), so traversal culls nothing the rule needs, even when a nearer hit met
later has a slightly wider window (a disc at the same distance, another
normal). A ray whose nearer hit widens the window past what was already
culled, or with more than 64 candidates, is queried again over its window;
``one_pass=False`` does that for every ray (the rule of earlier versions,
the same answers). On a sampled surface that is the
point in the ray's own pulse, whichever larger neighbouring disc happens to be
met first.

Discs holding the scanner
-------------------------
A disc whose centre lies within its own reach of the ray origin would be hit
by half of all rays at a tiny distance and hide the scene. ``skip_containing``
rejects hits on such discs (the same filter callback), so a scanner standing
among the points needs no rebuilt BVH.

Ray packets
-----------
Rays go to Embree in packets (``rtcIntersect4/8/16``; by default the widest
the CPU traces natively, ``packet=1`` one ray at a time): the same answers,
fewer descents of the BVH. Each ray carries its lane in its ``id``, and the
filter keeps that lane's state, whatever packet size Embree calls it with.

Struct layouts and enum values are those of the Embree 4 headers
(``rtcore_ray.h``, ``rtcore_common.h``, ``rtcore_scene.h``,
``rtcore_geometry.h``, ``rtcore_buffer.h``); tests check hits against
brute-force ray-disc and ray-triangle intersection.
"""

from .library import embree_available, embree_library
from .open3d_scene import Open3DScene
from .cast import CELLS_AND_SILHOUETTES, CELLS_OFF, CELLS_ONLY, silhouette_bit
from .scene import RayHits, RayScene, disc_vertices, padded_rows

__all__ = ["silhouette_bit", "RayScene", "RayHits", "Open3DScene", "embree_library", "embree_available", "padded_rows",
           "disc_vertices", "CELLS_OFF", "CELLS_AND_SILHOUETTES", "CELLS_ONLY"]
