"""``aeromanip sweep``: campaigns on a local Ray of 2 CPUs, started once for the module.

The campaigns fly the planar scenario for 0.5 s (5 steps). Failures are real: a
simulator of this module (``test_sweep:CrashOnce``, imported by the workers from this
directory) kills its own worker process in the middle of a run, the first time only (a
marker file records it), and ``test_sweep:FailingSim`` raises in flight.
"""

import importlib.util
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from aeromanip.cli import main
from aeromanip.sim.kinematic import KinematicSimulator
from aeromanip.sweep import campaign as campaign_mod
from aeromanip.sweep.axes import make_spec, parse_grid, parse_random
from aeromanip.sweep.fanout import ProgressLine
from aeromanip.sweep.plan import plan_campaign
from aeromanip.sweep.results import read_results

ray = pytest.importorskip("ray")

TESTS_DIR = Path(__file__).resolve().parent
MARKER_ENV = "AEROMANIP_TEST_KILL_MARKER"  # where CrashOnce records the worker it killed
DRIVER_ENV = "AEROMANIP_TEST_DRIVER_PID"  # never kill the test process itself
SHORT = ["planar", "--variant", "cond-default", "--set", "duration=0.5"]
KILL_AT_STEP = 3


class CrashOnce(KinematicSimulator):
    """The kinematic simulator, except that the first run to reach step 3 in a campaign
    kills its worker process there (``os._exit``), as a segfault or the OOM killer would."""

    def advance(self, u, plan_x, dt):
        self.steps = getattr(self, "steps", 0) + 1
        marker = os.environ.get(MARKER_ENV)
        if self.steps == KILL_AT_STEP and marker and os.environ.get(DRIVER_ENV) != str(os.getpid()):
            try:
                fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:  # killed one already
                pass
            else:
                os.write(fd, str(os.getpid()).encode())
                os.close(fd)
                os._exit(17)
        super().advance(u, plan_x, dt)


class FailingSim(KinematicSimulator):
    """A simulator that fails in flight."""

    def advance(self, u, plan_x, dt):
        raise RuntimeError("simulated sensor fault")


class BlowingUpSim(KinematicSimulator):
    """A simulator whose state turns not finite after two steps (the run stops, kept)."""

    def advance(self, u, plan_x, dt):
        super().advance(u, plan_x, dt)
        self.steps = getattr(self, "steps", 0) + 1
        if self.steps > 2:
            self.x[0] = float("nan")


@pytest.fixture(scope="module")
def local_ray(tmp_path_factory):
    """Ray with 2 CPUs whose workers import this module (``PYTHONPATH``)."""
    saved = {k: os.environ.get(k) for k in ("PYTHONPATH", MARKER_ENV, DRIVER_ENV)}
    path = [str(TESTS_DIR), saved["PYTHONPATH"]]
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in path if p)
    os.environ[MARKER_ENV] = str(tmp_path_factory.mktemp("kill") / "killed-pid")
    os.environ[DRIVER_ENV] = str(os.getpid())
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    try:
        ray.init(
            address="local",
            num_cpus=2,
            include_dashboard=False,
            log_to_driver=False,
            object_store_memory=128 * 2**20,
            _node_ip_address="127.0.0.1",
        )
        yield Path(os.environ[MARKER_ENV])
    finally:
        ray.shutdown()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def sweep(out, *args, base=SHORT):
    return main(["sweep", *base, "--out", str(out), "--no-run-figures", *args])


def rows_of(out):
    return {r["run_id"]: r for r in read_results(Path(out) / "results.csv")}


# --- what runs: spec ------------------------------------------------------------------


def test_grid_values_are_read_as_set_reads_them():
    assert parse_grid("initial_state=[0, 1],[2, 3]").values == ([0, 1], [2, 3])
    assert parse_grid("variant=cond-off,cond-high").values == ("cond-off", "cond-high")
    assert parse_grid("tasks.cond.weight=0,1e-3, 0.1").values == (0, 0.001, 0.1)


