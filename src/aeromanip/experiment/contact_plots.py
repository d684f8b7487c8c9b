"""The contact figure of a run with surfaces: the normal force against its set value,
the sensor's reading, the contact flag and the feed-forward, from the log alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aeromanip.experiment.plot_style import finish, grid, save, title_and_legend
from aeromanip.experiment.runlog import RunLog


def plot_contact(log: RunLog, out_dir: str | Path, name: str = "contact_force.png") -> list[Path]:
    """Normal force [N] (true ``f_n``, set ``f_ref``, balanced ``f_ff``), the tangential
    (friction) force and the contact flag; nothing for a run without surfaces."""
    if "f_n" not in log or "contact" not in log:
        return []
    t = log.column("t")
    fig, axes = grid(2, row_h=2.6)
    ax = axes[0]
    ax.plot(t, log.column("f_n"), color="C0", lw=1.2, label="normal force (true)")
    if "f_ref" in log:
        ax.plot(t, log.column("f_ref"), "r--", lw=1.2, label="set force")
    if "f_ff" in log:
        ax.plot(t, log.column("f_ff"), color="C2", lw=1.0, label="thrust feed-forward")
    finish(ax, "force [N]")
    ax = axes[1]
    ax.plot(t, log.column("f_t"), color="C1", lw=1.0, label="tangential force (true)")
    ax.fill_between(t, 0.0, np.asarray(log.column("contact")) * 0.1, step="post",
                    color="0.6", alpha=0.5, label="in contact")  # fmt: skip
    if "contact_lost" in log and np.any(log.column("contact_lost") > 0):
        ax.plot(t, 0.2 * np.asarray(log.column("contact_lost")), "k:", label="contact lost")
    ax.set_xlabel("t [s]")
    finish(ax, "force [N]")
    title_and_legend(fig, list(axes), f"{log.meta.get('scenario', 'run')}: contact force")
    return [save(fig, out_dir, name)]
