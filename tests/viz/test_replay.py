"""Replays rendered headless: a short run gives a video with the expected number of frames
and size, frames that change while the robot moves (not blank, not frozen), variants side by
side; ``aeromanip run --video``; one-line errors for bad inputs."""

import ctypes.util
import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

from aeromanip.cli import main
from aeromanip.errors import AeromanipError
from aeromanip.experiment.runner import run_scenarios
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.viz import gl, replay
from aeromanip.viz.dependencies import RenderBackendError
from aeromanip.viz.render import Panel
from aeromanip.viz.replay import auto_speed, frame_times
from aeromanip.viz.runs import load_run
from aeromanip.viz.video import parse_size

imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
Image = pytest.importorskip("PIL.Image")


def _gl_problem():
    try:
        gl.make_context(16, 16).free()
    except RenderBackendError as e:
        return str(e)
    return None


GL_PROBLEM = _gl_problem()
needs_gl = pytest.mark.skipif(GL_PROBLEM is not None, reason=f"no offscreen GL: {GL_PROBLEM}")
CAPTION_PX = 50  # the top of a frame holds the caption (its time changes every frame)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("replay") / "waypoints"
    run_scenarios(load_scenarios("waypoints", ["duration=4"]), out, progress=False, figures=False)
    return out


def read_mp4(path):
    gen = imageio_ffmpeg.read_frames(str(path))
    meta = gen.__next__()
    w, h = meta["size"]
    frames = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in gen]
    return meta, np.array(frames)


def below_caption(frames):
    return frames[..., CAPTION_PX:, :, :].astype(float)


@needs_gl
def test_mp4_has_the_frames_and_size_and_shows_the_robot_moving(run_dir, tmp_path):
    out = tmp_path / "hier.mp4"
    result = replay(run_dir / "hierarchical", out, size=(160, 120), fps=10, speed=1)
    expected = len(frame_times(0.0, 3.5, 10, 1))  # rows at 0, 0.5, ..., 3.5 s
    assert expected == 36 and result.frames == expected and result.path == out
    meta, frames = read_mp4(out)
    assert meta["size"] == (160, 120) and meta["fps"] == 10
    assert frames.shape == (expected, 120, 160, 3)
    assert frames.std(axis=(1, 2, 3)).min() > 10  # not blank
    scene = below_caption(frames)
    change = np.abs(np.diff(scene, axis=0)).mean(axis=(1, 2, 3))
    assert change.min() > 0.05  # every frame differs from the next: the UAM moves
    assert np.abs(scene[-1] - scene[0]).mean() > 1.0


@needs_gl
def test_frames_are_frozen_when_the_run_is(run_dir):
    """The change seen above is the robot's: a run at rest renders the same scene."""
    run = load_run(run_dir / "hierarchical")
    traj = run.traj
    for a in (traj.pos, traj.rpy, traj.q, traj.ee, traj.ref):
        a[:] = a[0]
    panel = Panel(run, 160, 120)
    try:
        a, b = (below_caption(panel.frame(t)) for t in (0.0, 2.0))
    finally:
        panel.close()
    assert np.array_equal(a, b)


@needs_gl
def test_gif_puts_variants_side_by_side(run_dir, tmp_path):
    result = replay(run_dir, tmp_path / "both.gif", size=(96, 72), fps=4, speed=2)
    assert result.frames == len(frame_times(0.0, 3.5, 4, 2)) == 8
    with Image.open(result.path) as im:
        assert im.size == (2 * 96, 72) and im.n_frames == 8
        im.seek(7)
        last = np.asarray(im.convert("RGB")).astype(float)
    left, right = last[:, :96], last[:, 96:]
    assert left.std() > 10 and right.std() > 10 and np.abs(left - right).mean() > 0.5


@needs_gl
def test_png_still_and_cli_replay(run_dir, tmp_path, capsys):
    out = tmp_path / "still.png"
    code = main(["replay", str(run_dir / "tracking-only"), "--out", str(out), "--size", "128x96",
                 "--at", "2", "--quiet"])  # fmt: skip
    assert code == 0 and "a still 128x96 at t = 2 s" in capsys.readouterr().out
    with Image.open(out) as im:
        assert im.size == (128, 96) and np.asarray(im).std() > 10


