"""Bad input fails fast in one line (exit 2), runs that did not fly exit 3, and no run is lost.

The command line checks everything before it builds or flies anything: ``--out``, ``--json``,
the backend's options, sanity limits of the scenario and of the robot. A run whose steps
failed exits 3 and keeps its outputs. A run directory is staged beside ``DIR``, locked, and
moved into place whole (an earlier run kept as ``DIR.previous``), even when interrupted;
a killed run leaves its staged rows in ``DIR.partial-<pid>``.

In-process runs skip drawing figures (seconds each; ``test_cli`` and ``test_plots`` draw
them); runs that need a signal or a second process fly in a subprocess, bounded by timeouts.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from aeromanip.cli import main
from aeromanip.errors import ConfigError, StateError
from aeromanip.experiment.runlog import RunLog

ROBOT_TOML = Path(__file__).resolve().parents[2] / "src" / "aeromanip" / "robots" / "x8-3dof.toml"
# waypoints with one weighted controller and no variants: DIR/log.csv, 2 steps a second
TINY_SCENARIO = """\
extends = "waypoints"
duration = 1.0
[controller]
strategy = "weighted"
[tasks.cog]
weight = 0.0
"""
FAST_S = 10.0  # [s] a check that fails before flying takes well under this (warm: < 0.2 s)
WAIT_S = 90.0  # [s] the longest a subprocess step may take before the test gives up


@pytest.fixture
def no_figures(monkeypatch):
    """In-process runs draw no figures (the figures are not what these tests check)."""
    import aeromanip.experiment.runner as runner

    monkeypatch.setattr(runner, "plot_run", lambda *a, **k: [])
    monkeypatch.setattr(runner, "plot_comparison", lambda *a, **k: [])


def write_tiny(where: Path) -> Path:
    """A scenario file without variants (its run directory holds log.csv itself)."""
    path = where / "tiny.toml"
    path.write_text(TINY_SCENARIO)
    return path


@pytest.fixture
def tiny(tmp_path):
    return write_tiny(tmp_path)


def error_line(capsys, quiet: bool = True) -> str:
    """The one stderr line of a refused command (asserting it is one line, no traceback
    and, if ``quiet``, nothing on stdout: no "running", no figure, no measurement)."""
    out, err = capsys.readouterr()
    err = err.strip()
    assert "Traceback" not in err, err
    if quiet:
        assert out == "", out
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("aeromanip: error: "), err
    return lines[0].removeprefix("aeromanip: error: ")


def refused_fast(argv, capsys) -> str:
    """Run ``argv`` in-process; assert exit 2 within ``FAST_S``, nothing flown; the line."""
    t0 = time.perf_counter()
    rc = main(argv)
    elapsed = time.perf_counter() - t0
    line = error_line(capsys)
    assert rc == 2, line
    assert elapsed < FAST_S, f"refused only after {elapsed:.1f} s: {line}"
    return line


def read_json(path: Path) -> dict:
    return json.loads(path.read_text())


def start_run(scenario: Path, out: str, cwd: Path, *sets: str) -> subprocess.Popen:
    """A long run in a subprocess (stopped by the test, never left to finish)."""
    args = ["run", str(scenario), "--set", "duration=600", *sets, "--quiet", "--out", out]
    return subprocess.Popen(
        [sys.executable, "-m", "aeromanip.cli", *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_until(proc: subprocess.Popen, ready, what: str) -> None:
    """Poll ``ready()`` until true; fail (the process still running) after ``WAIT_S``."""
    deadline = time.monotonic() + WAIT_S
    while not ready():
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"the run ended (exit {proc.returncode}) before {what}:\n{out}\n{err}")
        if time.monotonic() > deadline:
            pytest.fail(f"no {what} after {WAIT_S:g} s")
        time.sleep(0.05)


def rows_on_disk(run_dir: Path) -> int:
    """Rows of a streamed log readable by ``RunLog.load`` (0 while none or not yet there)."""
    try:
        return len(RunLog.load(run_dir))
    except ConfigError:
        return 0


def stop(proc: subprocess.Popen, sig: int) -> tuple[str, str]:
    """Send ``sig`` and wait for the process (killed if it does not stop in time)."""
    proc.send_signal(sig)
    try:
        return proc.communicate(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the run did not stop on {signal.Signals(sig).name}:\n{out}\n{err}")


def kill_if_running(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.communicate()


# ---------------------------------------------------------------- fail before flying: --out


def _out_cases():
    return [
        pytest.param("file", id="an-existing-file"),
        pytest.param("file/sub", id="below-a-file"),
        pytest.param("/proc/aeromanip-test", id="under-proc"),
    ]


@pytest.mark.parametrize("check", [False, True], ids=["run", "check"])
@pytest.mark.parametrize("out", _out_cases())
def test_out_that_cannot_be_a_directory_is_refused_before_flying(
    out, check, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("not a directory\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    # the default duration (30 s, two variants: 120 steps) would fly for many seconds
    argv = ["run", "waypoints", "--quiet", "--out", out] + (["--check"] if check else [])
    line = refused_fast(argv, capsys)
    assert line.startswith(f"--out: {out}"), line
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no DIR, .partial, .lock
    assert not list(Path(out).absolute().parent.glob(f"{Path(out).name}.*"))


@pytest.mark.parametrize(
    "target", ["a-directory", "file/results.json", "/proc/aeromanip-test.json"]
)
def test_bench_json_that_cannot_be_written_is_refused_before_measuring(
    target, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a-directory").mkdir()
    (tmp_path / "file").write_text("not a directory\n")
    line = refused_fast(["bench", "kinematics", "--json", target], capsys)
    assert line.startswith(f"--json: {target}") or line.startswith(f"--json: cannot write {target}")
    assert (tmp_path / "a-directory").is_dir() and (tmp_path / "file").is_file()


# ------------------------------------------------------ fail before flying: solver options

SQP_BAD_OPTIONS = [
    ('max_iter="many"', "solver_options.max_iter", "'many'", "an integer >= 1"),
    (
        'qpsol="gurobi"',
        "solver_options.qpsol",
        "'gurobi'",
        "one of ['auto', 'daqp', 'qpoases', 'riccati', 'hpipm']",
    ),
    ("tol=-1", "solver_options.tol", "-1", "a finite number >= 0"),
    ("nosuch=1", "solver_options.nosuch", "unknown sqp option", "known: max_iter"),
]


@pytest.mark.parametrize("check", [True, False], ids=["check", "run"])
@pytest.mark.parametrize(
    ("option", "key", "value", "allowed"), SQP_BAD_OPTIONS, ids=lambda v: str(v)[:12]
)
def test_bad_sqp_option_is_one_line_naming_the_key_before_any_build(
    option, key, value, allowed, check, tmp_path, capsys
):
    out = tmp_path / "out"
    argv = [
        "run",
        "waypoints",
        "--variant",
        "tracking-only",
        "--set",
        "controller.backend=sqp",
        "--set",
        f"controller.solver_options.{option}",
        "--set",
        "duration=1",
        "--quiet",
        "--out",
        str(out),
    ]
    line = refused_fast(argv + (["--check"] if check else []), capsys)
    assert line.startswith(f"{key}: "), line
    assert value in line and allowed in line, line
    assert not out.exists() and not list(tmp_path.glob("out.*"))


@pytest.mark.parametrize("check", [True, False], ids=["check", "run"])
@pytest.mark.parametrize(
    "option",
    ["controller.solver_options.nosuch=1", "controller.solver_options.ipopt={nosuch = 1}"],
    ids=["plugin-option", "ipopt-table"],
)
def test_unknown_ipopt_option_is_one_line_before_flying(option, check, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["run", "waypoints", "--variant", "tracking-only", "--set", "controller.backend=ipopt"]
    argv += ["--set", option, "--set", "duration=1", "--quiet", "--out", str(out)]
    line = refused_fast(argv + (["--check"] if check else []), capsys)
    assert line.startswith("solver_options: ipopt rejects the options"), line
    assert "nosuch" in line, line
    assert not out.exists() and not list(tmp_path.glob("out.*"))


def test_set_reaches_dotted_ipopt_options_in_the_free_form_solver_options(tmp_path, capsys):
    base = ["run", "waypoints", "--variant", "tracking-only", "--check", "--out", str(tmp_path)]
    assert main([*base, "--set", "controller.solver_options.ipopt.tol=1e-7"]) == 0
    capsys.readouterr()
    assert main([*base, "--set", "controller.solver_options.ipopt.nosuch=1"]) == 2
    line = error_line(capsys)
    assert "solver_options" in line and "nosuch" in line and "unknown key" not in line, line


# ------------------------------------------------------------------------ sanity limits

SANITY_LIMITS = [
    pytest.param(["duration=1e18"], "duration", ["1e+18", "[0.5, 1e+06]"], id="duration-1e18"),
    pytest.param(["duration=1e308"], "duration", ["1e+308", "[0.5, 1e+06]"], id="duration-1e308"),
    pytest.param(
        ["controller.dt=1e-300"], "controller.dt", ["1e-300", "[0.001, 60]"], id="dt-tiny"
    ),
    pytest.param(
        ["duration=1", "controller.dt=1e-6"], "controller.dt", ["1e-06", "[0.001, 60]"], id="dt-1us"
    ),
    pytest.param(
        ["controller.horizon=1000000000000000000"],
        "controller.horizon",
        ["1000000000000000000", "[1, 500]"],
        id="horizon-1e18",
    ),
    pytest.param(
        ["controller.horizon=100000"],
        "controller.horizon",
        ["100000", "[1, 500]"],
        id="horizon-1e5",
    ),
    pytest.param(["clearance.points=[]"], "clearance.points", ["non-empty"], id="no-points"),
    pytest.param(
        ["controller.time_budget=0"], "controller.time_budget", ["0.0", "> 0"], id="budget-0"
    ),
    pytest.param(
        ["controller.time_budget=-1"], "controller.time_budget", ["-1.0", "> 0"], id="budget-neg"
    ),
    pytest.param(  # within the state bounds, the forearm folded up to the base
        ["initial_state=[0.0, 0.0, 1.0, 0.0, 0.0, 1.5, 2.2]"],
        "initial_state",
        ["m below the base", "clearance.d_min is 0.1 m"],
        id="x0-in-clearance",
    ),
    pytest.param(
        ["controller.hierarchy.rel_tol=1e308"],
        "controller.hierarchy.rel_tol",
        ["1e+308", "[0, 1]"],
        id="rel-tol-huge",
    ),
    *(
        pytest.param([f"{key}={v}"], key, [f"{v:.1f}", rule], id=f"regularizer-scale-{v}")
        for key in ["controller.hierarchy.regularizer_scale"]
        for v, rule in [(0, "> 0"), (2, "<= 1")]
    ),
    pytest.param(
        ["tasks.tracking.weight=1e308"], "tasks.tracking.weight", ["1e+308", "[0, 1e+09]"], id="w"
    ),
    pytest.param(['name=""'], "name", ["''", "non-empty"], id="empty-name"),
    pytest.param(["max_failure_ratio=2"], "max_failure_ratio", ["2", "[0, 1]"], id="ratio-2"),
]


@pytest.mark.parametrize(("sets", "key", "fragments"), SANITY_LIMITS)
def test_value_beyond_a_sanity_limit_is_one_line_naming_key_value_and_range(
    sets, key, fragments, tmp_path, capsys
):
    argv = ["run", "waypoints", "--check", "--out", str(tmp_path / "out")]
    for s in sets:
        argv += ["--set", s]
    line = refused_fast(argv, capsys)
    assert line.startswith(f"{key}: "), line
    for f in fragments:
        assert f in line, line


def test_negative_task_delta_is_one_line_naming_the_tasks_key(tmp_path, capsys):
    argv = ["run", "planar", "--set", "tasks.cond.delta=-1", "--check", "--out", str(tmp_path)]
    line = refused_fast(argv, capsys)
    assert line.startswith("tasks.cond.delta: "), line
    assert "-1" in line and "[0, 1]" in line, line


@pytest.mark.parametrize("key", ["abs_tol", "rel_tol"])
def test_zero_hierarchy_tolerance_is_accepted(key, tmp_path, capsys):
    argv = ["run", "waypoints", "--variant", "hierarchical", "--check", "--out", str(tmp_path)]
    assert main([*argv, "--set", f"controller.hierarchy.{key}=0"]) == 0
    out, err = capsys.readouterr()
    assert out.rstrip().endswith(": ok") and err == ""


ROBOT_EDITS = [
    pytest.param(
        ("mass = 0.06,", "mass = 1e30,"),
        "joints[0].link.mass",
        ["1e+30", "[0, 1000] kg"],
        id="heavy-link",
    ),
    pytest.param(
        ("inertia = [1.5e-5, 1.5e-5, 1.0e-5,", "inertia = [1.0, 1.0, 5.0,"),
        "joints[0].link.inertia",
        ["[1.0, 1.0, 5.0]", "I1 + I2 >= I3"],
        id="inertia-triangle",
    ),
    pytest.param(
        ('name = "pan"', 'name = "base_link"'),
        "joints[0].name",
        ["'base_link'", "used twice"],
        id="joint-named-base-link",
    ),
]


@pytest.mark.parametrize(("edit", "key", "fragments"), ROBOT_EDITS)
def test_unphysical_robot_file_is_one_line_naming_file_key_and_value(
    edit, key, fragments, tmp_path, capsys
):
    text = ROBOT_TOML.read_text()
    old, new = edit
    assert text.count(old) == 1
    robot = tmp_path / "robot.toml"
    robot.write_text(text.replace(old, new))
    argv = ["run", "waypoints", "--set", f'robot="{robot}"', "--check", "--out", str(tmp_path)]
    line = refused_fast(argv, capsys)
    assert line.startswith(f"{robot}: robot.{key}: "), line
    for f in fragments:
        assert f in line, line


# --------------------------------------------------------------------------- exit codes


def test_short_run_that_flies_exits_0(tmp_path, no_figures, capsys):
    out = tmp_path / "out"
    argv = ["run", "waypoints", "--variant", "tracking-only", "--set", "duration=1", "--quiet"]
    assert main([*argv, "--out", str(out)]) == 0
    assert "did not fly" not in capsys.readouterr().err
    summary = read_json(out / "tracking-only" / "summary.json")
    assert summary["flight_ok"] is True and summary["flight_problem"] == ""
    assert summary["steps"] == 2


def test_run_whose_steps_all_fail_exits_3_and_keeps_its_outputs(tmp_path, no_figures, capsys):
    out = tmp_path / "out"
    argv = ["run", "waypoints", "--variant", "tracking-only", "--set", "duration=1", "--quiet"]
    argv += ["--set", "controller.time_budget=1e-9", "--out", str(out)]  # every solve too slow
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "the run did not fly: tracking-only: 2 of 2 steps stopped the robot" in err, err
    run = out / "tracking-only"
    summary = read_json(run / "summary.json")
    assert summary["flight_ok"] is False and "2 of 2 steps stopped" in summary["flight_problem"]
    assert summary["steps_by_status"] == {"stopped": 2}
    assert len(RunLog.load(run)) == 2
    assert (run / "config.toml").is_file() and (run / "robot.xml").is_file()
    assert not list(tmp_path.glob("out.*"))  # moved into place, lock released


def test_failure_ratio_above_max_fails_the_flight_and_at_it_does_not():
    from aeromanip.experiment.runner import verdict

    def summary(fallback, stopped=0):
        counts = {"ok": 100 - fallback - stopped, "fallback": fallback, "stopped": stopped}
        return {"steps": 100, "steps_by_status": counts}

    assert verdict(summary(5), 0.05)["flight_ok"] is True
    over = verdict(summary(6), 0.05)
    assert over["flight_ok"] is False and "6 of 100 steps failed" in over["flight_problem"]
    assert verdict(summary(6), 0.1)["flight_ok"] is True
    one_stop = verdict(summary(0, stopped=1), 0.5)  # a stop never passes, whatever the ratio
    assert one_stop["flight_ok"] is False and "1 of 100 steps stopped" in one_stop["flight_problem"]


# ------------------------------------------------------------------ aeromanip plot DIR


@pytest.fixture(scope="module")
def flown_run(tmp_path_factory):
    """A real 2-step run directory (no figures), for the plot tests to copy and spoil."""
    import aeromanip.experiment.runner as runner

    out = tmp_path_factory.mktemp("flown") / "run"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(runner, "plot_run", lambda *a, **k: [])
        rc = main(["run", str(write_tiny(out.parent)), "--quiet", "--out", str(out)])
    assert rc == 0
    assert len(RunLog.load(out, require_rows=True)) == 2 and not (out / "figures").exists()
    return out


def _spoil_log_empty(run: Path) -> None:
    (run / "log.csv").write_text("")


def _spoil_log_header_only(run: Path) -> None:
    log = run / "log.csv"
    log.write_text(log.read_text().splitlines()[0] + "\n")


def _spoil_log_is_a_directory(run: Path) -> None:
    (run / "log.csv").unlink()
    (run / "log.csv").mkdir()


def _spoil_log_binary(run: Path) -> None:
    (run / "log.csv").write_bytes(bytes(range(256)) * 8)


def _spoil_meta_truncated(run: Path) -> None:
    meta = run / "meta.json"
    meta.write_text(meta.read_text()[:40])


def _spoil_meta_not_an_object(run: Path) -> None:
    (run / "meta.json").write_text("[1, 2]\n")


def _spoil_meta_bounds(run: Path) -> None:
    meta = read_json(run / "meta.json")
    meta["bounds"] = {"x": "abc"}
    (run / "meta.json").write_text(json.dumps(meta))


@pytest.mark.parametrize(
    ("spoil", "message"),
    [
        (_spoil_log_empty, "empty run log"),
        (_spoil_log_header_only, "no rows"),
        (_spoil_log_is_a_directory, "no log.csv here"),
        (_spoil_log_binary, "cannot read run log"),
        (_spoil_meta_truncated, "cannot read run metadata"),
        (_spoil_meta_not_an_object, "run metadata must be a JSON object"),
        (_spoil_meta_bounds, "meta.bounds.x"),
    ],
    ids=lambda v: getattr(v, "__name__", "")[7:] or None,
)
def test_plot_of_a_spoilt_run_is_one_line_exit_2_and_draws_nothing(
    spoil, message, flown_run, tmp_path, capsys
):
    run = tmp_path / "run"
    shutil.copytree(flown_run, run)
    spoil(run)
    assert main(["plot", str(run)]) == 2
    line = error_line(capsys)
    assert message in line, line
    assert not (run / "figures").exists()


# ----------------------------------------------------------------- Controller.step input


@pytest.fixture(scope="module")
def controller(small_problem):
    from aeromanip.nmpc.controller import Controller

    return Controller(small_problem, "weighted", "ipopt")


X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])


@pytest.mark.parametrize(
    ("state", "t", "message"),
    [
        ("abc", 0.0, "state: expected 7 numbers"),
        (X0, None, "t: must be a finite number"),
        (X0, "1", "t: must be a finite number"),
        ([1, 2], 0.0, "state: expected 7 values (x, y, z, yaw, q1, q2, q3), got 2"),
        (X0, float("nan"), "t: must be a finite number"),
        (np.where(np.arange(7) == 5, np.nan, X0), 0.0, "state: q2 is not finite"),
    ],
    ids=["state-text", "t-none", "t-text", "state-short", "t-nan", "state-nan"],
)
def test_controller_step_rejects_malformed_input_with_state_error(state, t, message, controller):
    with pytest.raises(StateError) as e:
        controller.step(state, t)
    assert message in str(e.value)
    assert controller.step(X0, 0.0).status == "ok"  # refused input left the controller usable


# ------------------------------------------------------------- run directories: lock, kept


def test_second_run_into_the_same_out_is_refused_naming_the_lock(tiny, tmp_path, capsys):
    out = tmp_path / "out"
    proc = start_run(tiny, "out", tmp_path)
    try:
        wait_until(proc, lambda: any(tmp_path.glob("out.partial-*")), "staging directory")
        rc = main(["run", str(tiny), "--quiet", "--out", str(out)])
        line = error_line(capsys, quiet=False)  # it says "running" before it locks
        assert rc == 2, line
        assert line.startswith(f"--out: {out}") and f"lock {out}.lock" in line, line
        assert not (tmp_path / f"out.partial-{os.getpid()}").exists()
        _, err = stop(proc, signal.SIGINT)
    finally:
        kill_if_running(proc)
    assert proc.returncode == 130, err
    assert (out / "summary.json").is_file()  # the first run, kept as flown


def test_rerun_into_the_same_out_keeps_the_first_as_previous(tiny, tmp_path, no_figures):
    out = tmp_path / "out"
    assert main(["run", str(tiny), "--quiet", "--out", str(out)]) == 0
    first = read_json(out / "summary.json")
    assert main(["run", str(tiny), "--set", "duration=1.5", "--quiet", "--out", str(out)]) == 0
    assert read_json(tmp_path / "out.previous" / "summary.json") == first
    assert read_json(out / "summary.json")["steps"] == 3 and first["steps"] == 2
    assert sorted(p.name for p in tmp_path.glob("out*")) == ["out", "out.previous"]


def test_interrupted_run_keeps_its_rows_and_the_previous_run(tiny, tmp_path, no_figures):
    out = tmp_path / "out"
    assert main(["run", str(tiny), "--quiet", "--out", str(out)]) == 0
    complete = read_json(out / "summary.json")
    proc = start_run(tiny, "out", tmp_path)
    try:
        staging = tmp_path / f"out.partial-{proc.pid}"
        wait_until(proc, lambda: rows_on_disk(staging) > 0, "rows on disk")
        _, err = stop(proc, signal.SIGINT)
    finally:
        kill_if_running(proc)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted (SIGINT)" in err, err
    log = RunLog.load(out)
    assert len(log) > 0 and log.column("t")[0] == 0.0
    summary = read_json(out / "summary.json")
    assert summary["interrupted"] is True and summary["steps"] == len(log)
    assert read_json(tmp_path / "out.previous" / "summary.json") == complete
    assert not staging.exists() and not (tmp_path / "out.lock").exists()


def test_killed_run_leaves_its_rows_in_partial_and_out_untouched(tiny, tmp_path, no_figures):
    out = tmp_path / "out"
    assert main(["run", str(tiny), "--quiet", "--out", str(out)]) == 0
    complete = read_json(out / "summary.json")
    proc = start_run(tiny, "out", tmp_path)
    try:
        staging = tmp_path / f"out.partial-{proc.pid}"
        wait_until(proc, lambda: rows_on_disk(staging) > 0, "rows on disk")
        stop(proc, signal.SIGKILL)
    finally:
        kill_if_running(proc)
    assert proc.returncode == -signal.SIGKILL
    assert len(RunLog.load(staging)) > 0
    assert read_json(out / "summary.json") == complete
    assert not (tmp_path / "out.previous").exists()
    # the dead run's lock file is left, but no longer held: the next run goes ahead
    assert main(["run", str(tiny), "--quiet", "--out", str(out)]) == 0
    assert read_json(tmp_path / "out.previous" / "summary.json") == complete


def test_an_unknown_mujoco_gl_is_one_line_naming_the_variable(tmp_path):
    """MuJoCo's import fails outright on a MUJOCO_GL value it does not know (even for a
    kinematic run: the simulators are all discovered): one line, exit 2, nothing built."""
    env = {**os.environ, "MUJOCO_GL": "foo"}
    cmd = [sys.executable, "-m", "aeromanip.cli", "run", "flight", "--check"]
    p = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=WAIT_S)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("aeromanip: error: MUJOCO_GL='foo': "), lines
    assert "egl" in lines[0] and not list(tmp_path.iterdir())
