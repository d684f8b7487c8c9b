"""The feedback noise model (sim/feedback.py) against a brute-force simulation of the
estimator it models: every measurement of the outer-loop rate filtered one by one."""

import math

import numpy as np
import pytest

from aeromanip.sim.feedback import FeedbackNoise

STD = np.array([0.001, 0.002, 0.0005])
RATE_HZ, T_S = 100.0, 0.1


def brute_force(n_samples, every, seed):
    """``e <- a e + (1 - a) n`` at each of ``n_samples`` measurements; read every ``every``."""
    rng = np.random.default_rng(seed)
    a = math.exp(-1.0 / (RATE_HZ * T_S))
    e = STD * math.sqrt((1 - a) / (1 + a)) * rng.normal(size=3)
    out = []
    for k in range(1, n_samples + 1):
        e = a * e + (1 - a) * STD * rng.normal(size=3)
        if k % every == 0:
            out.append(e.copy())
    return np.array(out)


@pytest.mark.parametrize("every", [1, 5, 20])  # read at 100, 20 and 5 Hz
def test_readings_have_the_estimators_spread_and_correlation_whatever_the_read_rate(every):
    reads = 4000
    noise = FeedbackNoise(STD, T_S, RATE_HZ, seed=1)
    exact = np.array([noise.error(k * every / RATE_HZ) for k in range(1, reads + 1)])
    brute = brute_force(reads * every, every, seed=2)
    a = math.exp(-1.0 / (RATE_HZ * T_S))
    std = STD * math.sqrt((1 - a) / (1 + a))  # the filter's stationary spread
    lag = a**every  # correlation of two readings ``every`` samples apart
    for e in (exact, brute):
        assert np.allclose(e.std(axis=0), std, rtol=0.12)
        rho = [np.corrcoef(e[1:, i], e[:-1, i])[0, 1] for i in range(3)]
        assert np.allclose(rho, lag, atol=0.06)
    assert std[0] < 0.25 * STD[0]  # an estimate is much smoother than one measurement


def test_reading_twice_at_one_time_gives_the_same_error_and_white_noise_is_fresh():
    noise = FeedbackNoise(STD, T_S, RATE_HZ, seed=3)
    np.testing.assert_array_equal(noise.error(0.5), noise.error(0.5))
    white = FeedbackNoise(STD, 0.0, RATE_HZ, seed=3)
    first, second = white.error(0.5), white.error(0.5)
    assert not np.allclose(first, second)
    rng = np.random.default_rng(3)  # one draw per DoF, in order
    np.testing.assert_array_equal(first, [rng.normal(0.0, s) for s in STD])
