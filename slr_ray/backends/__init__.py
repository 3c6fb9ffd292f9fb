"""Subsampling backends behind :func:`slr_ray.simulate_scan`.

A backend is a function ``(points, origin, pattern, **options) -> Scan`` taking
checked float arrays. Backends that need an optional library import it on
first use, so ``import slr_ray`` never fails because of one.
"""

from __future__ import annotations

from enum import Enum

from ..errors import InputValueError

__all__ = ["Backend", "get_backend", "available_backends"]


class Backend(str, Enum):
    """Names of the subsampling backends."""

    BINNING = "binning"
    EMBREE = "embree"


def get_backend(name):
    """The scan function of backend ``name`` (a :class:`Backend` or its value)."""
    try:
        name = Backend(name)
    except ValueError:
        raise InputValueError(
            f"unknown backend {name!r}; choose one of {[b.value for b in Backend]}"
        ) from None
    if name is Backend.BINNING:
        from ..scan import _binning

        return _binning
    from .embree import scan_points

    return scan_points


def available_backends() -> list[str]:
    """Backends whose dependencies import on this machine."""
    import importlib.util

    out = [Backend.BINNING.value]
    if importlib.util.find_spec("embreex") is not None:
        out.append(Backend.EMBREE.value)
    return out
