"""A campaign's figures, drawn from ``results.csv`` alone (``aeromanip plot DIR`` re-draws
them): each metric against each swept key, and a Pareto plot of two metrics.

``DIR/figures/sweep_<key>.png``: one panel per metric (those that vary between the runs,
or the chosen ones); at each value of the key every run is a dot and, for a key with few
values, a line joins the means of the runs that share the other swept values (a series
each). Against the seed key (Monte-Carlo), a band shows the mean +- one standard
deviation. ``DIR/figures/pareto_<a>__<b>.png``: the runs in the plane of two metrics, both
to be minimised, the non-dominated ones joined and labelled with their swept values.
Failed runs are left out (they have no metrics).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from aeromanip.errors import ConfigError
from aeromanip.experiment.plot_style import finish, margins, save, title_and_legend
from aeromanip.sweep.results import FIXED_COLUMNS, TASK_COLUMNS, number
from aeromanip.sweep.tasks import DONE

Rows = list[dict[str, str]]
LINE_MAX_VALUES = 12  # a key with more distinct values (random draws) gets dots only
MAX_SERIES = 8  # series beyond this share one colour (no legend entry each)
PANEL_W, PANEL_H = 3.3, 2.3  # [in]
NCOLS = 3
LOG_SPAN = 50.0  # positive values spanning this ratio or more get a log axis
MAX_LABELS = 15  # Pareto points labelled with their swept values, at most


def metric_columns(rows: Rows, keys: Sequence[str]) -> list[str]:
    """The numeric columns that differ between the runs (the metrics worth a panel)."""
    skip = {*FIXED_COLUMNS, *TASK_COLUMNS, *keys}
    cols = [c for c in (rows[0] if rows else {}) if c not in skip]
    out = []
    for c in cols:
        v = np.array([number(r.get(c)) for r in rows])
        finite = v[np.isfinite(v)]
        if finite.size and np.ptp(finite) > 0:
            out.append(c)
    return out


def _x_values(rows: Rows, key: str) -> tuple[np.ndarray, list[str] | None]:
    """The key's values as positions: numbers, or categories in order of appearance."""
    cells = [r.get(key, "") for r in rows]
    nums = np.array([number(c) for c in cells])
    if np.all(np.isfinite(nums)) and not any(c in ("true", "false") for c in cells):
        return nums, None
    cats = list(dict.fromkeys(cells))
    return np.array([cats.index(c) for c in cells], dtype=float), cats


def _x_scale(ax: Axes, x: np.ndarray) -> None:
    """A log axis for positive values over decades; symlog if 0 is among them."""
    pos = x[x > 0]
    if pos.size < 2 or np.any(x < 0) or pos.max() / pos.min() < LOG_SPAN:
        return
    if np.any(x == 0):
        ax.set_xscale("symlog", linthresh=float(pos.min()))
    else:
        ax.set_xscale("log")


def _series(rows: Rows, others: Sequence[str]) -> dict[str, list[int]]:
    """Row indices grouped by the values of the ``others`` keys (label -> indices)."""
    groups: dict[str, list[int]] = {}
    for i, r in enumerate(rows):
        label = ", ".join(f"{k}={r.get(k, '')}" for k in others)
        groups.setdefault(label, []).append(i)
    return groups


def _panel(
    ax: Axes, x: np.ndarray, y: np.ndarray, groups: dict[str, list[int]], band: bool
) -> None:
    """Dots per run; per series a line through the means (or a mean +- std band)."""
    lines = len(np.unique(x)) <= LINE_MAX_VALUES
    for n, (label, idx) in enumerate(groups.items()):
        color = f"C{n % 10}" if n < MAX_SERIES else "0.5"
        name = (label or "runs") if n < MAX_SERIES else "_nolegend_"
        xs, ys = x[idx], y[idx]
        ax.plot(xs, ys, "o", color=color, ms=3.5, alpha=0.7, label=name)
        ok = np.isfinite(ys)
        if band and ok.any():
            m, s = float(np.mean(ys[ok])), float(np.std(ys[ok]))
            ax.axhline(m, color=color, lw=1.2, label="mean" if n == 0 else "_nolegend_")
            ax.axhspan(
                m - s,
                m + s,
                color=color,
                alpha=0.15,
                label="mean +- std" if n == 0 else "_nolegend_",
            )
        elif lines:
            ux = np.unique(xs[ok])
            means = [float(np.mean(ys[ok][xs[ok] == u])) for u in ux]
            ax.plot(ux, means, "-", color=color, lw=1.2)


