"""Frames of a saved run: MuJoCo's offscreen renderer on the run's ``robot.xml``.

One ``Offscreen`` (GL context, ``MjrContext``, ``MjvScene``) per panel is made once and
reused for every frame; a frame sets ``qpos`` from the logged pose (free joint: position and
``Rz(yaw) Ry(pitch) Rx(roll)``; hinges: ``q1..qn``), runs ``mj_kinematics`` and
``mj_camlight`` only (no dynamics; a compliant probe's tip at its logged travel),
updates the scene, appends the overlays
(``viz.scene``), renders, and writes the caption with Pillow.

No shadow mapping, multisampling or reflections: on a software renderer (Mesa llvmpipe on a
2-core machine) they cost 2-3x and leave artefacts; a soft disc on the ground under the
platform gives the height cue (``viz.scene``). ``QUALITY`` ``fast`` (videos, 30-50 frames/s
at 640x480 here) renders at the output size; ``high`` (stills) at twice the size, box-filtered
down (smooth edges), about 4x slower.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from aeromanip.errors import AeromanipError, ConfigError
from aeromanip.viz.dependencies import require
from aeromanip.viz.gl import import_mujoco, make_context
from aeromanip.viz.runs import SavedRun
from aeromanip.viz.scene import DISC_SHARE, LINE_PX, FollowCamera, Overlays
from aeromanip.viz.transforms import quat_from_rpy

mujoco = import_mujoco()

QUALITY = {"fast": 1, "high": 2}  # name -> supersampling factor
EXTRA_GEOMS = 64  # scene room beyond the model's geoms and the overlays
FONT_PX = 15
SKY_TOP = (0.55, 0.7, 0.85)  # gradient skybox colours (RGB in [0, 1])
SKY_BOTTOM = (0.12, 0.14, 0.18)
STATUS_RGB = {"ok": (120, 230, 120), "fallback": (255, 190, 60)}
FAIL_RGB = (255, 90, 90)


class Offscreen:
    """An offscreen renderer of ``model`` at ``width`` x ``height`` pixels (reused)."""

    def __init__(
        self, model: mujoco.MjModel, width: int, height: int, extra_geoms: int, quality: str
    ) -> None:
        if quality not in QUALITY:
            raise ConfigError(f"--quality: {quality!r} is not one of {sorted(QUALITY)}")
        self.scale = QUALITY[quality]
        self.width, self.height = width, height
        width, height = width * self.scale, height * self.scale
        model.vis.global_.offwidth = width
        model.vis.global_.offheight = height
        model.vis.quality.offsamples = 0
        self.model = model
        self._gl = make_context(width, height)
        self.scene = mujoco.MjvScene(model, maxgeom=model.ngeom + extra_geoms + EXTRA_GEOMS)
        self.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        self.option = mujoco.MjvOption()
        self._ctx: Any = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._buf = np.empty((height, width, 3), dtype=np.uint8)

    def update(self, data: mujoco.MjData, camera: mujoco.MjvCamera) -> mujoco.MjvScene:
        """Fill the scene from ``data`` seen by ``camera``; returns it (add geoms to it)."""
        mujoco.mjv_updateScene(
            self.model, data, self.option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, self.scene
        )
        return self.scene

    def render(self) -> np.ndarray:
        """The scene as an RGB image (height, width, 3), top row first (a new array)."""
        if self._ctx is None:
            raise AeromanipError("Offscreen.render: the renderer is closed")
        self._gl.make_current()
        mujoco.mjr_render(self._rect, self.scene, self._ctx)
        mujoco.mjr_readPixels(self._buf, None, self._rect, self._ctx)
        if self.scale == 1:
            return self._buf[::-1].copy()
        image = require("PIL.Image", "pillow", "a high-quality replay")
        return np.asarray(image.fromarray(self._buf[::-1]).reduce(self.scale))

    def close(self) -> None:
        """Free the GL resources (idempotent)."""
        if self._ctx is not None:
            self._gl.make_current()
            self._ctx.free()
            self._ctx = None
            self._gl.free()


class Panel:
    """One run rendered at any time ``t``: robot, overlays, caption (``quality``: a key of
    ``QUALITY``)."""

    def __init__(
        self,
        run: SavedRun,
        width: int,
        height: int,
        label: str | None = None,
        quality: str = "fast",
    ) -> None:
        self.model = load_model(run)
        self.data = mujoco.MjData(self.model)
        self.run, self.label = run, run.name if label is None else label
        self.overlays = Overlays.of_run(run.log, run.traj)
        self._bind()
        self.offscreen = Offscreen(self.model, width, height, self.overlays.count(), quality)
        radius = self._radius()
        arrows = self.overlays.arrows
        normal = (
            arrows.direction[np.argmax(arrows.drawn)] if arrows and arrows.drawn.any() else None
        )
        self.camera = FollowCamera(run.traj, radius, float(self.model.vis.global_.fovy), normal)
        self._disc = DISC_SHARE * radius
        self._font = _font(FONT_PX)

    def _bind(self) -> None:
        """Where the free joint, the hinges and the EE site are in the model."""
        m = self.model
        free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        hinges = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
        nq = self.run.traj.q.shape[1]
        if len(free) != 1 or len(hinges) != nq:
            raise ConfigError(
                f"{self.run.path}/robot.xml: expected one free joint and {nq} hinges "
                f"(the log's q1..q{nq}), got {len(free)} and {len(hinges)}"
            )
        self._free = int(m.jnt_qposadr[free[0]])
        self._base = int(m.jnt_bodyid[free[0]])
        self._hinges = np.array([m.jnt_qposadr[j] for j in hinges])
        depth = [self._depth(int(m.site_bodyid[s])) for s in range(m.nsite)]
        self._ee = int(np.argmax(depth)) if m.nsite else -1  # the site deepest in the arm
        slides = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE]
        log = self.run.log
        self._probe = (  # the compliant probe's tip (the model's one slide), as logged
            (int(m.jnt_qposadr[slides[0]]), log.column("probe_travel"))
            if len(slides) == 1 and "probe_travel" in log
            else None
        )

    def _depth(self, body: int) -> int:
        d = 0
        while body > 0:
            body, d = int(self.model.body_parentid[body]), d + 1
        return d

    def _radius(self) -> float:
        """Radius [m] of a sphere about the base holding the robot at its first pose."""
        self.pose(float(self.run.traj.t[0]))
        m, d = self.model, self.data
        robot = [g for g in range(m.ngeom) if m.geom_bodyid[g] > 0]
        if not robot:
            return 1.0
        far = np.linalg.norm(d.geom_xpos[robot] - d.xpos[self._base], axis=1) + m.geom_rbound[robot]
        return float(max(far.max(), 0.2))

    def pose(self, t: float) -> None:
        """Set the model to the logged pose at ``t`` [s] (kinematics and lights only)."""
        pos, rpy, q = self.run.traj.pose(t)
        qpos = self.data.qpos
        qpos[self._free : self._free + 3] = pos
        qpos[self._free + 3 : self._free + 7] = quat_from_rpy(rpy)[0]
        qpos[self._hinges] = q
        if self._probe is not None:
            adr, travel = self._probe
            qpos[adr] = np.interp(t, self.run.traj.t, travel)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)  # light directions (kinematics leaves them)

    def frame(self, t: float) -> np.ndarray:
        """The RGB image (height, width, 3) of time ``t`` [s]."""
        self.pose(t)
        d = self.data
        base = d.xpos[self._base]
        ee = d.site_xpos[self._ee].copy() if self._ee >= 0 else base.copy()
        scene = self.offscreen.update(d, self.camera.aim(base, ee))
        self.overlays.draw(scene, t, ee, LINE_PX * self.offscreen.scale)
        self.overlays.ground_disc(scene, base, self._disc)
        return self.caption(self.offscreen.render(), t)

    def caption(self, image: np.ndarray, t: float) -> np.ndarray:
        """Write the run's name, time, EE error (with surfaces: the measured normal
        force) and the step's status on ``image``."""
        pil = require("PIL.Image", "pillow", "the replay's caption")
        draw_mod = require("PIL.ImageDraw", "pillow", "the replay's caption")
        traj, font = self.run.traj, self._font
        k = traj.row(t)
        status = str(traj.status[k]) or "-"
        info = f"t = {t:.1f} s   EE error {1e3 * traj.error(k):.1f} mm   "
        arrows = self.overlays.arrows
        if arrows is not None:  # a run with surfaces: the measured normal force
            info += f"force {max(float(arrows.along[k]), 0.0):.2f} N   "
        im = pil.fromarray(image)
        draw = draw_mod.Draw(im, "RGBA")
        y2 = 6 + FONT_PX + 4
        width = max(draw.textlength(s, font=font) for s in (self.label, info + status))
        draw.rectangle((2, 2, 14 + width, y2 + FONT_PX + 6), fill=(0, 0, 0, 150))
        draw.text((8, 6), self.label, font=font, fill=(255, 255, 255))
        draw.text((8, y2), info, font=font, fill=(255, 255, 255))
        x = 8 + draw.textlength(info, font=font)
        draw.text((x, y2), status, font=font, fill=STATUS_RGB.get(status, FAIL_RGB))
        return np.asarray(im)

    def close(self) -> None:
        """Free the renderer."""
        self.offscreen.close()


def load_model(run: SavedRun) -> mujoco.MjModel:
    """The run's MJCF with a sky (a gradient skybox) added for the replay."""
    try:
        spec = mujoco.MjSpec.from_string(run.mjcf)
        if not any(t.type == mujoco.mjtTexture.mjTEXTURE_SKYBOX for t in spec.textures):
            spec.add_texture(
                name="replay_sky",
                type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
                builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                rgb1=SKY_TOP,
                rgb2=SKY_BOTTOM,
                width=64,
                height=384,
            )
        return spec.compile()
    except ValueError as e:
        raise ConfigError(f"{run.path}/robot.xml: {' '.join(str(e).split())[:200]}") from None


def _font(px: int) -> Any:
    """Pillow's built-in font at ``px`` pixels (its bitmap font on an old Pillow)."""
    font_mod = require("PIL.ImageFont", "pillow", "the replay's caption")
    try:
        return font_mod.load_default(size=px)
    except TypeError:  # Pillow < 10.1
        return font_mod.load_default()
