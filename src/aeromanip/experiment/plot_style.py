"""Layout helpers shared by ``plots``: fixed-inch margins, time-series grids, bound lines and
one figure-level legend in a band under the title (so no legend covers data or bounds)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from aeromanip.experiment.runlog import bound_pair

DPI = 120
BOUND_STYLE: dict[str, Any] = {"color": "0.35", "ls": "--", "lw": 1.0}
_TITLE_IN = 0.12  # title top, inches below the figure top
_LEGEND_IN = 0.42  # legend band top, inches below the figure top
_ROW_IN = 0.18  # height of one legend row [in]


def unit(name: str, rate: bool = False) -> str:
    """SI unit of a state DoF (``rate``: of its derivative)."""
    base = "m" if name in ("x", "y", "z") else "rad"
    return f"{base}/s" if rate else base


def save(fig: Figure, out_dir: str | Path, name: str) -> Path:
    """Write ``fig`` as ``out_dir/name`` (directory created) and return the path."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    path = d / name
    fig.savefig(path, dpi=DPI)
    return path


def margins(
    fig: Figure,
    nrows: int = 1,
    ncols: int = 1,
    *,
    left: float = 0.9,
    right: float = 0.25,
    top: float = 0.6,
    bottom: float = 0.55,
    hgap: float = 0.3,
    wgap: float = 1.0,
) -> None:
    """Fixed margins and gaps in inches (cheaper and steadier than a layout engine)."""
    w, h = fig.get_size_inches()
    ax_w = (w - left - right - wgap * (ncols - 1)) / ncols
    ax_h = (h - top - bottom - hgap * (nrows - 1)) / nrows
    fig.subplots_adjust(
        left=left / w,
        right=1 - right / w,
        top=1 - top / h,
        bottom=bottom / h,
        wspace=wgap / ax_w,
        hspace=hgap / ax_h,
    )


def grid(
    n: int, width: float = 9.0, row_h: float = 2.2, max_rows: int = 4
) -> tuple[Figure, list[Axes]]:
    """A figure with ``n`` time-series axes sharing x (two columns beyond ``max_rows``)."""
    ncols = 1 if n <= max_rows else 2
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(width if ncols == 1 else width * 1.6, 1.15 + row_h * nrows))
    axes = fig.subplots(nrows, ncols, sharex=True, squeeze=False).ravel().tolist()
    margins(fig, nrows, ncols, hgap=0.3 if n <= max_rows else 0.45)
    for ax in axes[n:]:
        ax.set_visible(False)
    for i, ax in enumerate(axes[:n]):
        if i + ncols >= n:  # nothing visible below: this axes shows the time axis
            ax.xaxis.set_tick_params(labelbottom=True)
            ax.set_xlabel("t [s]")
    return fig, axes[:n]


def bound_lines(ax: Axes, bounds: Mapping[str, Any], key: str) -> None:
    """Dashed horizontal lines at the finite sides of ``bounds[key]`` (legend: "bounds")."""
    if bounds.get(key) is None:
        return
    label = "bounds"
    for v in bound_pair(bounds[key], key):
        if math.isfinite(v):
            ax.axhline(v, **BOUND_STYLE, label=label)
            label = "_nolegend_"


def finish(ax: Axes, ylabel: str) -> None:
    """Y label and a light grid."""
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.4)


def active(col: np.ndarray) -> bool:
    """Whether a numeric column holds any non-zero (finite) value."""
    return bool(col.size) and bool(np.any(np.nan_to_num(col) != 0.0))


def _unique_handles(axes: Sequence[Axes]) -> tuple[list[Artist], list[str]]:
    handles: dict[str, Artist] = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    if "bounds" in handles:  # constraint lines last, after the data they bound
        handles["bounds"] = handles.pop("bounds")
    return list(handles.values()), list(handles)


def _legend_columns(labels: Sequence[str], width: float) -> int:
    """Most legend columns (filled column-wise) whose estimated width fits ``width`` [in]."""
    item_w = [0.75 + 0.07 * len(lab) for lab in labels]
    for ncol in range(len(labels), 1, -1):
        rows = math.ceil(len(labels) / ncol)
        cols = [item_w[j : j + rows] for j in range(0, len(labels), rows)]
        if sum(max(c) for c in cols) <= width:
            return ncol
    return 1


def title_and_legend(fig: Figure, axes: Sequence[Axes], title: str) -> None:
    """Title plus one legend of the axes' distinct labels in a band under it.

    The figure grows by the band's height (axes keep their size in inches), so the legend
    sits outside every axes and never covers data or bound lines.
    """
    handles, labels = _unique_handles(axes)
    w, h = fig.get_size_inches()
    extra = 0.0
    ncol = _legend_columns(labels, w - 0.4)
    if labels:
        extra = _ROW_IN * math.ceil(len(labels) / ncol) + 0.1
    sp = fig.subplotpars
    top_in, bottom_in = (1 - sp.top) * h + extra, sp.bottom * h
    h2 = h + extra
    fig.set_size_inches(w, h2)
    fig.subplots_adjust(top=1 - top_in / h2, bottom=bottom_in / h2)
    fig.suptitle(title, y=1 - _TITLE_IN / h2, va="top")
    if labels:
        fig.legend(
            handles,
            labels,
            loc="upper center",
            bbox_to_anchor=(0.5, 1 - _LEGEND_IN / h2),
            ncol=ncol,
            fontsize="small",
            frameon=False,
            handlelength=2.5,
        )