def plot_key(
    rows: Rows,
    key: str,
    keys: Sequence[str],
    metrics: Sequence[str],
    out_dir: Path,
    replicate_key: str | None = None,
) -> Path:
    """``sweep_<key>.png``: every metric against ``key`` (module docstring)."""
    x, cats = _x_values(rows, key)
    band = key == replicate_key
    others = [k for k in keys if k not in (key, replicate_key)]
    groups = _series(rows, others)
    ncols = min(NCOLS, len(metrics))
    nrows = math.ceil(len(metrics) / ncols)
    fig = Figure(figsize=(1.2 + PANEL_W * ncols, 1.0 + PANEL_H * nrows))
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel().tolist()
    margins(fig, nrows, ncols, left=0.8, hgap=0.75, wgap=0.85)
    for ax in axes[len(metrics) :]:
        ax.set_visible(False)
    for ax, m in zip(axes, metrics, strict=False):
        y = np.array([number(r.get(m)) for r in rows])
        _panel(ax, x, y, groups, band)
        _dress(ax, m, key, x, cats, y if band and len(groups) == 1 else None)
    title_and_legend(fig, axes[: len(metrics)], f"{len(rows)} runs: metrics against {key}")
    return save(fig, out_dir, f"sweep_{key}.png")


def _dress(
    ax: Axes,
    metric: str,
    key: str,
    x: np.ndarray,
    cats: list[str] | None,
    spread: np.ndarray | None,
) -> None:
    """Title (with the mean +- std of ``spread`` if given), grid, x ticks and scale."""
    title = metric
    ok = spread[np.isfinite(spread)] if spread is not None else np.array([])
    if ok.size:
        title += f": {np.mean(ok):.4g} +- {np.std(ok):.2g}"
    finish(ax, "")
    ax.set_title(title, fontsize="small")
    ax.tick_params(labelsize="x-small")
    ax.set_xlabel(key, fontsize="small")
    if cats is not None:
        ax.set_xticks(range(len(cats)), cats, rotation=20, fontsize="x-small")
        return
    if np.all(x == np.round(x)):
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    _x_scale(ax, x)


def pareto_front(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Indices of the points no other point beats in both (minimised), sorted by ``a``."""
    ok = np.flatnonzero(np.isfinite(a) & np.isfinite(b))
    front, best_b = [], math.inf
    for i in sorted(ok, key=lambda i: (a[i], b[i])):
        if b[i] < best_b:
            front.append(i)
            best_b = b[i]
    return np.array(front, dtype=int)


def _short(key: str) -> str:
    """A swept key shortened for a label: its last two parts (``cond.weight``)."""
    return ".".join(key.split(".")[-2:])


def plot_pareto(rows: Rows, pair: tuple[str, str], keys: Sequence[str], out_dir: Path) -> Path:
    """``pareto_<a>__<b>.png``: the runs in the plane of two metrics, the front joined and
    numbered, its runs' swept values listed beside the plot."""
    ma, mb = pair
    for m in pair:
        if rows and m not in rows[0]:
            raise ConfigError(f"--pareto {m}: not a column of results.csv")
    a = np.array([number(r.get(ma)) for r in rows])
    b = np.array([number(r.get(mb)) for r in rows])
    front = pareto_front(a, b)
    listed = front[:MAX_LABELS]
    lines = ["Pareto front:"] + [
        f"{n}: " + ", ".join(f"{_short(k)}={rows[i].get(k, '')}" for k in keys)
        for n, i in enumerate(listed, 1)
    ]
    side = min(4.0, 0.4 + 0.075 * max(map(len, lines))) if len(listed) else 0.0  # [in]
    fig = Figure(figsize=(6.0 + side, 4.6))
    ax = fig.subplots()
    margins(fig, left=0.95, right=0.25 + side, bottom=0.6)
    ax.plot(a, b, "o", color="0.6", ms=4, label="runs")
    ax.plot(a[front], b[front], "o-", color="C3", ms=5, lw=1.2, label="Pareto front")
    for n, i in enumerate(listed, 1):
        ax.annotate(
            str(n),
            (a[i], b[i]),
            xytext=(4, 4),
            textcoords="offset points",
            fontsize="x-small",
            color="C3",
        )
    if len(listed):
        w, h = fig.get_size_inches()
        fig.text(
            1 - (side - 0.15) / w,
            1 - 0.75 / h,
            "\n".join(lines),
            va="top",
            ha="left",
            fontsize="x-small",
            family="monospace",
        )
    ax.ticklabel_format(style="sci", scilimits=(-3, 4))
    ax.set_xlabel(ma)
    finish(ax, mb)
    title_and_legend(fig, [ax], f"{len(rows)} runs: {mb} against {ma} (both minimised)")
    return save(fig, out_dir, f"pareto_{ma}__{mb}.png")


def plot_sweep(
    rows: Rows,
    keys: Sequence[str],
    out_dir: Path,
    *,
    metrics: Sequence[str] | None = None,
    pareto: tuple[str, str] | None = None,
    replicate_key: str | None = None,
) -> list[Path]:
    """Every figure of a campaign from its ``results.csv`` rows; returns their paths."""
    done = [r for r in rows if r.get("status") == DONE]
    if not done:
        return []
    chosen = list(metrics) if metrics else metric_columns(done, keys)
    missing = [m for m in chosen if m not in done[0]]
    if missing:
        raise ConfigError(f"--metrics {missing[0]}: not a column of results.csv")
    paths = []
    if chosen:
        paths += [plot_key(done, k, keys, chosen, out_dir, replicate_key) for k in keys]
    if pareto is not None:
        paths.append(plot_pareto(done, pareto, keys, out_dir))
    return paths
