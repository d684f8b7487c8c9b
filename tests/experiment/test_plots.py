"""Figures: every file produced as a real PNG, and re-plotting a loaded log gives the same set."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.figure import Figure

import aeromanip.experiment.plots as plots
from aeromanip.errors import ConfigError
from aeromanip.experiment.plots import (
    _command_dofs,
    plot_attitude,
    plot_commands,
    plot_comparison,
    plot_condition,
    plot_joints,
    plot_paths_3d,
    plot_platform,
    plot_run,
    plot_tracking,
)
from aeromanip.experiment.runlog import RunLog
from aeromanip.references import Waypoints

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
WAYPOINTS = [[1.0, 0.0, 0.5], [1.5, 0.5, 0.7], [1.0, 1.0, 0.4]]


def make_log(n: int = 80, cond_scale: float = 1.0, physics: bool = True) -> RunLog:
    """A small plausible 3-joint run tracking waypoints (not a simulation)."""
    t = np.arange(n) * 0.1
    ref = Waypoints(WAYPOINTS, [0.0, 3.0, 7.0]).sample(t - 0.2)
    ee = Waypoints(WAYPOINTS, [0.0, 3.0, 7.0]).sample(t - 0.4)
    base = ee + np.array([-0.3, 0.0, 0.45])
    q = np.stack([0.3 * np.sin(0.5 * t + k) for k in range(3)], axis=1)
    cols = {"t": t, "x": base[:, 0], "y": base[:, 1], "z": base[:, 2], "yaw": np.zeros(n)}
    for i in range(3):
        cols[f"q{i + 1}"] = q[:, i]
    vel = np.gradient(base, t, axis=0)
    cols |= {"u_x": vel[:, 0], "u_y": vel[:, 1], "u_z": vel[:, 2], "u_yaw": np.zeros(n)}
    qd = np.gradient(q, t, axis=0)
    for i in range(3):
        cols[f"u_q{i + 1}"] = qd[:, i]
    for j, c in enumerate("xyz"):
        cols[f"ee_{c}"] = ee[:, j]
        cols[f"ref_{c}"] = ref[:, j]
    cols |= {
        "cog_bx": 0.05 * np.cos(t),
        "cog_by": 0.02 * np.sin(t),
        "manip": 0.01 + 0.001 * t,
        "cond": cond_scale * (2.0 + np.sin(t) ** 2),
        "clearance": 0.2 + 0.05 * np.cos(t),
        "solve_ms": 5.0 + 3.0 * np.abs(np.sin(3 * t)),
        "status": np.where(np.arange(n) == 10, "fallback", "ok"),
    }
    if physics:
        cols |= {"roll": 0.02 * np.sin(t), "pitch": 0.01 * np.cos(t)}
        cols |= {"arm_torque": 0.05 + 0.01 * np.sin(t)}
        cols |= {f"motor_{i}": 7.0 + 0.1 * np.sin(t + i) for i in range(1, 5)}
    bounds = {f"q{i}": [-0.35, 0.35] for i in (1, 2, 3)}
    bounds |= {f"u_q{i}": [-0.5, 0.5] for i in (1, 2, 3)}
    bounds |= {"z": [0.5, None], "u_x": [-1.0, 1.0], "u_y": [-1.0, 1.0], "u_z": [-0.5, 0.5]}
    meta = {
        "bounds": bounds,
        "state_names": ["x", "y", "z", "yaw", "q1", "q2", "q3"],
        "waypoints": WAYPOINTS,
        "scenario": "test",
    }
    return RunLog(cols, meta)


def _check_png(path, min_bytes=8_000):
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE, path
    assert len(data) > min_bytes, (path, len(data))


RUN_FIGURES = {
    "ee_tracking.png",
    "commands.png",
    "joints.png",
    "platform.png",
    "cog_offset.png",
    "attitude.png",
    "solve_time.png",
}
COMPARISON_FIGURES = {"condition.png", "paths_3d.png", "comparison_errors.png"}


def test_plot_run_writes_all_figures_and_replots_from_loaded_log(tmp_path):
    log = make_log()
    paths = plot_run(log, tmp_path / "figs")
    assert {p.name for p in paths} == RUN_FIGURES
    for p in paths:
        _check_png(p)
    log.save(tmp_path / "run")
    again = plot_run(RunLog.load(tmp_path / "run"), tmp_path / "figs2")
    assert sorted(p.name for p in again) == sorted(p.name for p in paths)
    for p in again:
        _check_png(p)


def test_plot_comparison(tmp_path):
    logs = {
        "weighted": make_log(cond_scale=1.0),
        "hierarchical": make_log(cond_scale=100.0, physics=False),
    }
    paths = plot_comparison(logs, tmp_path)
    assert {p.name for p in paths} == COMPARISON_FIGURES
    for p in paths:
        _check_png(p)


def test_individual_figures_names_and_bounds_override(tmp_path):
    log = make_log(n=40)
    (p,) = plot_tracking(log, tmp_path, name="fig2.png")
    assert p.name == "fig2.png"
    _check_png(p)
    (p,) = plot_commands(log, tmp_path, bounds={"u_y": [-0.2, 0.2]}, name="fig3.png")
    _check_png(p)
    (p,) = plot_paths_3d({"only": log}, tmp_path, name="fig5.png")
    assert p.name == "fig5.png"
    _check_png(p)
    assert plot_condition({}, tmp_path) == []


def test_planar_log_without_meta_infers_active_dofs(tmp_path):
    log = make_log(n=30, physics=False)
    log.meta = {}
    for c in ("u_x", "u_yaw"):
        log.columns[c] = np.zeros(len(log))
    for c in ("q3", "u_q3"):
        del log.columns[c]
    assert _command_dofs(log) == ["y", "z", "q1", "q2"]
    log.meta = {"state_names": ["y", "z", "q1", "q2"]}
    assert _command_dofs(log) == ["y", "z", "q1", "q2"]
    _check_png(plot_joints(log, tmp_path)[0])
    _check_png(plot_platform(log, tmp_path)[0])


def test_missing_columns_skip_figures(tmp_path):
    t = np.arange(5) * 0.1
    log = RunLog({"t": t, "x": t, "y": t, "z": t})
    assert [p.name for p in plot_run(log, tmp_path)] == ["platform.png"]
    assert plot_comparison({"a": log}, tmp_path) == [tmp_path / "comparison_errors.png"]


@pytest.mark.parametrize("bad", [[1.0], "ab", [0.0, "x"]])
def test_malformed_bounds_are_reported(tmp_path, bad):
    log = make_log(n=10)
    log.meta["bounds"] = {"q1": bad}
    with pytest.raises(ConfigError, match=r"meta\.bounds\.q1"):
        plot_joints(log, tmp_path)


@pytest.fixture
def figures(monkeypatch):
    """Every figure ``plots`` saves, by file name (drawn, so extents are final)."""
    seen: dict[str, Figure] = {}
    real_save = plots.save

    def save(fig, out_dir, name):
        path = real_save(fig, out_dir, name)
        seen[name] = fig
        return path

    monkeypatch.setattr(plots, "save", save)
    return seen


def _ylabels(fig: Figure) -> list[str]:
    return [ax.get_ylabel() for ax in fig.axes if ax.get_visible()]


def _planar_log(n: int = 40) -> RunLog:
    """The planar robot: platform y, z and two joints; x (platform and EE) is always 0."""
    log = make_log(n=n, physics=False)
    for c in ("x", "ee_x", "ref_x", "u_x", "yaw", "u_yaw"):
        log.columns[c] = np.zeros(len(log))
    for c in ("q3", "u_q3"):
        del log.columns[c]
    log.meta["state_names"] = ["y", "z", "q1", "q2"]
    return log


def test_planar_figures_skip_the_inactive_x_axis(tmp_path, figures):
    log = _planar_log()
    plot_tracking(log, tmp_path)
    plot_platform(log, tmp_path)
    assert _ylabels(figures["ee_tracking.png"]) == ["y_e [m]", "z_e [m]", "error [mm]"]
    assert _ylabels(figures["platform.png"]) == ["y [m]", "z [m]"]
    log.columns["ref_x"] = np.full(len(log), 0.3)  # a constant but non-zero axis is shown
    plot_tracking(log, tmp_path)
    assert _ylabels(figures["ee_tracking.png"])[0] == "x_e [m]"


def test_legends_sit_outside_every_axes(tmp_path, figures):
    log = make_log(n=40)
    plot_run(log, tmp_path)
    plot_comparison({"a": log, "b": make_log(n=40, cond_scale=100.0)}, tmp_path)
    assert len(figures) == len(RUN_FIGURES | COMPARISON_FIGURES)
    for name, fig in figures.items():
        assert [ax for ax in fig.axes if ax.get_legend() is not None] == [], name
        (legend,) = fig.legends
        fig.draw_without_rendering()
        box = legend.get_window_extent()
        for ax in fig.axes:
            if ax.get_visible():
                assert box.y0 >= ax.get_tightbbox().y1 - 1, (name, ax.get_title())
    labels = [t.get_text() for t in figures["commands.png"].legends[0].get_texts()]
    assert labels == ["platform velocity command", "arm joint velocity command", "bounds"]


def test_paths_3d_start_marker_matches_its_legend_entry(tmp_path, figures):
    plot_paths_3d({"a": make_log(n=30)}, tmp_path)
    fig = figures["paths_3d.png"]
    legend = fig.legends[0]
    labels = [t.get_text() for t in legend.get_texts()]
    entry = legend.legend_handles[labels.index("start")]
    starts = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "start"]
    assert len(starts) == 2  # end effector and platform start, drawn alike
    for ln in starts:
        assert ln.get_marker() == entry.get_marker() == "o"
        assert ln.get_markerfacecolor() == entry.get_markerfacecolor()
        assert ln.get_markeredgecolor() == entry.get_markeredgecolor()


def test_attitude_figure_only_for_physics_logs(tmp_path, figures):
    (p,) = plot_attitude(make_log(n=40), tmp_path)
    assert p.name == "attitude.png"
    _check_png(p)
    assert _ylabels(figures["attitude.png"]) == [
        "tilt [deg]",
        "arm torque [N m]",
        "motor thrust [N]",
    ]
    roll = figures["attitude.png"].axes[0].get_lines()[0].get_ydata()
    assert np.allclose(roll, np.degrees(make_log(n=40).column("roll")))
    kinematic = make_log(n=40, physics=False)
    assert plot_attitude(kinematic, tmp_path / "kin") == []
    assert "attitude.png" not in {p.name for p in plot_run(kinematic, tmp_path / "kin")}
    partial = make_log(n=40)
    for c in ["arm_torque"] + [f"motor_{i}" for i in range(1, 5)]:
        del partial.columns[c]
    plot_attitude(partial, tmp_path)
    assert _ylabels(figures["attitude.png"]) == ["tilt [deg]"]
