"""Rate measurement and identification (``aeromanip identify``), against truths computed
here: finite differences of the simulated state, a simulator whose response is a known
first-order lag, the kinematic simulator (no lag at all)."""

import subprocess
import sys
import tomllib

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.experiment.identification import identify
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.experiment.step_response import record_step
from aeromanip.robot.loader import load_robot
from aeromanip.sim.base import Simulator
from aeromanip.sim.physics import PhysicsSimulator

X8 = load_robot("x8-3dof")
X0 = np.array([0.0, 0.0, 1.0, 0.3, 0.0, 0.6, -1.2])


@pytest.mark.parametrize("setpoint", ["position", "velocity"])
def test_physics_rates_are_the_derivative_of_the_state(setpoint):
    sim = PhysicsSimulator(X8, setpoint=setpoint)
    sim.reset(X0)
    u = np.array([0.3, -0.2, 0.1, 0.4, 0.3, -0.2, 0.2])
    start = X0.copy()
    for _ in range(40):  # moving and tilted: the yaw rate is not the body z rate
        sim.advance(u, start, 0.01)
        start = start + 0.01 * u
    h = sim.h
    before = sim.true_state()
    r = sim.rates()
    sim.advance(u, start, h)
    after = sim.true_state()
    # over one physics step the state moves by h times the rate (semi-implicit Euler:
    # the position is updated with the velocity at the end of the step); the yaw, from the
    # quaternion rotated by the body rates, to first order in h
    fd, rates = (after - before) / h, sim.rates()
    yaw = X8.state_names.index("yaw")
    others = np.arange(7) != yaw
    np.testing.assert_allclose(fd[others], rates[others], atol=1e-9)
    assert abs(fd[yaw] - rates[yaw]) < 2e-4 * abs(fd[yaw])
    body_z_rate = sim.data.qvel[sim._free_v + 5]  # what tilt makes wrong: 100x further off
    assert abs(fd[yaw] - body_z_rate) > 100 * abs(fd[yaw] - rates[yaw])
    assert np.abs(r[:4]).max() > 0.05  # it moved
    assert abs(sim.extras()["roll"]) + abs(sim.extras()["pitch"]) > 1e-3  # tilted


class FirstOrderSimulator(Simulator):
    """Every DoF's rate lags its command by a known time constant (exact, analytic)."""

    kind = "first-order"

    def __init__(self, tau):
        self.tau = np.asarray(tau, dtype=float)

    def reset(self, x0):
        self.x, self.r = np.array(x0, dtype=float), np.zeros(len(x0))

    def advance(self, u, plan_x, dt):
        a = np.exp(-dt / self.tau)
        self.x = self.x + dt * u + self.tau * (1 - a) * (self.r - u)
        self.r = u + a * (self.r - u)

    def state(self):
        return self.x.copy()

    def rates(self):
        return self.r.copy()


def test_identification_recovers_known_time_constants():
    from aeromanip.experiment.step_response import fit_first_order

    tau = np.array([0.3, 0.25, 0.2, 0.08, 0.05, 0.03, 0.01])
    sim = FirstOrderSimulator(tau)
    for i in range(7):
        fit = fit_first_order(record_step(sim, X0, i, f"d{i}", 0.4, 2.0))
        assert fit.tau == pytest.approx(tau[i], rel=1e-4)
        assert fit.r2 > 0.999999 and fit.position_rms < 1e-6


def test_a_simulator_without_lag_identifies_as_the_papers_model():
    sc = load_scenarios("flight", ["sim='kinematic'"])[""]
    for rec, fit in identify(sc, duration=0.5):
        assert fit.tau == 0.0 and fit.position_rms < 1e-12, rec.dof


def test_the_fitted_model_predicts_the_physics_platform_better_than_no_lag():
    sc = load_scenarios("flight", ['physics.setpoint="velocity"'])[""]
    fits = {f.dof: f for _, f in identify(sc, duration=2.0)}
    for dof in ("x", "y", "z"):
        f = fits[dof]
        assert 0.05 < f.tau < 1.0 and f.r2 > 0.8, f
        assert f.position_rms < 0.6 * f.position_rms_0, f


def test_identify_command_writes_a_table_to_paste(tmp_path):
    out = tmp_path / "ident"
    cmd = [sys.executable, "-m", "aeromanip.cli", "identify", "flight", "--set", "sim='kinematic'"]
    cmd += ["--duration", "0.5", "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    table = tomllib.loads((out / "response.toml").read_text())["controller"]["response"]
    assert table == dict.fromkeys(X8.state_names, 0.0)
    assert (out / "step_responses.png").stat().st_size > 10_000
    bad = subprocess.run([*cmd[:-2], "--step", "2", "--out", str(out)], capture_output=True,
                         text=True, timeout=60)  # fmt: skip
    assert bad.returncode == 2 and "--step" in bad.stderr and "\n" not in bad.stderr.strip()


@pytest.mark.parametrize(
    "override, key",
    [
        ("controller.latency=0.5", "controller.latency"),
        ("controller.latency=0.0031", "controller.latency"),  # not whole physics steps
        ("controller.dt=0.1003", "controller.dt"),
        ("bounds.acceleration={q9=1.0}", "bounds.acceleration.q9"),
        ("bounds.acceleration={x=-1.0}", "bounds.acceleration.x"),
        ("controller.response={x=-0.1}", "controller.response.x"),
        ("controller.response={yaw=50.0}", "controller.response.yaw"),
        ("controller.weights_dt=0.0", "controller.weights_dt"),
        ('physics.setpoint="torque"', "physics.setpoint"),
    ],
)
def test_bad_values_name_their_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_scenarios("flight", [override])
