"""Heavy third-party libraries loaded on first use of one of their names.

``trimesh = module("trimesh")`` at the top of a module binds a stand-in that
imports the library the first time one of its names is read
(``trimesh.Trimesh``), then holds the library's names itself. A command that
never meshes, draws or builds a k-d tree does not pay for the import:
``slr-ray --help`` and the quick commands start without trimesh, the figures'
library, scipy's signal, ndimage and spatial packages, laspy (and the
``requests`` it loads) (``import slr_ray.cli``:
7.9 s to 3.7 s on a loaded 2-core machine, about half; numba's import and
the ray engine's compiled callback stay). A library's own errors (it is not
installed) surface at first use, naming it.

``@cfunc(signature, cache=True, ...)`` is ``numba.cfunc`` made on first use: a
C callback is compiled (or loaded from numba's cache) where it is defined, and
that sets up numba's compiler (``numba.np`` with scipy.linalg, most of a
second). The ray engine's Embree filter is made on the first cast instead of
at ``import slr_ray`` (``import slr_ray.cli``, with laspy lazy too: 1.7 s to 0.9 s of CPU, loaded 2-core
machine); ``FILTER.address`` (and every other attribute of numba's
``CFunc``) reads the compiled callback, as before.
"""

from __future__ import annotations

import functools
import importlib
import threading
import types

__all__ = ["module", "LazyModule", "cfunc", "LazyCFunc"]


class LazyModule(types.ModuleType):
    """A library (``name``, dotted for a submodule) imported the first time one of its names is read."""

    def __getattr__(self, attr):
        if attr.startswith("__") and attr.endswith("__"):  # a probe (copy, pickle, inspect): not a use
            raise AttributeError(attr)
        # the library's name as it is now, each time (no copy: a test's monkeypatch of the library is seen)
        return getattr(importlib.import_module(self.__name__), attr)


def module(name: str) -> LazyModule:
    """A stand-in for the library ``name`` (module docstring)."""
    return LazyModule(name)



class LazyCFunc:
    """``numba.cfunc(signature, **options)(function)``, made the first time one of its attributes is read
    (``address``, ``ctypes``, ...: numba's ``CFunc``'s), once, whichever thread reads first."""

    def __init__(self, function, signature, options):
        functools.update_wrapper(self, function)
        self._signature, self._options = signature, options
        self._made = None
        self._making = threading.Lock()

    def compiled(self):
        """numba's ``CFunc``, compiled or loaded from the cache on the first call."""
        with self._making:
            if self._made is None:
                numba = importlib.import_module("numba")
                self._made = numba.cfunc(self._signature, **self._options)(self.__wrapped__)
        return self._made

    def __getattr__(self, attr):
        if attr.startswith("__") and attr.endswith("__") or attr.startswith("_"):  # a probe, or not set yet
            raise AttributeError(attr)
        return getattr(self.compiled(), attr)


def cfunc(signature, **options):
    """``numba.cfunc`` made on first use (module docstring): ``@cfunc(types.void(types.voidptr), cache=True)``."""
    return lambda function: LazyCFunc(function, signature, options)
