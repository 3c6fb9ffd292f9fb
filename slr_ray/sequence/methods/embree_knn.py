"""``embree-knn``: the embree backend on the union with its defaults (kNN discs)."""

from __future__ import annotations

from ..estimators import embree_returns
from .base import SequenceMethod

__all__ = ["EmbreeKnn", "METHOD"]


class EmbreeKnn(SequenceMethod):
    """Discs of the union's points (k nearest neighbours' normals and spacing), cast by Embree."""

    name = "embree-knn"
    label = "embree kNN discs (union)"

    def returns(self, points, pattern, options):
        return embree_returns(points, pattern)


METHOD = EmbreeKnn()
