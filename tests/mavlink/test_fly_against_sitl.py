"""End to end: the ``flight`` scenario flown in real time by ``aeromanip fly`` over MAVLink
against ``aeromanip sitl`` (two processes, 127.0.0.1 only, every wait bounded).

One SITL serves three runtimes in turn (about 60 s in all):

A. a 30 s mission, completed: the vehicle's truth-log EE RMSE is within 1.5x of the same
   scenario flown in-process in physics; no deadline miss at 2 Hz; setpoints >= 20 Hz.
B. a runtime killed (SIGKILL) mid-flight: the SITL's offboard failsafe holds the vehicle
   (speed < 0.05 m/s, in place, arm still) within 1.5 s, inside its box.
D. a runtime stopped by Ctrl-C (SIGINT) mid-flight: it puts the vehicle in hold, checked,
   and exits 130 with its run directory.
C. the SITL killed (SIGKILL) mid-flight: the runtime reports link loss within 0.5 s of
   the last state and exits non-zero with its run directory intact.
"""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from aeromanip.experiment.closed_loop import simulate
from aeromanip.experiment.runlog import RunLog
from aeromanip.experiment.scenario import load_scenarios
from loopback import free_udp_port, start_sitl

pytest.importorskip("pymavlink")
pytestmark = pytest.mark.realtime  # the two processes fly against the wall clock

HOST = "127.0.0.1"
MISSION_S = 30.0
SITL_MAX_S = 240.0  # the SITL stops by itself after this, whatever happens
CLI = [sys.executable, "-m", "aeromanip.cli"]


def rows_in(path: Path) -> int:
    try:
        return max(0, len(path.read_text().splitlines()) - 1)
    except OSError:
        return 0


def wait_rows(proc: subprocess.Popen, log: Path, n: int, timeout_s: float) -> None:
    """Wait until ``log`` has ``n`` rows (the process streaming it must stay alive)."""
    end = time.monotonic() + timeout_s
    while rows_in(log) < n:
        assert proc.poll() is None, f"exited early ({proc.returncode}): {log}"
        assert time.monotonic() < end, f"no {n} rows in {log} within {timeout_s} s"
        time.sleep(0.05)


