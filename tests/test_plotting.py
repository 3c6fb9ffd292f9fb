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


def test_cells_figure_reads_without_internal_names_or_an_axis_offset():
    # a UTM cloud: matplotlib wrote "+5.4012e6" above the y axis, and the title listed stage ids
    import numpy as np

    from slr_ray.plotting import cells_figure
    from slr_ray.positions import select_positions

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0, 40, 20_000), rng.uniform(0, 40, 20_000), np.zeros(20_000)])
    pts += [636_000.0, 5_401_200.0, 100.0]
    pos, cells = select_positions(pts, np.ones(len(pts), bool), 3, min_ground_points=50, return_cells=True)
    fig = cells_figure(cells, pos, pts)
    fig.canvas.draw()
    ax = fig.axes[0]
    assert ax.xaxis.get_offset_text().get_text() == "" and ax.yaxis.get_offset_text().get_text() == ""
    texts = [ax.get_title(), ax.get_xlabel(), ax.get_ylabel()] + [t.get_text() for t in ax.get_legend().get_texts()]
    assert not any("_" in t for t in texts), texts
    assert "5,401,200" in ax.get_ylabel()


def test_evaluation_figure_has_one_panel_a_method():
    # it drew each method's range image and its error: 11 thin panels for 5 methods, unreadable at a glance
    import numpy as np

    from slr_ray.plotting import evaluation_figure

    real = np.random.default_rng(0).uniform(1, 40, (8, 30))
    real[0, :5] = np.inf
    rows = [{"method": m, "label": m, "image": {"rmse": 0.1, "medae": 0.01, "accuracy": 0.9}} for m in "ab"]
    fig = evaluation_figure({"images": {"real": real, "a": real + 0.1, "b": real - 0.1}, "rows": rows})
    panels = [ax for ax in fig.axes if ax.get_images() and ax.get_title(loc="left")]
    assert len(panels) == 3
    assert "a: RMSE 0.10 m" in panels[1].get_title(loc="left")
