"""The chains of imports of a checkout, as tests/test_layout.py measures them (issue #39).

Prints and saves (results/layout_chains.json) the longest chain between modules, the longest
between units (a top-level module or a subpackage), and the deepest "uses" chain (units of the
simulation and uses layers, counted in units), each with its length and the chain itself.
Pass a checkout's root to measure another (``python benchmarks/layout_chains.py /path/to/checkout``).
The measures are the test's own functions, read from this checkout's tests/test_layout.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE))
import test_layout as layout  # noqa: E402
from common import save  # noqa: E402


def measure(root: Path) -> dict:
    layout.PKG = root / "slr_ray"
    graph = layout._import_graph()
    units = layout._unit_graph(graph)
    layers = dict(layout.LAYERS)
    computation = set().union(*(layers[name] for name in layout.COMPUTATION_LAYERS))
    out = {}
    for name, chain, edges in (("modules", layout._longest_chain(graph), True),
                               ("units", layout._longest_chain(units), True),
                               ("uses", layout._chain_within(units, computation), False)):
        # imports in a chain for the first two (the test's limit of 12); units in it for "uses" (limit 3)
        out[name] = {"length": len(chain) - 1 if edges else len(chain), "chain": chain}
    return out


def main():
    root = Path(sys.argv[1]).resolve() if len(sys.argv) > 1 else HERE.parent
    out = {"checkout": str(root), **measure(root)}
    for name in ("modules", "units", "uses"):
        print(f"{name}: {out[name]['length']}  {' -> '.join(out[name]['chain'])}")
    save("layout_chains", out)


if __name__ == "__main__":
    main()
