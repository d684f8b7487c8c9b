"""A Foxglove layout for ``run.mcap`` (``foxglove-layout.json``, imported with Layout ->
Import from file): the robot in 3D beside plots of the log (docs/foxglove.md).

Left, the 3D panel: the URDF from ``/robot_description`` moved by ``/tf``, the ``/scene``
overlays, a grid, the camera following the platform. Right, tabs of plots of ``/log``
columns against simulation time: EE vs reference, joints, clearance and CoG, the solver
(time, iterations, status); in physics runs also attitude and the arm's torque; with
surfaces the measured normal force against the set one (``/contact``) and, in 3D, the
force arrow (``/contact/arrow``).
"""

from __future__ import annotations

from typing import Any

from aeromanip.experiment.runlog import RunLog
from aeromanip.viz.dependencies import require

LAYOUT_FILE = "foxglove-layout.json"


def _plot(fl: Any, title: str, paths: list[tuple[str, str]]) -> Any:
    """A plot panel of ``/log`` columns (or of full message paths, ``/topic.field``):
    (column, label) pairs."""
    series = [
        fl.PlotSeries(value=c if c.startswith("/") else f"/log.{c}", label=label, enabled=True)
        for c, label in paths
    ]
    config = fl.PlotConfig(paths=series, show_legend=True, legend_display="top")
    return fl.PlotPanel(title=title, config=config)


def _three_d(fl: Any, base_link: str, contact: bool) -> Any:
    urdf = fl.BaseRendererUrdfLayerSettings(
        visible=True,
        layer_id="foxglove.Urdf",
        instance_id="uam",
        label="UAM (robot.urdf)",
        source_type="topic",
        topic="/robot_description",
        control_mode="transforms",
    )
    grid = fl.BaseRendererGridLayerSettings(
        visible=True, layer_id="foxglove.Grid", instance_id="grid", label="Grid", frame_id="world"
    )
    config = fl.ThreeDeeConfig(
        layers={"uam": urdf, "grid": grid},
        topics={
            topic: fl.BaseRendererSceneUpdateTopicSettings(visible=True)
            for topic in ("/scene", *(("/contact/arrow",) if contact else ()))
        },
        fixed_frame="world",
        follow_tf=base_link,
        follow_mode="follow-position",
        camera_state=fl.ThreeDeeCameraState(distance=3.0, phi=65.0, theta_offset=45.0),
    )
    return fl.ThreeDeePanel(title="UAM", config=config)


def foxglove_layout(log: RunLog, base_link: str) -> str:
    """The layout (JSON text) for a run with ``log``'s columns and platform ``base_link``."""
    fl = require("foxglove.layouts", "foxglove-sdk", "a Foxglove layout")
    xyz = "xyz"
    tabs = [
        ("EE", [(f"ee_{c}", f"ee {c}") for c in xyz] + [(f"ref_{c}", f"ref {c}") for c in xyz]),
        ("joints", [(f"q{i}", f"q{i}") for i in range(1, log.n_joints + 1)]),
        (
            "clearance, CoG",
            [("clearance", "clearance m"), ("cog_bx", "CoG x"), ("cog_by", "CoG y")],
        ),
        ("platform", [("x", "x"), ("y", "y"), ("z", "z"), ("yaw", "yaw")]),
    ]
    if "roll" in log:
        tabs.append(("attitude", [("roll", "roll"), ("pitch", "pitch")]))
    if "arm_torque" in log:
        tabs.append(("arm torque", [("arm_torque", "arm torque N m")]))
    contact = "tip_x" in log and "f_x" in log
    if contact:
        forces = [("/contact.normal_force", "measured N"), ("/contact.f_n", "true N")]
        if "f_ref" in log:
            forces.append(("/contact.f_ref", "set N"))
        tabs.append(("contact force", forces))
    items = [fl.TabItem(title=t, content=_plot(fl, t, p)) for t, p in tabs]
    solver = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(content=_plot(fl, "solver", [("solve_ms", "solve ms")])),
            fl.SplitItem(
                content=fl.StateTransitionsPanel(
                    title="status",
                    config=fl.StateTransitionsConfig(
                        paths=[fl.StateTransitionsSeries(value="/log.status", label="status")]
                    ),
                )
            ),
        ],
    )
    items.append(fl.TabItem(title="solver", content=solver))
    right = fl.TabContainer(tabs=items)
    content = fl.SplitContainer(
        direction="row",
        items=[
            fl.SplitItem(proportion=3, content=_three_d(fl, base_link, contact)),
            fl.SplitItem(proportion=2, content=right),
        ],
    )
    return fl.Layout(content=content).to_json()