def fly(root: Path, name: str, port: int, duration: float) -> subprocess.Popen:
    return subprocess.Popen(
        [*CLI, "fly", "flight", "--link", f"udpin:{HOST}:{port}", "--out", str(root / name),
         "--set", f"duration={duration:g}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("mavlink")
    port = free_udp_port()
    sitl = start_sitl(root / "sitl", port, SITL_MAX_S)
    procs = [sitl]
    out = {"root": root}
    try:
        a = fly(root, "a", port, MISSION_S)
        procs.append(a)
        out["a_stdout"], out["a_stderr"] = a.communicate(timeout=MISSION_S + 60)
        out["a_rc"] = a.returncode
        b = fly(root, "b", port, MISSION_S)
        procs.append(b)
        wait_rows(b, root / f"b.partial-{b.pid}" / "log.csv", 7, 30)  # 3 s into it
        out["b_killed"] = time.time()
        b.kill()
        b.wait(timeout=10)
        time.sleep(3.0)  # the SITL fails safe and logs the hold
        d = fly(root, "d", port, MISSION_S)
        procs.append(d)
        wait_rows(d, root / f"d.partial-{d.pid}" / "log.csv", 7, 30)
        out["d_interrupted"] = time.time()
        d.send_signal(signal.SIGINT)  # Ctrl-C
        out["d_stdout"], out["d_stderr"] = d.communicate(timeout=15)
        out["d_rc"] = d.returncode
        time.sleep(3.0)
        c = fly(root, "c", port, MISSION_S)
        procs.append(c)
        wait_rows(c, root / f"c.partial-{c.pid}" / "log.csv", 5, 30)
        out["sitl_killed"] = time.time()
        sitl.kill()
        out["c_stdout"], out["c_stderr"] = c.communicate(timeout=15)
        out["c_rc"] = c.returncode
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.communicate(timeout=10)
    staged = list(root.glob("sitl.partial-*"))  # killed outright: its staging directory
    assert len(staged) == 1, staged
    out["truth"] = RunLog.load(staged[0])
    return out


def summary(d: Path) -> dict:
    return json.loads((d / "summary.json").read_text())


def test_mission_flew_in_real_time(flights):
    assert flights["a_rc"] == 0, flights["a_stderr"]
    s = summary(flights["root"] / "a")
    assert s["steps"] == round(MISSION_S / 0.5) and s["flight_ok"] and s["ending"] == "completed"
    assert s["deadline_misses"] == 0
    log = RunLog.load(flights["root"] / "a")
    assert log.missing_columns() == []
    assert np.all(log.column("deadline_miss") == 0)
    assert np.max(log.column("step_ms")) < 500.0  # each solve within the 2 Hz period
    assert s["setpoint_rate_hz"] >= 20.0
    assert np.nanmin(log.column("setpoints")[1:]) >= 10  # >= 20 Hz over every period
    assert s["setpoint_gap_max_ms"] < 500.0  # PX4 leaves offboard below 2 Hz
    assert s["state_age_ms_max"] < 100.0
    assert s["hold_accepted"]  # left holding at the end


def test_truth_rmse_within_1_5x_of_in_process_physics(flights):
    truth = flights["truth"]
    tm, status = truth.column("t_mission"), truth.column("status")
    start = summary(flights["root"] / "a")["start_wall_time"]
    a = (status == "offboard") & (truth.column("wall_time") < start + MISSION_S + 1.0)
    a &= np.isfinite(tm) & (tm <= MISSION_S)
    assert a.sum() >= 0.95 * MISSION_S * 20  # truth rows at 20 Hz over the whole mission
    over_mavlink = float(np.sqrt(np.mean(truth.ee_error()[a] ** 2)))
    sc = next(iter(load_scenarios("flight", [f"duration={MISSION_S:g}"]).values()))
    in_process = simulate(sc).summary()["ee_rmse_m"]
    print(f"EE RMSE: in-process {in_process:.5f} m, over MAVLink {over_mavlink:.5f} m")
    assert over_mavlink <= 1.5 * in_process


@pytest.mark.parametrize("stop", ["b_killed", "d_interrupted"])
def test_runtime_stopped_the_vehicle_holds_in_its_box(flights, stop):
    truth, killed = flights["truth"], flights[stop]
    wall = truth.column("wall_time")
    after = (wall >= killed) & (wall <= killed + 3.0)
    status = truth.column("status")[after]
    t_hold = wall[after][np.argmax(status == "hold")] - killed
    # killed: the offboard failsafe after 0.5 s; Ctrl-C: hold commanded at once
    assert np.any(status == "hold") and t_hold <= (0.5 if stop == "b_killed" else 0.0) + 0.1
    before = (wall > killed - 1.0) & (wall < killed)
    if stop == "b_killed":  # it was moving when killed (D starts where B's hold left it)
        assert np.max(truth.column("speed")[before]) > 0.05
    speed = truth.column("speed")
    slow = np.nonzero(after & ~((speed < 0.05) & (wall >= killed)))[0]  # last fast row
    t_slow = (wall[slow[-1] + 1] if slow.size else killed) - killed
    print(
        f"{stop} at {np.max(speed[before]):.3f} m/s: hold after {t_hold:.2f} s, "
        f"speed < 0.05 m/s from {t_slow:.2f} s on"
    )
    held = (wall >= killed + 1.5) & (wall <= killed + 3.0)
    assert held.sum() >= 20
    assert np.all(truth.column("status")[held] == "hold")
    assert np.max(truth.column("speed")[held]) < 0.05
    for c in ("x", "y", "z"):  # in place (no drift) ...
        assert np.ptp(truth.column(c)[held]) < 0.02, c
    for q in ("q1", "q2", "q3"):  # ... and the arm still
        assert np.ptp(truth.column(q)[held]) < 2e-3, q
    box = {"x": (-0.6, 0.6), "y": (-0.6, 0.6), "z": (0.8, 1.5)}  # flight's platform_box
    for c, (lo, hi) in box.items():
        v = truth.column(c)[after]
        assert np.all((v >= lo) & (v <= hi)), c


def test_sitl_killed_the_runtime_reports_link_loss(flights):
    assert flights["c_rc"] == 4, flights["c_stderr"]
    assert "link lost" in flights["c_stderr"]
    d = flights["root"] / "c"
    s = summary(d)
    assert s["link_lost"] and s["ending"] == "link lost"
    detected = s["link_lost_wall_time"] - flights["sitl_killed"]
    print(f"link loss reported {detected:.3f} s after the SITL was killed")
    # the last state came < 20 ms before the kill: loss is declared 0.5 s after it
    assert 0.4 <= detected <= 0.5 + 0.05
    assert 0.5 <= s["link_lost_state_age_s"] <= 0.55
    log = RunLog.load(d, require_rows=True)  # intact: every row readable, the contract's columns
    assert log.missing_columns() == [] and len(log) == s["steps"] >= 5
    assert (d / "config.toml").is_file() and (d / "robot.urdf").is_file()


def test_ctrl_c_leaves_the_vehicle_holding_and_exits_cleanly(flights):
    assert flights["d_rc"] == 130, flights["d_stderr"]
    assert "vehicle holding" in flights["d_stderr"] and "Traceback" not in flights["d_stderr"]
    d = flights["root"] / "d"
    s = summary(d)
    assert s["interrupted"] and s["ending"] == "interrupted" and s["hold_accepted"]
    assert len(RunLog.load(d, require_rows=True)) == s["steps"] >= 7
