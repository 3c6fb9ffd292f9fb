"""True scans of a scene's secondary positions, made once and shared by its primaries.

A scene's primaries (0.0144 and 0.00576 deg) are compared with the same true
scans, as in the paper. A hundred of them are ~5 GB, too much to hold next to
a fine primary, so with more than one primary they wait on disk under
``.truths/<scene>/`` (which also serves a resume) and are removed when the
scene is done.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from ..io import atomic_path
from ..meshscan import scan_mesh

__all__ = ["TruthCache"]


class TruthCache:
    """True points of ``scene`` at position ``i`` with truth semantics ``t``.

    Parameters
    ----------
    scene : RectangleScene
    pattern : ScanPattern
        The secondary pattern.
    supersample : int
        Sub-rays per pulse side for the 'nearest' truth.
    spill : Path, optional
        Directory to keep them in between primaries (None: not kept).
    """

    def __init__(self, scene, pattern, supersample: int, spill: Path | None = None):
        self.scene, self.pattern, self.supersample, self.spill = scene, pattern, supersample, spill

    def __call__(self, i: int, position, truth: str) -> np.ndarray:
        path = self.spill / f"{i}-{truth}.npy" if self.spill is not None else None
        if path is not None and path.exists():
            return np.load(path)
        pts = scan_mesh(self.scene, position, self.pattern, mode=truth, supersample=self.supersample).points
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp:
                np.save(tmp, pts)
        return pts

    def clear(self) -> None:
        """Forget every kept true scan (positions were redrawn, or the scene is done)."""
        if self.spill is not None and self.spill.exists():
            shutil.rmtree(self.spill)