def test_run_ids_depend_on_values_only():
    a = make_spec(["a.x=1,2", "b.y=3"], base=["c.z=1"]).runs()
    b = make_spec(["b.y=3", "a.x=2.0,1"], base=["c.z=1"]).runs()
    assert len(a) == 2 and len({r.run_id for r in a}) == 2
    ids_b = {r.values["a.x"]: r.run_id for r in b}
    assert a[0].run_id == make_spec(["a.x=1", "b.y=3"], base=["c.z=1"]).runs()[0].run_id
    assert a[1].run_id != ids_b[2.0]  # 2 (integer) and 2.0 (float) are different values
    assert make_spec(["a.x=0.001"]).runs()[0].run_id == make_spec(["a.x=1e-3"]).runs()[0].run_id


def test_random_draws_are_reproducible_and_typed():
    spec = make_spec(random=["n=1:5", "w=1e-4:1e-1:log"], samples=20, random_seed=7)
    runs = spec.runs()
    assert [r.values for r in runs] == [r.values for r in spec.runs()]
    assert all(isinstance(r.values["n"], int) and 1 <= r.values["n"] <= 5 for r in runs)
    assert all(1e-4 <= r.values["w"] <= 1e-1 for r in runs)
    assert parse_random("k=-1:1").lo == -1
    assert len(make_spec(["a.x=1,2"], seeds=3).runs()) == 6


