"""Figures are built without pyplot and without switching matplotlib's backend."""

import subprocess
import sys
import textwrap


def test_figures_do_not_touch_pyplot_or_the_backend(tmp_path):
    code = textwrap.dedent(f"""
        import sys, matplotlib
        before = matplotlib.get_backend()
        import numpy as np
        from slr_ray.compare import compare_backends
        from slr_ray.plotting import comparison_figure, save_figure
        from matplotlib.figure import Figure
        pts = np.random.default_rng(0).normal(size=(2000, 3)) * 5
        res = compare_backends(pts, [[0, 0, 0]], 2.0, embree_options={{"radius": 0.2}})
        fig = comparison_figure(res)
        assert isinstance(fig, Figure)
        save_figure(fig, r"{tmp_path / 'c.png'}")
        assert "matplotlib.pyplot" not in sys.modules, "pyplot was imported"
        assert matplotlib.get_backend() == before, (before, matplotlib.get_backend())
    """)
    subprocess.run([sys.executable, "-c", code], check=True, env={"MPLBACKEND": "svg", "PATH": ""})
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
