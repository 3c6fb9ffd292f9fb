"""Heavy third-party libraries loaded on first use of one of their names.

``trimesh = module("trimesh")`` at the top of a module binds a stand-in that
imports the library the first time one of its names is read
(``trimesh.Trimesh``), then holds the library's names itself. A command that
never meshes, draws or builds a k-d tree does not pay for the import:
``slr-ray --help`` and the quick commands start without trimesh, the figures'
library, scipy's signal, ndimage and spatial packages (``import slr_ray.cli``:
7.9 s to 3.7 s on a loaded 2-core machine, about half; numba's import and
the ray engine's compiled callback stay). A library's own errors (it is not
installed) surface at first use, naming it.
"""

from __future__ import annotations

import importlib
import types

__all__ = ["module", "LazyModule"]


class LazyModule(types.ModuleType):
    """A library (``name``, dotted for a submodule) imported the first time one of its names is read."""

    def __getattr__(self, attr):
        if attr.startswith("__") and attr.endswith("__"):  # a probe (copy, pickle, inspect): not a use
            raise AttributeError(attr)
        real = importlib.import_module(self.__name__)
        self.__dict__.update({k: v for k, v in vars(real).items() if k not in ("__name__", "__spec__", "__loader__")})
        return getattr(real, attr)


def module(name: str) -> LazyModule:
    """A stand-in for the library ``name`` (module docstring)."""
    return LazyModule(name)
