import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

# The suite is deterministic by default ("same seed, same result" holds for the
# tests too): hypothesis draws the same examples on every run and CI cannot fail
# by chance. HYPOTHESIS_PROFILE=explore draws new random examples on every run,
# for a developer hunting edge cases.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

from slr_ray.core import BinTables


def shared_data(start=None) -> Path:
    """The real-data directory (``shared/data``), by the rule of ``benchmarks/common.py``'s
    ``data_dir``: ``$SLR_RAY_DATA`` where set, else the first ``shared/data`` found walking up from
    ``start`` (default this checkout): the main checkout's parent holds it, a git worktree's
    (``/work/wt/NAME``) lies a level further down. Where none is found (CI), the path the main
    checkout's layout gives, which does not exist: the tests that need it skip."""
    env = os.environ.get("SLR_RAY_DATA")
    if env:
        return Path(env)
    here = Path(start or Path(__file__).resolve().parents[1]).resolve()
    for d in (here, *here.parents):
        if (d / "shared" / "data").is_dir():
            return d / "shared" / "data"
    return here.parent / "shared" / "data"


#: the real data of every test that reads it (absent on CI: those tests skip)
DATA = shared_data()


def brute_grid_neighbours(keys, ranges, shape, gate):
    """The pulse-grid neighbour rule by Python loops, the reference the embree tests share:
    per point (``keys``: its flat pulse id, -1 outside; ``shape``: ``(nv, nh)``), the
    neighbour chosen in each adjacent pulse ``(dv, dh)`` (within the range gate, the nearest
    to the scanner, then the lowest index; azimuth wraps, zenith does not)."""
    nv, nh = shape
    by_key = {}
    for i, k in enumerate(keys):
        by_key.setdefault(int(k), []).append(i)
    out = []
    for i, k in enumerate(keys):
        chosen = {}
        out.append(chosen)
        if k < 0:
            continue
        v, h = divmod(int(k), nh)
        for dv in (-1, 0, 1):
            for dh in (-1, 0, 1):
                if (dv, dh) == (0, 0) or not 0 <= v + dv < nv:
                    continue
                cand = [q for q in by_key.get((v + dv) * nh + (h + dh) % nh, [])
                        if abs(ranges[q] - ranges[i]) <= gate * ranges[i]]
                if cand:
                    chosen[dv, dh] = min(cand, key=lambda q: (ranges[q], q))
    return out


def brute_force_scan(points, origin, pattern):
    """Nearest-in-pulse by a plain loop: the definition, written the slow way."""
    from slr_ray import pulse_bins

    v, h, r, vis = pulse_bins(points, origin, pattern)
    best = {}
    for i in range(len(points)):
        if not vis[i]:
            continue
        key = (int(v[i]), int(h[i]))
        if key not in best or r[i] < best[key][0]:  # ties keep the lower index
            best[key] = (r[i], i)
    return np.array(sorted(i for _, i in best.values()), dtype=np.intp)


@pytest.fixture(params=["dense", "slots", "shared-slots", "hash"])
def table_kind(request, monkeypatch):
    """Run a test with each kind of binning table ("slots": a slot array per
    thread; "shared-slots": one for all threads)."""
    monkeypatch.setattr(BinTables, "dense_bytes", 2**62 if request.param == "dense" else 0)
    monkeypatch.setattr(BinTables, "slot_bytes", 2**62 if request.param.endswith("slots") else 0)
    monkeypatch.setattr(BinTables, "own_slots", request.param == "slots")
    return request.param


def scene_cloud(n=20000, seed=0, origin=(0.0, 0.0, 0.0)):
    """A small realistic cloud: ground plane 1.65 m below, boxes and noise around."""
    rng = np.random.default_rng(seed)
    g = rng.uniform(-30, 30, size=(n // 2, 2))
    ground = np.column_stack([g, np.full(len(g), -1.65)])
    walls = np.column_stack([
        rng.uniform(5, 6, n // 4), rng.uniform(-5, 5, n // 4), rng.uniform(-1.65, 3, n // 4)
    ])
    rest = rng.normal(scale=8, size=(n - len(ground) - len(walls), 3))
    return np.vstack([ground, walls, rest]) + np.asarray(origin)


@pytest.fixture
def las_reads(monkeypatch):
    """Points read through each ``laspy.open(...).chunk_iterator`` while a test
    runs, one entry per pass over a file: ``len(las_reads)`` counts the passes."""
    import laspy

    opened = laspy.open
    reads = []

    class Counting:
        def __init__(self, reader):
            self.reader = reader

        def __enter__(self):
            self.reader.__enter__()
            return self

        def __exit__(self, *exc):
            return self.reader.__exit__(*exc)

        def __getattr__(self, name):
            return getattr(self.reader, name)

        def chunk_iterator(self, n):
            reads.append(0)
            for pts in self.reader.chunk_iterator(n):
                reads[-1] += len(pts)
                yield pts

    monkeypatch.setattr(laspy, "open", lambda *a, **k: Counting(opened(*a, **k)))
    return reads


class CliRun:
    """``slr-ray ARGS...`` in this process: ``CliRun(capsys)(*args)`` gives ``returncode``, ``stdout``
    and ``stderr`` (what the command printed, nothing from before)."""

    def __init__(self, capsys):
        self.capsys = capsys

    def __call__(self, *args):
        from types import SimpleNamespace

        from slr_ray.cli import main

        self.capsys.readouterr()
        rc = main([str(a) for a in args])
        out = self.capsys.readouterr()
        return SimpleNamespace(returncode=rc, stdout=out.out, stderr=out.err)