@needs_gl
def test_run_video_flag_renders_at_the_end(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["run", "waypoints", "--variant", "tracking-only", "--set", "duration=1",
                 "--out", str(out), "--quiet", "--video", "--no-mcap"])  # fmt: skip
    assert code == 0
    meta, frames = read_mp4(out / "replay.mp4")
    assert meta["size"] == (640, 480) and len(frames) == len(frame_times(0.0, 0.5, 30, 1)) == 16
    assert not list(out.rglob("run.mcap"))
    assert f"wrote {out / 'replay.mp4'}" in capsys.readouterr().out


def test_default_speed_keeps_videos_short():
    assert auto_speed(30.0) == 1.0 and auto_speed(90.0) == 1.0 and auto_speed(160.0) == 2.0
    assert auto_speed(780.0) == 10.0  # the 13-min flight: 78 s of video


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--size", "640x481"], "--size: expected WxH with even W and H in [16, 4096]"),
        (["--size", "big"], "e.g. 640x480, got 'big'"),
        (["--out", "x.avi"], "x.avi: unknown suffix '.avi' (allowed: .mp4, .gif, .png)"),
        (["--speed", "0"], "--speed: must be in (0, 10000], got 0.0"),
        (["--fps", "1000"], "--fps: must be in (0, 120], got 1000.0"),
        (["--out", "x.png", "--at", "99"], "--at: must be a time of the run, in [0, 3.5] s"),
        (["--out", "x.gif", "--speed", "0.001"], "is too long for a GIF"),
        (["--at", "1"], "--at: picks the time of a .png still"),
    ],
)
def test_bad_options_are_one_line_errors(run_dir, tmp_path, capsys, args, message):
    args = [a.replace("x.", f"{tmp_path}/x.") if a.startswith("x.") else a for a in args]
    assert main(["replay", str(run_dir / "hierarchical"), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not list(tmp_path.iterdir())  # nothing written


def test_bad_run_directories_are_one_line_errors(tmp_path, run_dir, capsys):
    assert main(["replay", str(tmp_path / "nope")]) == 2
    assert "nope: not a run directory" in capsys.readouterr().err
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("log.csv", "meta.json"):
        (bare / name).write_bytes((run_dir / "hierarchical" / name).read_bytes())
    assert main(["replay", str(bare)]) == 2
    assert "no robot.xml" in capsys.readouterr().err


def test_no_gl_backend_names_the_fix(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "vulkan")
    with pytest.raises(RenderBackendError, match="MUJOCO_GL='vulkan': not an offscreen backend"):
        gl.make_context(16, 16)
    monkeypatch.setenv("MUJOCO_GL", "egl")

    def broken(name):
        raise ImportError("libEGL.so.1: cannot open shared object file")

    monkeypatch.setattr(gl, "_context_class", broken)
    with pytest.raises(AeromanipError) as e:
        gl.make_context(16, 16)
    text = str(e.value)
    assert "MUJOCO_GL=egl" in text and "MUJOCO_GL=osmesa" in text and "apt install" in text
    assert "libEGL.so.1" in text and "\n" not in text


def test_without_mujoco_gl_the_backend_is_the_first_installed(monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    libs = {"EGL": None, "OSMesa": "libOSMesa.so.8"}
    monkeypatch.setattr(ctypes.util, "find_library", libs.get)
    assert gl.backend_name() == "osmesa"
    libs["EGL"] = "libEGL.so.1"
    assert gl.backend_name() == "egl"
    libs.update(EGL=None, OSMesa=None)
    assert gl.backend_name() == "egl"  # none found: EGL's own error will name the fix


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is not None, reason="OSMesa works here")
def test_cli_replay_with_a_missing_backend_is_a_one_line_error(run_dir, tmp_path):
    """``MUJOCO_GL=osmesa`` without libOSMesa breaks ``import mujoco`` itself (PyOpenGL);
    the command says so in one line naming the fix, in a fresh process."""
    out = tmp_path / "x.png"
    env = os.environ | {"MUJOCO_GL": "osmesa"}
    cmd = [sys.executable, "-m", "aeromanip.cli", "replay", str(run_dir), "--out", str(out)]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr
    err = p.stderr.strip()
    assert len(err.splitlines()) == 1 and "MUJOCO_GL=osmesa" in err, err
    assert "set MUJOCO_GL=egl" in err and "apt install libosmesa6" in err and not out.exists()


def test_parse_size():
    assert parse_size("640x480") == (640, 480) and parse_size(" 320X240 ") == (320, 240)
    for bad in ("8x8", "640", "640x480x3", "-640x480", "5000x480"):
        with pytest.raises(AeromanipError):
            parse_size(bad)
    with pytest.raises(AeromanipError, match=r"got \(641, 480\)"):
        replay("/nonexistent", size=(641, 480))  # the Python API checks it too


def test_a_frame_of_the_wrong_size_is_refused_and_no_file_appears(tmp_path):
    from aeromanip.viz.video import FrameWriter

    message = r"^FrameWriter\.write: a frame of shape \(4, 6, 3\), expected \(8, 6, 3\) "
    writer = FrameWriter(tmp_path / "a.png", 6, 8, 10.0)
    with pytest.raises(AeromanipError, match=message), writer as w:
        w.write(np.zeros((4, 6, 3), dtype=np.uint8))
    assert list(tmp_path.iterdir()) == []


def test_rendering_after_close_is_an_error_of_ours():
    from aeromanip.viz.render import Offscreen

    model = gl.import_mujoco().MjModel.from_xml_string(
        "<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>"
    )
    view = Offscreen(model, 16, 12, 0, "fast")
    view.close()
    view.close()  # idempotent
    with pytest.raises(AeromanipError, match=r"^Offscreen\.render: the renderer is closed$"):
        view.render()


@pytest.fixture(scope="module")
def contact_dir(tmp_path_factory):
    """contact-wall for 9 s: pressing the wall with 2 N set from 7 s."""
    out = tmp_path_factory.mktemp("replay") / "contact"
    scenarios = load_scenarios("contact-wall", ["duration=9"], "cog")
    run_scenarios(scenarios, out, progress=False, figures=False)
    return out / "cog"


def _arrows(scene):
    import mujoco

    geoms = [scene.geoms[i] for i in range(scene.ngeom)]
    return [g for g in geoms if g.type == mujoco.mjtGeom.mjGEOM_ARROW]


@needs_gl
def test_replay_draws_the_force_arrow_at_the_probe_and_a_still(contact_dir, tmp_path):
    """At 8 s the probe presses the wall (x = 0.3 m, normal -x): one arrow from the
    drawn probe's contact point along -x, 0.1 m per newton the sensor measured along it;
    the probe's tip drawn pushed in as logged; the still shows the wall and the arrow."""

    run = load_run(contact_dir)
    c = run.log.columns
    k = int(np.argmin(np.abs(c["t"] - 8.0)))
    assert c["contact"][k] == 1.0 and c["f_x"][k] < -1.0  # pressing
    panel = Panel(run, 160, 120)
    try:
        with_arrow = panel.frame(8.0).astype(float)
        (arrow,) = _arrows(panel.offscreen.scene)
        probe = panel.data.geom("ee_probe")
        tip, radius = probe.xpos.copy(), panel.model.geom("ee_probe").size[0]
        np.testing.assert_allclose(arrow.pos, tip + np.array([radius, 0.0, 0.0]), atol=1e-6)
        np.testing.assert_allclose(arrow.mat.reshape(3, 3)[:, 2], [-1.0, 0.0, 0.0], atol=1e-6)
        # MuJoCo draws an arrow geom half its size[2] long (shaft to 1/3, head to 1/2)
        assert arrow.size[2] / 2 == pytest.approx(0.1 * -c["f_x"][k], rel=1e-6)
        # the tip drawn where the physics had it (not at the unpressed 12 mm further in)
        logged = np.array([c["tip_x"][k], c["tip_y"][k], c["tip_z"][k]])
        assert c["probe_travel"][k] > 0.005
        np.testing.assert_allclose(tip, logged, atol=0.004)
        panel.frame(3.0)  # approaching: no contact, no arrow
        assert not _arrows(panel.offscreen.scene)
        panel.overlays = dataclasses.replace(panel.overlays, arrows=None)
        without = panel.frame(8.0).astype(float)
    finally:
        panel.close()
    assert np.abs(with_arrow - without).sum(axis=2).astype(bool).sum() > 30  # pixels it covers
    assert 'name="surface_1" type="box"' in run.mjcf  # the replay draws the wall from it
    out = tmp_path / "contact.png"
    result = replay(contact_dir, out, size=(320, 240), at=8.0)
    assert result.path == out
    with Image.open(out) as im:
        assert im.size == (320, 240) and np.asarray(im).std() > 10
