"""Which rows a run still has to make, and the secondary positions they are made at.

Positions are drawn once per scene (on the scene's positions primary) and
saved to ``positions/<scene>.csv`` with a tag line naming the draw (count,
seed, ground-support threshold), so a resumed run never rescans a primary
only to redraw them. Draws are prefix-consistent: the first N of a draw of M
> N positions are the draw of N, so a file drawn for more serves a run that
asks for fewer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import ValidationConfig
from .results import row_key

__all__ = ["ScenePlan", "plan", "positions_file", "positions_tag", "load_positions"]


@dataclass
class ScenePlan:
    """The work left on one scene of a config.

    Attributes
    ----------
    spec : str
        Scene spec.
    resolutions : list of float
        The scene's primaries, in config order.
    backends : list of str
    todo : dict
        Primary resolution -> positions (indices) with a row still missing.
    positions_resolution : float
        The primary the positions are drawn on.
    """

    spec: str
    resolutions: list
    backends: list
    todo: dict
    positions_resolution: float

    @property
    def done(self) -> bool:
        return not any(self.todo.values())

    def passes(self) -> list:
        """Primaries in the order they are scanned: the positions' one first."""
        return [self.positions_resolution] + [r for r in self.resolutions if r != self.positions_resolution]


def plan(config: ValidationConfig, done: dict) -> list:
    """A :class:`ScenePlan` per scene entry of ``config``, given the rows already ``done``."""
    out = []
    for entry in config.scenes:
        spec, resolutions = config.scene_entry(entry)
        backends = config.scene_backends(entry)
        todo = {res: [i for i in range(config.positions)
                      if any(row_key(spec, res, i, b, t) not in done for b, t in config.wanted(res, i, backends))]
                for res in resolutions}
        out.append(ScenePlan(spec, resolutions, backends, todo,
                             float(config.positions_resolution or resolutions[0])))
    return out


def positions_file(outdir, spec: str) -> Path:
    return Path(outdir) / "positions" / (Path(spec).stem + ".csv")


def positions_tag(config: ValidationConfig, n: int) -> str:
    return f"# positions={n} seed={config.seed} min_ground_points={config.min_ground_points}"


def load_positions(path: Path, config: ValidationConfig):
    """Positions saved by an earlier run of the same draw, or None (draw again)."""
    if not path.exists():
        return None
    head = path.read_text().split("\n", 1)[0]
    try:
        n = int(head.split()[1].split("=")[1])
    except (IndexError, ValueError):
        return None
    if head != positions_tag(config, n) or n < config.positions:
        return None
    return np.loadtxt(path, delimiter=",", ndmin=2)[: config.positions]
