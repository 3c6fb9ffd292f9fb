"""Every figure slr_ray draws, as :class:`matplotlib.figure.Figure` objects.

No function here touches pyplot's global state or calls ``matplotlib.use``:
each builds a ``Figure`` directly, so a notebook user's backend is left as it
is, figures can be drawn from threads, and nothing stays open. Show one in a
notebook by leaving it as a cell's value, or write it with
:func:`save_figure` (atomically, PNG by default).

>>> from slr_ray.plotting import comparison_figure, save_figure  # doctest: +SKIP
>>> save_figure(comparison_figure(result), "compare.png")         # doctest: +SKIP
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import lazy
from .errors import InputTypeError, InputValueError
from .io import atomic_path
from .metrics import full_pairs, series
from .paper import NEAR_DISTANCE, PRIMARY_RESOLUTION, PRIMARY_RESOLUTION_FINE, Q1_SCENES, Q2_SCENES

#: the figures' library, loaded when a figure is made (slr_ray.lazy: a command that draws nothing skips it)
mpl = lazy.module("matplotlib")
mpl_figure, mpl_lines, mpl_patches = (lazy.module(f"matplotlib.{m}") for m in ("figure", "lines", "patches"))
mpl_backends = lazy.module("matplotlib.backend_bases")

__all__ = ["save_figure", "check_figure_path", "validation_figure", "paper_figure", "comparison_figure", "demo_figure",
           "distances_figure", "cells_figure", "range_image_figure", "evaluation_figure"]

DPI = 110


def _figure(**kw):
    return mpl_figure.Figure(**kw)


def check_figure_path(path) -> str:
    """The figure format of ``path`` (its extension, default ``'png'``).

    Raises
    ------
    InputValueError
        for an extension matplotlib cannot write: checked before any work
        (:class:`~slr_ray.io.outputs.OutputPlan` runs it), not after it.
    """
    fmt = Path(path).suffix[1:].lower() or "png"
    known = mpl_backends.FigureCanvasBase.get_supported_filetypes()
    if fmt not in known:
        raise InputValueError(f"{path}: cannot write a figure as {fmt!r}; formats: {', '.join(sorted(known))}")
    return fmt


def save_figure(fig, path, dpi: int = DPI) -> None:
    """Write ``fig`` to ``path`` atomically (format from the extension, default PNG)."""
    path = Path(path)
    fmt = check_figure_path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=fmt)


def _binned_means(d, s, edges):
    """Bin centres and mean of ``s`` in each bin of ``d`` that has a finite value."""
    mids, means = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (d >= lo) & (d < hi) & np.isfinite(s)
        if m.any():
            mids.append((lo + hi) / 2)
            means.append(float(s[m].mean()))
    return mids, means


def _rows_of(rows):
    """The records a validation figure draws (figures read no files: :mod:`slr_ray.validation` reads them)."""
    if isinstance(rows, (str, Path)):
        raise InputTypeError(f"a validation figure takes a run's rows, not a file ({rows}): "
                             "slr_ray.validation.load_rows(path) reads them")
    rows = list(rows.values() if isinstance(rows, dict) else rows)  # read_rows' dict by key, or the rows
    if not rows:
        raise InputValueError("no rows to plot")
    return rows


def validation_figure(rows):
    """Figures like the paper's Figure 3 for any validation run.

    Top: (a) similarity (coverage) against scanner distance, (b) by number of
    rectangles, (c) by primary resolution; one series per backend and truth
    semantics. Bottom: the same for precision (the share of SLR points within
    the threshold of a true point), where the rows record it.

    Parameters
    ----------
    rows : list of dict
        Rows of a ``results.csv``, as :func:`slr_ray.validation.load_rows` reads them.
    """
    rows = _rows_of(rows)
    have_precision = any(r.get("precision") not in (None, "") for r in rows)
    fig = _figure(figsize=(16, 9.2 if have_precision else 4.6))
    ax = fig.subplots(2 if have_precision else 1, 3, squeeze=False)
    edges = np.arange(0, 105, 5.0)
    metrics = [("similarity", "similarity (coverage, %)")] + ([("precision", "precision (%)")] if have_precision
                                                               else [])
    for row_i, (metric, ylabel) in enumerate(metrics):
        axes = ax[row_i]
        for b, t in sorted({(r["backend"], r["truth"]) for r in rows}):
            rr = [r for r in rows if r["backend"] == b and r["truth"] == t]
            d = np.array([float(r["distance_m"]) for r in rr])
            s = 100 * np.array([float(r[metric]) if r.get(metric) not in (None, "") else np.nan for r in rr])
            label = f"{b} vs {t} truth"
            axes[0].scatter(d, s, s=6, alpha=0.4)
            axes[0].plot(*_binned_means(d, s, edges), "-", label=label)
            for k, key in ((1, "n_rectangles"), (2, "primary_resolution")):
                for g in sorted({float(r[key]) for r in rr}):
                    m = np.array([float(r[key]) == g for r in rr])
                    axes[k].plot(*_binned_means(d[m], s[m], edges), "o-", ms=3,
                                 label=f"{label}, {key.replace('_', ' ')} {g:g}")
        axes[0].axvline(NEAR_DISTANCE, ls=":", c="gray")
        axes[0].axhline(90, ls=":", c="gray")
        titles = [f"(a) {metric} vs scanner distance", "(b) by number of rectangles", "(c) by primary resolution"]
        for a, title in zip(axes, titles):
            a.set(xlabel="distance from primary scanner (m)", ylabel=ylabel, ylim=(0, 101), title=title)
            if a.get_legend_handles_labels()[0]:
                a.legend(fontsize=7)
    fig.tight_layout()
    return fig


def paper_figure(rows, backend: str = "binning", truth: str = "center"):
    """The paper's Figure 3 from a ``validate-paper`` run, for one backend and truth.

    (a) question 1, similarity against scanner distance over the five
    1000-rectangle scenes; (b) question 2, one line per number of rectangles;
    (c) question 3, the same with the 0.00576 deg primaries (solid) over the
    0.0144 deg ones (dotted); (d) every backend and truth semantics on the
    positions where all were run; (e) precision against distance for the
    series of (a) and (b), where the rows record it. Lines are means in 5 m bins.
    ``rows``: a run's rows, as :func:`slr_ray.validation.load_rows` reads them.
    """
    rows = _rows_of(rows)
    have_precision = any(r.get("precision") not in (None, "") for r in rows)
    n = 5 if have_precision else 4
    fig = _figure(figsize=(5 * n, 4.6))
    ax = fig.subplots(1, n)
    edges = np.arange(0, 50, 5.0)

    def binned(d, s):
        return _binned_means(d, 100 * s, edges)

    d, s, p = series(rows, Q1_SCENES, PRIMARY_RESOLUTION, backend, truth)
    ax[0].scatter(d, 100 * s, s=7, alpha=0.5, c="C0", label=f"{len(d)} pairs")
    ax[0].plot(*binned(d, s), "k-", label="mean in 5 m bins")
    if have_precision:
        ax[4].plot(*binned(d, p), "k-", label="question 1 (1000 rectangles)")
    for k, sc in enumerate(Q2_SCENES):
        n_rect = next((r["n_rectangles"] for r in rows if r["scene"] == sc), sc)
        for a, res, ls in ((ax[1], PRIMARY_RESOLUTION, "o-"), (ax[2], PRIMARY_RESOLUTION, ":"), (ax[2], PRIMARY_RESOLUTION_FINE, "o-")):
            d, s, p = series(rows, [sc], res, backend, truth)
            if len(d):
                lab = f"{n_rect} rectangles" + (f", {res:g}°" if a is ax[2] else "")
                a.plot(*binned(d, s), ls, ms=3, c=f"C{k}", label=lab)
                if have_precision and a is not ax[1]:
                    ax[4].plot(*binned(d, p), ls, ms=3, c=f"C{k}", label=f"{n_rect} rectangles, {res:g}°")
    names = sorted({(r["backend"], r["truth"]) for r in rows})
    if len(names) > 1:
        full = full_pairs(rows, PRIMARY_RESOLUTION, names)
        for k, (b, t) in enumerate(names):
            d, s, _ = series(rows, None, PRIMARY_RESOLUTION, b, t, full)
            if len(d):
                ax[3].plot(*binned(d, s), "o-", ms=3, c=f"C{k}", label=f"{b} vs {t} truth ({len(d)} pairs)")
    for a in ax[:3]:
        a.axvline(NEAR_DISTANCE, ls=":", c="gray")
        a.axhline(90, ls=":", c="gray")
    titles = ["(a) distance: five 1000-rectangle scenes", f"(b) occlusion ({PRIMARY_RESOLUTION:g}° primaries)",
              "(c) primary resolution", f"(d) backends and truths, same pairs ({PRIMARY_RESOLUTION:g}°)",
              "(e) precision: SLR points near a true point"]
    for a, title in zip(ax, titles):
        a.set(xlabel="distance from primary scanner (m)", title=title,
              ylabel="precision (%)" if title.startswith("(e)") else "similarity (%)",
              ylim=(60, 101) if a is not ax[0] else (0, 101), xlim=(0, edges[-1]))
        if a.get_legend_handles_labels()[0]:
            a.legend(fontsize=7, loc="lower left")
    fig.suptitle(f"SLR validation: {backend} SLR scans vs {truth} truth")
    fig.tight_layout()
    return fig


def comparison_figure(result: dict):
    """Per range band, Jaccard index and see-through fraction of binning vs
    embree, one line per position (``result`` of :func:`slr_ray.compare.compare_backends`)."""
    fig = _figure(figsize=(11, 4.2))
    ax = fig.subplots(1, 2)
    for i, pos in enumerate(result["positions"]):
        mids = [b["band_m"][0] for b in pos["bands"]]
        jac = [b["jaccard"] if b["jaccard"] is not None else np.nan for b in pos["bands"]]
        see = [b["see_through"] / b["binning"] if b["binning"] else np.nan for b in pos["bands"]]
        ax[0].plot(mids, jac, "o-", label=f"position {i}")
        ax[1].plot(mids, 100 * np.array(see), "o-", label=f"position {i}")
    ax[0].set(xlabel="range band start (m)", ylabel="Jaccard index (binning vs embree)", ylim=(0, 1.02))
    ax[1].set(xlabel="range band start (m)", ylabel=f"see-through binning returns (%, > {result['tolerance']} m)")
    ax[0].legend(fontsize=8)
    fig.suptitle(f"binning vs embree, {result['n_points']:,} points, {result['pattern']['azimuth_resolution']} deg")
    fig.tight_layout()
    return fig


def demo_figure(primary, positions, rows, n_rectangles: int):
    """The demo's figure: the primary scan from above with the SLR positions
    numbered as in the demo's table and files (``position_01``...), and
    coverage and precision of each SLR scan against its true scan, per backend.

    ``rows`` carry ``number`` (1, 2, ...), ``distance_m``, ``backend``,
    ``similarity`` and ``precision``."""
    fig = _figure(figsize=(12, 5.5))
    ax = fig.subplots(1, 2)
    pts = primary.points
    step = max(1, len(pts) // 200_000)
    objects = primary.labels[::step] > 0
    colours = {"ground": "#9db4d8", "objects (rectangles)": "#c0392b"}
    ax[0].scatter(pts[::step, 0], pts[::step, 1], s=0.1, rasterized=True,
                  c=np.where(objects, colours["objects (rectangles)"], colours["ground"]))
    ax[0].scatter(positions[:, 0], positions[:, 1], marker="^", c="k", s=60, zorder=3)
    for i, p in enumerate(positions, 1):
        ax[0].annotate(str(i), p[:2], xytext=(5, 5), textcoords="offset points", fontsize=11, fontweight="bold",
                       bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8})
    ax[0].scatter([0], [0], marker="*", c="gold", s=150, edgecolor="k", zorder=3)
    handles = [mpl_patches.Patch(color=c, label=k) for k, c in colours.items()] + [
        mpl_lines.Line2D([], [], ls="", marker="^", c="k", label="SLR positions (numbered)"),
        mpl_lines.Line2D([], [], ls="", marker="*", c="gold", mec="k", ms=12, label="primary scanner")]
    ax[0].legend(handles=handles, loc="upper right", fontsize=8)
    ax[0].set(xlim=(-60, 60), ylim=(-60, 60), aspect="equal", xlabel="x (m)", ylabel="y (m)",
              title=f"primary scan, top view ({n_rectangles} rectangles)")
    backends = sorted({r.get("backend", "binning") for r in rows})
    values = []
    for k, b in enumerate(backends):
        rr = [r for r in rows if r.get("backend", "binning") == b]
        d = [r["distance_m"] for r in rr]
        cov = [100 * r["similarity"] for r in rr]
        ax[1].plot(d, cov, "o", c=f"C{k}", ms=8, label=f"{b}: coverage")
        values += cov
        if all("precision" in r for r in rr):
            prec = [100 * r["precision"] for r in rr]
            ax[1].plot(d, prec, "x", c=f"C{k}", ms=8, mew=2, label=f"{b}: precision")
            values += prec
    for r in rows:  # the position's number once, above its points
        if r.get("backend", "binning") == backends[0] and "number" in r:
            ax[1].annotate(str(r["number"]), (r["distance_m"], 100), xytext=(0, -12), textcoords="offset points",
                           ha="center", fontsize=11, fontweight="bold")
    ax[1].axhline(90, ls=":", c="gray", label="90 %: the paper's similarity below 17.5 m")
    low = min([90.0, *values])
    ax[1].set(xlabel="distance from primary scanner (m)", ylabel="% within 10 cm",
              ylim=(max(0.0, 5 * np.floor(low / 5) - 5), 101), title="SLR scan vs true scan, by position")
    d = [r["distance_m"] for r in rows]
    if d:
        ax[1].set_xlim(min(d) - 1.5, max(d) + 1.5)
    ax[1].legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    return fig


def distances_figure(original, slr, sweep, max_distance: float = 40.0):
    """The paper's Figure 4 panels: (a) original clouds, (b) SLR clouds, (c)
    ground by scanner height, (d) non-ground by scanner height
    (:class:`~slr_ray.distances.DistanceHistogram` each; ``None`` hides a panel)."""
    fig = _figure(figsize=(11, 8))
    ax = fig.subplots(2, 2)
    for a, h, title in ((ax[0, 0], original, "(a) original clouds"), (ax[0, 1], slr, "(b) SLR clouds")):
        if h is None:
            a.set_visible(False)
            continue
        for kind in h.counts:  # the kinds of slr_ray.distances.KINDS, in its order
            a.stairs(h.density(kind), h.edges, label=f"{kind.replace('_', '-')} (peak {h.peak(kind):.1f} m)")
        a.set(title=f"{title}, {h.n_scans} scans", xlim=(0.3, max_distance), xscale="log")
    if sweep:
        cmap = mpl.colormaps["viridis"]
        for i, (height, h) in enumerate(sorted(sweep.items())):
            c = cmap(i / max(1, len(sweep) - 1))
            for a, kind in ((ax[1, 0], "ground"), (ax[1, 1], "non_ground")):
                a.stairs(h.density(kind), h.edges, color=c, label=f"{height:g} m (peak {h.peak(kind):.1f} m)")
        ax[1, 0].set(title="(c) ground, by scanner height", xlim=(0.3, max_distance), xscale="log")
        ax[1, 1].set(title="(d) non-ground, by scanner height", xlim=(0.3, max_distance), xscale="log")
    else:
        ax[1, 0].set_visible(False)
        ax[1, 1].set_visible(False)
    for a in ax.ravel():
        a.set(xlabel="distance (m, log)", ylabel="probability density (1/m)", yscale="log")
        if a.get_visible() and a.get_legend_handles_labels()[0]:
            a.legend(fontsize=8)
    fig.tight_layout()
    return fig


#: What each stage of the grid method removes, in a newcomer's words (slr_ray.positions.STAGES)
_STAGE_WORDS = {"ground_support": "too little ground within reach", "azimuth_profile": "view test (azimuth profile)"}


def _axis_origin(values) -> float:
    """A round number to measure large coordinates (UTM, 10^5-10^7 m) from, so that
    tick labels stay short and matplotlib adds no '+5.4012e6' offset; 0 for small ones."""
    values = np.asarray(values, float)
    if not len(values) or np.abs(values).max() < 1e4:
        return 0.0
    return float(np.floor(values.min() / 100.0) * 100.0)


def cells_figure(cells, positions=None, points=None):
    """Top view of the candidate cells of the grid method: those kept, and those
    removed by each stage (:class:`~slr_ray.positions.CandidateCells`), with the
    drawn positions numbered as in the output's list."""
    span = np.ptp(cells.centres, axis=0) if len(cells.centres) else np.ones(2)
    fig = _figure(figsize=(8, 1.5 + float(np.clip(6.5 * span[1] / max(span[0], 1e-9), 3.0, 8.0))))
    ax = fig.subplots()
    x0, y0 = _axis_origin(cells.centres[:, 0]), _axis_origin(cells.centres[:, 1])
    skipped = {st["stage"] for st in cells.stages if st.get("skipped")}
    shift = np.array([x0, y0])
    if points is not None and len(points):
        step = max(1, len(points) // 200_000)
        ax.scatter(points[::step, 0] - x0, points[::step, 1] - y0, s=0.05, c="0.8", rasterized=True)
    state = np.full(len(cells.ij), "ground_support", dtype=object)  # removed by ground support
    state[cells.kept["ground_support"] & ~cells.kept["azimuth_profile"]] = "azimuth_profile"
    state[cells.kept["azimuth_profile"]] = "kept"
    face = {"ground_support": "#f5b041", "azimuth_profile": "#85c1e9", "kept": "#1e8449"}
    handles = []
    for st, colour in face.items():
        m = state == st
        if m.any():
            ax.scatter(cells.centres[m, 0] - x0, cells.centres[m, 1] - y0, marker="s", s=12, c=colour,
                       alpha=0.8 if st == "kept" else 0.5, rasterized=True)
        if st in skipped:
            handles.append(mpl_patches.Patch(color="none", label=f"not run: {_STAGE_WORDS[st]}"))
            continue
        words = "candidates kept" if st == "kept" else "removed: " + _STAGE_WORDS[st]
        handles.append(mpl_patches.Patch(color=colour, label=f"{words} ({int(m.sum()):,})"))
    if positions is not None and len(positions):
        xy = np.asarray(positions)[:, :2] - shift
        ax.scatter(xy[:, 0], xy[:, 1], marker="^", c="k", s=50, zorder=3)
        for i, p in enumerate(xy, 1):
            ax.annotate(str(i), p, xytext=(4, 4), textcoords="offset points", fontsize=10, fontweight="bold")
        handles.append(mpl_lines.Line2D([], [], ls="", marker="^", c="k", label=f"positions drawn ({len(xy)})"))
    ax.legend(handles=handles, loc="best", fontsize=9)
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set(aspect="equal", xlabel=f"x (m{f', from {x0:,.0f}' if x0 else ''})",
           ylabel=f"y (m{f', from {y0:,.0f}' if y0 else ''})",
           title=f"scanner positions: {cells.cell_size:g} m cells with points, and which could hold a scanner")
    fig.tight_layout()
    return fig


def range_image_figure(image: dict, title: str = "", max_range: float | None = None):
    """A range image (:meth:`slr_ray.scan.Scan.range_image`): range by row
    (beam, highest first) and column (azimuth); white where no return."""
    rng = np.asarray(image["range"], float)
    rows, cols = rng.shape
    fig = _figure(figsize=(min(18, 2 + cols / 120), 1.5 + min(10, max(2.0, rows / 12))))
    ax = fig.subplots()
    vmax = max_range or (np.nanpercentile(rng, 99) if np.isfinite(rng).any() else 1.0)
    im = ax.imshow(rng, aspect="auto", interpolation="nearest", cmap="turbo", vmin=0, vmax=vmax)
    fig.colorbar(im, ax=ax, label="range (m)")
    filled = np.isfinite(rng).mean() if rng.size else 0.0
    ax.set(xlabel="column (azimuth)", ylabel="row (beam, by elevation)",
           title=f"{title} {rows} x {cols}, {100 * filled:.1f} % of pulses returned".strip())
    fig.tight_layout()
    return fig


def evaluation_figure(result: dict, max_range: float = 50.0, max_error: float = 1.0):
    """A real-pair evaluation (:func:`slr_ray.evaluate.evaluate_pair`) at a glance:
    the real range image of B, then one panel a method with its error where
    both return (simulated - real, blue nearer, red farther) and grey where
    only one of them returns; each titled with its scores. (Each method's
    simulated range image is in ``result['images']``.)"""
    images = result["images"]
    real = np.asarray(images["real"], float)
    methods = [r["method"] for r in result["rows"]]
    n = 1 + len(methods)
    rows, cols = real.shape
    fig = _figure(figsize=(14, 0.6 + n * float(np.clip(rows / 22, 1.6, 3.0))), layout="constrained")
    axes = fig.subplots(n, 1, squeeze=False, sharex=True)[:, 0]
    kw = {"aspect": "auto", "interpolation": "nearest"}
    im = axes[0].imshow(real, cmap="turbo", vmin=0, vmax=max_range, **kw)
    axes[0].set_title(f"real scan B: range, {100 * np.isfinite(real).mean():.1f} % of pulses returned", fontsize=12,
                      loc="left")
    fig.colorbar(im, ax=axes[0], label="range (m)", pad=0.01, fraction=0.03)
    by = {r["method"]: r for r in result["rows"]}
    err = None
    for ax, m in zip(axes[1:], methods):
        sim = np.asarray(images[m], float)
        only_one = np.isfinite(real) != np.isfinite(sim)
        ax.imshow(np.where(only_one, 1.0, np.nan), cmap="Greys", vmin=0, vmax=2, **kw)
        with np.errstate(invalid="ignore"):  # inf - inf where neither returns: blank
            diff = np.where(np.isfinite(real) & np.isfinite(sim), sim - real, np.nan)
        err = ax.imshow(diff, cmap="RdBu_r", vmin=-max_error, vmax=max_error, **kw)
        img = by[m]["image"]
        ax.set_title(f"{by[m]['label']}: RMSE {img['rmse']:.2f} m, median error {img['medae']:.3f} m, "
                     f"return or drop right {100 * img['accuracy']:.1f} %", fontsize=12, loc="left")
    if err is not None:
        fig.colorbar(err, ax=list(axes[1:]), label="simulated - real (m)", pad=0.01, fraction=0.03)
        axes[1].legend(handles=[mpl_patches.Patch(color="0.5", label="only one of real and simulated returns")],
                       loc="upper right", fontsize=10, framealpha=0.9)
    for ax in axes:
        ax.set_yticks([])
        ax.set_ylabel("beam")
    axes[-1].set_xlabel("column (azimuth)")
    return fig
