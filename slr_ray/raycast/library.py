"""The Embree 4 shared library, through ctypes: looked up and loaded once per process.

Looked up in order: ``$SLR_RAY_EMBREE``; the ``libembree4`` shipped in the
``embreex`` wheel; the system's ``embree4``. Enum values are those of the
Embree 4 headers (``rtcore_common.h``, ``rtcore_scene.h``,
``rtcore_geometry.h``, ``rtcore_buffer.h``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import threading

from ..errors import EngineError, MissingDependencyError

__all__ = ["EmbreeLibrary", "embree_library", "embree_available"]

# --- Embree 4 constants (rtcore_geometry.h, rtcore_buffer.h, rtcore_common.h, rtcore_scene.h)
GEOMETRY_TRIANGLE = 0
GEOMETRY_DISC_POINT = 51
GEOMETRY_ORIENTED_DISC_POINT = 52
BUFFER_INDEX = 0
BUFFER_VERTEX = 1
BUFFER_NORMAL = 3
FORMAT_UINT3 = 0x5003
FORMAT_FLOAT3 = 0x9003
FORMAT_FLOAT4 = 0x9004
SCENE_FLAG_DYNAMIC = 1 << 0  # with a low build quality: Embree's quick (Morton) BVH build
SCENE_FLAG_COMPACT = 1 << 1  # compact acceleration structures (less memory, a slower build)
SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS = 1 << 3
RAY_QUERY_FLAG_INVOKE_ARGUMENT_FILTER = 1 << 1
FEATURE_FLAGS_ALL = 0xFFFFFFFF
INVALID_ID = 0xFFFFFFFF
BUILD_QUALITY_LOW = 0

_lock = threading.Lock()
_lib = None


class EmbreeLibrary:
    """The Embree 4 C functions slr_ray uses, through ctypes (handles as integers)."""

    def __init__(self, path: str):
        lib = ctypes.CDLL(path)
        P, U, I = ctypes.c_size_t, ctypes.c_uint, ctypes.c_int

        def fn(name, res, *args):
            f = getattr(lib, name)
            f.restype, f.argtypes = res, list(args)
            return f

        self.path = path
        self.new_device = fn("rtcNewDevice", P, ctypes.c_char_p)
        self.release_device = fn("rtcReleaseDevice", None, P)
        self.device_error = fn("rtcGetDeviceError", I, P)
        self.new_scene = fn("rtcNewScene", P, P)
        self.release_scene = fn("rtcReleaseScene", None, P)
        self.set_scene_flags = fn("rtcSetSceneFlags", None, P, I)
        self.commit_scene = fn("rtcCommitScene", None, P)
        self.set_scene_build_quality = fn("rtcSetSceneBuildQuality", None, P, I)
        self.set_geometry_build_quality = fn("rtcSetGeometryBuildQuality", None, P, I)
        self.new_geometry = fn("rtcNewGeometry", P, P, I)
        self.set_shared_buffer = fn("rtcSetSharedGeometryBuffer", None, P, I, U, I, P, P, P, P)
        self.commit_geometry = fn("rtcCommitGeometry", None, P)
        self.attach_geometry = fn("rtcAttachGeometry", U, P, P)
        self.release_geometry = fn("rtcReleaseGeometry", None, P)
        self.get_device_property = fn("rtcGetDeviceProperty", ctypes.c_ssize_t, P, I)
        #: addresses of rtcIntersect1, 4, 8, 16 by packet width
        self.intersect = {w: ctypes.cast(getattr(lib, f"rtcIntersect{w}"), ctypes.c_void_p).value for w in (1, 4, 8, 16)}
        self.intersect1 = self.intersect[1]
        self.device = self.new_device(None)
        if not self.device:
            raise MissingDependencyError(f"Embree at {path} could not create a device")
        #: the widest packet this CPU's Embree kernels trace natively (RTC_DEVICE_PROPERTY_NATIVE_RAY4/8/16_SUPPORTED),
        #: 1 if none
        self.native_width = max([w for w, prop in ((4, 32), (8, 33), (16, 34))
                                 if self.get_device_property(self.device, prop)] or [1])

    def check(self, what: str):
        code = self.device_error(self.device)
        if code:
            raise EngineError(f"Embree error {code} in {what}")


def _candidates():
    env = os.environ.get("SLR_RAY_EMBREE")
    if env:
        yield env
    try:
        import embreex
    except ImportError:
        embreex = None
    if embreex is not None:
        libs = os.path.join(os.path.dirname(os.path.dirname(embreex.__file__)), "embreex.libs")
        yield from sorted(glob.glob(os.path.join(libs, "libembree4*.so*")))
        yield from sorted(glob.glob(os.path.join(os.path.dirname(embreex.__file__), "libembree4*")))
    found = ctypes.util.find_library("embree4")
    if found:
        yield found


def embree_library() -> EmbreeLibrary:
    """The Embree 4 library, loaded once per process.

    Looked up in order: ``$SLR_RAY_EMBREE``; the ``libembree4`` shipped in the
    ``embreex`` wheel; the system's ``embree4``.

    Raises
    ------
    MissingDependencyError
        when none loads (with the install command).
    """
    global _lib
    with _lock:
        if _lib is None:
            tried = []
            for path in _candidates():
                try:
                    _lib = EmbreeLibrary(path)
                    break
                except (OSError, AttributeError) as exc:
                    tried.append(f"{path}: {exc}")
            else:
                raise MissingDependencyError(
                    "ray casting needs the Embree 4 library: pip install embreex "
                    "(its wheel ships libembree4), or set SLR_RAY_EMBREE to a libembree4.so"
                    + (f"; tried {'; '.join(tried)}" if tried else ""))
        return _lib


def embree_available() -> bool:
    """Whether :func:`embree_library` finds a library (never raises)."""
    try:
        embree_library()
    except MissingDependencyError:
        return False
    return True
