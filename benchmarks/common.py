"""Shared helpers of the benchmark scripts: machine description, JSON output,
and the realistic 29 M-point cloud."""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"

# Measure the checkout this script belongs to, not whichever copy of slr_ray is
# installed (an editable install of another worktree would otherwise be timed).
_CHECKOUT = str(Path(__file__).resolve().parents[1])
if _CHECKOUT not in sys.path[:1]:
    sys.path.insert(0, _CHECKOUT)


def data_dir(start=None) -> Path:
    """The real-data directory (``shared/data``): ``$SLR_RAY_DATA`` where set, else the first
    ``shared/data`` found walking up from ``start`` (default this script's checkout): the main
    checkout's parent holds it, a git worktree's (``/work/wt/NAME``) lies a level further down. Where
    none is found, the path the main checkout's layout gives (the caller says it is absent)."""
    env = os.environ.get("SLR_RAY_DATA")
    if env:
        return Path(env)
    here = Path(start or _CHECKOUT).resolve()
    for d in (here, *here.parents):
        if (d / "shared" / "data").is_dir():
            return d / "shared" / "data"
    return here.parent / "shared" / "data"


def machine() -> dict:
    cpu = "unknown"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import numba
    import scipy

    mem = None
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        pass
    return {"cpu": cpu, "cores": len(os.sched_getaffinity(0)), "memory_gib": mem and round(mem, 1),
            "python": sys.version.split()[0], "platform": platform.platform(),
            "numpy": np.__version__, "numba": numba.__version__, "scipy": scipy.__version__,
            "date": time.strftime("%Y-%m-%d %H:%M:%S"), "checkout": _CHECKOUT}


def save(name: str, payload: dict) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps(payload, indent=2))
    print(f"saved {path}", file=sys.stderr)
    return path


def realistic_cloud(resolution: float = 0.029, n_rectangles: int = 1000, seed: int = 0):
    """A primary scan of a 1000-rectangle scene from (0, 0, 0): ground, objects,
    occlusion and sky, in scan order (about 29 M points at 0.029 deg, zenith
    0-135, 120 m: the size of a SYNS scan). Cached under results/."""
    from slr_ray import ScanPattern, scan_mesh
    from slr_ray.scenes import rectangle_scene

    cache = RESULTS / f"cloud_{n_rectangles}_{seed}_{resolution}.npy"
    if cache.exists():
        return np.load(cache, mmap_mode="r")  # slice what you need: the whole is 0.65 GiB
    scene = rectangle_scene(n_rectangles, seed=seed)
    ms = scan_mesh(scene, [0, 0, 0], ScanPattern(resolution, zenith_range=(0, 135), max_range=120),
                   progress=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    np.save(cache, ms.points)
    return ms.points


def run_isolated(script, args, key: str, name: str) -> dict:
    """Run ``script`` with ``args`` in a fresh Python process (so that its peak
    memory is its own); its last stdout line is a JSON object. Failures come
    back as ``{key: name, "error": ...}`` rather than stopping the benchmark."""
    import subprocess

    res = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True)
    if res.returncode:
        tail = " ".join(res.stderr.strip().splitlines()[-1:])
        return {key: name, "error": f"exit {res.returncode}: {tail}"}
    return json.loads(res.stdout.strip().splitlines()[-1])


def timed(fn, repeat: int = 3):
    """(best seconds, all seconds, last result)."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), times, out