def test_runs_differing_only_in_noise_share_one_problem():
    flight = plan_campaign("flight", make_spec(seeds=4, base=["duration=1"]))
    assert len(flight.runs) == 4 and len(flight.example) == 1
    weights = plan_campaign("planar", make_spec(["tasks.cond.weight=0,1"], variant="cond-default"))
    assert len(weights.example) == 2


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--grid", "tasks.cond.weight"], "--grid 'tasks.cond.weight': expected KEY=V1,V2"),
        (["--grid", "tasks.cond.wieght=1,2"], "tasks.cond.wieght: unknown key"),
        (["--grid", "nosuch.key=1,2"], "--grid nosuch.key=1: unknown key 'nosuch'"),
        (["--grid", "tasks.cond.weight=1,1"], "value 1 is given twice"),
        (["--random", "tasks.cond.weight=1:0", "--samples", "2"], "LO 1 must be < HI 0"),
        (["--random", "tasks.cond.weight=0:1:log", "--samples", "2"], "a log range needs 0 <"),
        (["--random", "tasks.cond.weight=0:1"], "needs --samples N"),
        (["--samples", "3"], "--samples 3: needs at least one --random"),
        (["--grid", "controller.horizon=0,-1"], "controller.horizon: must be in [1, 500]"),
        (["--grid", "a.b=1", "--set", "a.b=2"], "a.b is also swept"),
        (["--seeds", "2"], "--seeds physics.seed=0: unknown key 'physics'"),
        (["--grid", "tasks.cond.weight=1", "--workers", "0"], "--workers: must be in [1,"),
        (["--grid", "tasks.cond.weight=1", "--pareto", "ee_rmse_m"], "expected 2 comma-separated"),
        ([], "nothing to sweep"),
        (
            ["--grid", "tasks.cond.weight=1", "--address", "127.0.0.1:1"],
            "--address 127.0.0.1:1: no Ray cluster answers there",
        ),
        (["--grid", "tasks.cond.weight=1", "--address", "head"], "expected HOST:PORT, ray://"),
    ],
)
def test_user_errors_are_one_line_before_ray_starts(args, message, tmp_path, capsys, monkeypatch):
    def no_ray(*a, **k):
        raise AssertionError("Ray started")

    monkeypatch.setattr(campaign_mod, "ray_session", no_ray)
    assert sweep(tmp_path / "out", *args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_without_ray_the_command_stops_before_any_work(tmp_path, capsys, monkeypatch):
    real = importlib.util.find_spec

    def find_spec(name, *args):
        return None if name == "ray" else real(name, *args)

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    assert sweep(tmp_path / "out", "--grid", "tasks.cond.weight=0,1") == 2
    err = capsys.readouterr().err
    assert "needs Ray, not installed: pip install 'aeromanip[sweep]'" in err
    assert not (tmp_path / "out").exists()


def test_a_variant_that_overrides_a_swept_key_is_refused(tmp_path, capsys):
    args = ["sweep", "planar", "--grid", "tasks.cond.weight=0,1", "--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert "variant cond-off of planar sets it" in capsys.readouterr().err


def test_seeds_of_a_noiseless_simulator_are_refused(tmp_path, capsys):
    args = ["sweep", "flight", "--set", "sim=kinematic", "--seeds", "3"]
    assert main([*args, "--out", str(tmp_path / "o"), "--check"]) == 2
    assert "--seeds 3: physics.seed changes nothing with sim = kinematic" in capsys.readouterr().err


def test_unwritable_out_is_refused(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    assert sweep(tmp_path / "file" / "out", "--grid", "tasks.cond.weight=1") == 2
    assert "--out: " in capsys.readouterr().err


# --- campaigns on Ray -------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_sweep(local_ray, tmp_path_factory):
    """6 runs (3 weights x 2 horizons), each run's figures drawn (the whole contract)."""
    out = tmp_path_factory.mktemp("small") / "sweep"
    args = ["--grid", "tasks.cond.weight=0,1e-3,0.1", "--grid", "controller.horizon=3,5"]
    code = main(["sweep", *SHORT, "--out", str(out), *args, "--quiet"])
    return out, code


def test_a_small_sweep_writes_every_run_and_a_row_each(small_sweep):
    out, code = small_sweep
    assert code == 0
    rows = rows_of(out)
    assert len(rows) == 6 and {r["status"] for r in rows.values()} == {"done"}
    combos = {(float(r["tasks.cond.weight"]), int(r["controller.horizon"])) for r in rows.values()}
    assert combos == {(w, h) for w in (0, 1e-3, 0.1) for h in (3, 5)}
    for run_id, row in rows.items():
        d = out / "runs" / run_id
        for f in ("config.toml", "robot.urdf", "robot.xml", "log.csv", "summary.json"):
            assert (d / f).is_file(), f
        assert list((d / "figures").glob("*.png"))
        config = (d / "config.toml").read_text()
        assert f"horizon = {row['controller.horizon']}\n" in config
        summary = json.loads((d / "summary.json").read_text())
        for key in ("ee_rmse_m", "cog_xy_mean_m", "cond_mean", "steps"):
            assert float(row[key]) == pytest.approx(summary[key], rel=1e-12)
        assert row["steps_by_status.ok"] == str(summary["steps_by_status"]["ok"])
    names = {p.name for p in (out / "figures").glob("*.png")}
    assert names == {
        "sweep_tasks.cond.weight.png",
        "sweep_controller.horizon.png",
        "pareto_ee_rmse_m__cog_xy_mean_m.png",
    }


def test_a_second_invocation_runs_nothing_new(small_sweep, capsys):
    out, _ = small_sweep
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("runs/*/summary.json")}
    args = ["--grid", "tasks.cond.weight=0.1,0,1e-3", "--grid", "controller.horizon=5,3"]
    assert sweep(out, *args) == 0
    assert "0 run(s) flown now, 6 done before" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in out.glob("runs/*/summary.json")} == stamps


def test_aeromanip_plot_redraws_the_sweep_figures(small_sweep, capsys):
    out, _ = small_sweep
    for p in (out / "figures").glob("*.png"):
        p.unlink()
    assert main(["plot", str(out)]) == 0
    assert len(capsys.readouterr().out.split()) == 3 == len(list((out / "figures").glob("*.png")))


def test_a_resumed_campaign_runs_only_the_missing_runs(local_ray, tmp_path, capsys):
    out = tmp_path / "sweep"
    args = ["--grid", "tasks.cond.weight=0,1e-3,0.1,1"]
    assert sweep(out, *args) == 0
    runs = sorted((out / "runs").iterdir())
    lost = runs[:2]  # as if the campaign had been killed before these two finished
    for d in lost:
        os.rename(d, d.with_name(f"{d.name}.partial-99999"))  # left staged by a dead worker
    kept = {d: (d / "summary.json").stat().st_mtime_ns for d in runs[2:]}
    capsys.readouterr()
    assert sweep(out, *args) == 0
    assert "2 run(s) flown now, 2 done before" in capsys.readouterr().out
    assert all((d / "summary.json").is_file() for d in lost)
    assert not list((out / "runs").glob("*.partial-*"))
    assert {d: (d / "summary.json").stat().st_mtime_ns for d in runs[2:]} == kept
    assert len(rows_of(out)) == 4


def test_a_worker_killed_mid_run_is_retried_and_no_row_is_lost(local_ray, tmp_path):
    marker = local_ray
    out = tmp_path / "sweep"
    code = sweep(
        out, "--grid", "tasks.cond.weight=0,1e-3,1e-2,0.1", "--set", "sim=test_sweep:CrashOnce"
    )
    killed = int(marker.read_text())  # a worker did die, mid-run
    assert code == 0
    rows = rows_of(out)
    assert len(rows) == 4 and {r["status"] for r in rows.values()} == {"done"}
    pids = {json.loads(p.read_text())["pid"] for p in out.glob("runs/*/task.json")}
    assert killed not in pids  # the killed run finished in another worker
    assert not list((out / "runs").glob("*.partial-*"))


def test_failed_runs_are_recorded_with_their_error_and_the_others_finish(local_ray, tmp_path):
    out = tmp_path / "sweep"
    sims = ("kinematic", "test_sweep:FailingSim", "test_sweep:BlowingUpSim")
    code = sweep(out, "--grid", "controller.horizon=0,3", "--grid", f"sim={','.join(sims)}")
    assert code == 3
    rows = list(rows_of(out).values())
    assert len(rows) == 6
    status = {(r["controller.horizon"], r["sim"]): (r["status"], r["error"]) for r in rows}
    assert status[("3", "kinematic")] == ("done", "")
    assert status[("3", "test_sweep:FailingSim")][0] == "failed"
    assert "RuntimeError: simulated sensor fault" in status[("3", "test_sweep:FailingSim")][1]
    # stopped by a state not finite: failed, its rows kept with a summary saying why
    assert status[("3", "test_sweep:BlowingUpSim")][0] == "failed"
    assert "StateError: state: y is not finite" in status[("3", "test_sweep:BlowingUpSim")][1]
    (blown,) = [r["run_id"] for r in rows if r["sim"] == sims[2] and r["controller.horizon"] == "3"]
    summary = json.loads((out / "runs" / blown / "summary.json").read_text())
    assert summary["steps"] == 3 and "not finite" in summary["stopped_by"]
    for sim in sims:  # does not build: never sent to Ray
        assert status[("0", sim)][0] == "failed"
        assert "controller.horizon: must be in [1, 500], got 0" in status[("0", sim)][1]
    failed = json.loads((out / "failed.json").read_text())
    assert len(failed) == 5 and all(f["error"] for f in failed.values())


def test_scaling_flies_the_campaign_once_per_worker_count(local_ray, tmp_path, capsys):
    out = tmp_path / "sweep"
    assert sweep(out, "--grid", "tasks.cond.weight=0,0.1", "--scaling", "1,2", "--quiet") == 0
    text = capsys.readouterr().out
    for n in (1, 2):
        rows = rows_of(out / f"workers-{n}")
        assert len(rows) == 2 and {r["status"] for r in rows.values()} == {"done"}
    table = text[text.index("workers") :].splitlines()
    assert [line.split()[:3] for line in table[1:3]] == [["1", "2", "0"], ["2", "2", "0"]]
    assert table[1].split()[4] == "1.00"  # the first count's speed-up over itself
    assert sweep(out, "--grid", "tasks.cond.weight=0,0.1", "--scaling", "1,2") == 2
    assert "workers-1 exists; a measurement flies every run" in capsys.readouterr().err


@pytest.mark.parametrize("text", ["1", "1,1", "0,2", "a,b"])
def test_bad_scaling_counts_are_refused(text, tmp_path, capsys):
    assert sweep(tmp_path / "o", "--grid", "tasks.cond.weight=0", "--scaling", text) == 2
    assert f"--scaling {text!r}: expected 2 to 8 distinct worker counts" in capsys.readouterr().err


def test_progress_counts_done_failed_left(capsys):
    p = ProgressLine(3, tty=False)
    p.update({"status": "done", "run_id": "a", "elapsed_s": 1.0}, "w=0")
    p.update({"status": "failed", "run_id": "b", "error": "ValueError: bad"}, "w=1")
    lines = capsys.readouterr().err.splitlines()
    assert "1/3  1 done, 0 failed, 2 left, eta " in lines[0] and lines[0].endswith("ok")
    assert "2/3  1 done, 1 failed, 1 left, eta " in lines[1]
    assert lines[1].endswith("FAILED: ValueError: bad") and "[################--------]" in lines[1]
    tty = ProgressLine(1, tty=True)  # a terminal: one bar redrawn in place
    tty.update({"status": "done", "run_id": "a"}, "w=0")
    err = capsys.readouterr().err
    assert err.count("\r") == 1 and err.endswith("1/1  1 done, 0 failed, 0 left, eta 0 s\n")


@pytest.mark.codegen
def test_each_problem_is_compiled_once_in_the_driver_not_in_the_workers(
    local_ray, tmp_path, monkeypatch, capsys
):
    """4 runs of one sqp problem, on a cold cache: the driver builds its libraries, the
    workers build none. The control: without the driver's build, the workers do build."""
    base = ["planar", "--variant", "cond-default", "--set", "controller.backend=sqp"]
    args = ["--set", "controller.horizon=3", "--grid", "duration=0.3,0.4,0.5,0.6"]
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path / "cache"))
    assert sweep(tmp_path / "sweep", *args, base=base) == 0
    text = capsys.readouterr().out
    assert "compiled once: 1 problem(s)" in text
    built = int(re.search(r"\((\d+) libraries built\)", text).group(1))
    assert built >= 1 and "built in the workers: 0" in text
    assert {r["cache_built"] for r in rows_of(tmp_path / "sweep").values()} == {"0"}

    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path / "cache2"))
    monkeypatch.setattr(campaign_mod, "precompile", lambda *a: {})
    assert sweep(tmp_path / "control", *args, base=base) == 0
    assert sum(int(r["cache_built"]) for r in rows_of(tmp_path / "control").values()) >= built


def test_the_command_starts_its_own_ray_and_resumes_after_sigint(local_ray, tmp_path):
    """From a shell: ``aeromanip sweep`` starts a local Ray of ``--workers`` CPUs; SIGINT
    after the first run stops it with exit 130, results.csv holding what finished; the
    same command, again, flies only the rest."""
    out = tmp_path / "sweep"
    args = [
        *SHORT,
        "--set",
        "duration=3",
        "--grid",
        "tasks.cond.weight=0,1e-3,1e-2,0.1",
        "--out",
        str(out),
        "--workers",
        "1",
        "--no-run-figures",
    ]
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    p = subprocess.Popen(
        [sys.executable, "-m", "aeromanip.cli", "sweep", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob("runs/*/summary.json")) and time.monotonic() < deadline:
            assert p.poll() is None, p.communicate()
            time.sleep(0.2)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err
    assert "interrupted" in err
    first = rows_of(out)
    assert 1 <= len(first) < 4 and {r["status"] for r in first.values()} == {"done"}
    assert main(["sweep", *args[:-3], "--no-run-figures", "--quiet"]) == 0
    rows = rows_of(out)
    assert len(rows) == 4 and {r["status"] for r in rows.values()} == {"done"}
