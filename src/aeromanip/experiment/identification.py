"""``aeromanip identify``: the rate time constants of a scenario's simulator, written out.

Records a step response per active DoF (``experiment.step_response``), fits the first-order model
and writes ``DIR/response.toml`` (the ``[controller.response]`` table to paste into a
scenario), ``DIR/step_responses.csv`` and ``DIR/step_responses.png``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import tomli_w
from matplotlib.figure import Figure

from aeromanip.experiment.closed_loop import make_simulator
from aeromanip.experiment.plot_style import margins, save, unit
from aeromanip.experiment.scenario import Scenario
from aeromanip.experiment.step_response import (
    Fit,
    StepResponse,
    first_order,
    fit_first_order,
    record_step,
)

STEP_SHARE = 0.5  # of each DoF's velocity limit
UNBOUNDED_STEP = 0.2  # [m/s or rad/s] the step of a DoF without a velocity limit
STEP_DURATION = 3.0  # [s]


def identify(
    sc: Scenario, step_share: float = STEP_SHARE, duration: float = STEP_DURATION
) -> list[tuple[StepResponse, Fit]]:
    """Step responses of every DoF of ``sc``'s simulator and their fits. A joint steps
    toward its farther limit and stops short of it (at 90 % of the way)."""
    sim = make_simulator(sc)
    b, out, x0 = sc.limits, [], np.asarray(sc.x0, dtype=float)
    for i, name in enumerate(sc.robot.state_names):
        v = min(-b.u_lower[i], b.u_upper[i])
        step, length = (step_share * v if np.isfinite(v) else UNBOUNDED_STEP), duration
        if i >= sc.robot.n_platform:
            room_down, room_up = x0[i] - b.x_lower[i], b.x_upper[i] - x0[i]
            step = step if room_up >= room_down else -step
            length = min(duration, 0.9 * max(room_up, room_down) / abs(step))
        rec = record_step(sim, x0, i, name, step, length)
        out.append((rec, fit_first_order(rec)))
    return out


def write_identification(results: list[tuple[StepResponse, Fit]], out_dir: Path) -> list[Path]:
    """``response.toml``, ``step_responses.csv`` and ``step_responses.png`` in ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    toml = out_dir / "response.toml"
    table = {"controller": {"response": {f.dof: round(f.tau, 4) for _, f in results}}}
    toml.write_text(
        "# aeromanip identify: first-order rate time constants [s] (paste into a scenario)\n"
        + tomli_w.dumps(table)
    )
    rows = out_dir / "step_responses.csv"
    with rows.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["dof", "t", "step", "rate", "position", "model_rate", "model_position"])
        for rec, fit in results:
            mr, mp = first_order(rec.t, rec.step, fit.tau)
            for k in range(len(rec.t)):
                w.writerow(
                    [rec.dof, rec.t[k], rec.step, rec.rate[k], rec.position[k], mr[k], mp[k]]
                )
    return [toml, rows, _plot(results, out_dir)]


def _plot(results: list[tuple[StepResponse, Fit]], out_dir: Path) -> Path:
    n = len(results)
    cols = min(n, 4)
    rows = -(-n // cols)
    fig = Figure(figsize=(3.2 * cols, 2.6 * rows + 0.8))
    axes = fig.subplots(rows, cols, squeeze=False)
    margins(fig, rows, cols, wgap=0.8, hgap=0.6)
    for ax, (rec, fit) in zip(axes.flat, results, strict=False):
        ax.plot(rec.t, rec.rate, label="simulator")
        ax.plot(rec.t, first_order(rec.t, rec.step, fit.tau)[0], "--", label="first order")
        ax.set_title(f"{rec.dof}: tau = {fit.tau:.3f} s", fontsize=9)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"rate [{unit(rec.dof, rate=True)}]")
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=8)
    fig.suptitle("step responses of the rate commands")
    return save(fig, out_dir, "step_responses.png")


def format_fits(fits: list[Fit]) -> str:
    """A table of the fits, one line per DoF."""
    head = f"{'dof':<6}{'tau s':>8}{'R2':>8}{'rate rms':>10}{'pos rms':>10}{'tau=0 rms':>11}"
    lines = [head]
    for f in fits:
        lines.append(
            f"{f.dof:<6}{f.tau:>8.3f}{f.r2:>8.3f}{f.rate_rms:>10.4f}"
            f"{f.position_rms:>10.4f}{f.position_rms_0:>11.4f}"
        )
    return "\n".join(lines)
