"""Every reference's CasADi expression (what an exported controller computes) against its
NumPy ``sample``, before, inside and after its motion, at and between knots."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.references import Constant, Csv, Lissajous, Reference, SinusoidPhases, Waypoints

POINTS = np.array([[1.0, 0.0, 1.0], [1.5, 0.5, 1.2], [1.0, 1.0, 0.8], [0.5, 0.2, 1.0]])


def _csv(tmp_path) -> Csv:
    f = tmp_path / "ref.csv"
    rows = ["t,x,y,z", "0,0,0,1", "1.5,0.2,0.1,1.1", "4,0.2,-0.3,0.9", "9,1,0,1"]
    f.write_text("\n".join(rows) + "\n")
    return Csv(f)


def _references(tmp_path) -> dict[str, Reference]:
    return {
        "constant": Constant([0.1, -0.2, 0.9]),
        "lissajous": Lissajous([0, 0, 0.6], [0.7, 0.6, 0.2], [0.0125, 0.0091, 0.0067], [0.1, 0, 2]),
        "waypoints at times": Waypoints(POINTS, [0.0, 4.0, 7.0, 12.0]),
        "waypoints at speed": Waypoints(POINTS, speed=0.3, hold_s=1.0),
        "one waypoint": Waypoints(POINTS[:1], [2.0]),
        "sinusoids": SinusoidPhases([0, 0.1, 1], "y", [(3.0, 0.08, 0.1), (5.0, 1.0, 0.04)]),
        "csv": _csv(tmp_path),
    }


@pytest.mark.parametrize(
    "kind",
    ["constant", "lissajous", "waypoints at times", "waypoints at speed", "one waypoint",
     "sinusoids", "csv"],
)  # fmt: skip
def test_the_expression_is_the_sample_at_every_time(kind, tmp_path):
    ref = _references(tmp_path)[kind]
    t = ca.SX.sym("t")
    f = ca.Function("r", [t], [ref.expression(t)])
    end = ref.duration
    times = np.concatenate([[-5.0, 0.0], np.linspace(0, end, 97), [end, end + 0.5, end + 300]])
    times = np.concatenate([times, getattr(ref, "_knot_t", []), getattr(ref, "t", [])])
    got = np.array(f.map(times.size)(times[None, :])).T
    np.testing.assert_allclose(got, ref.sample(times), rtol=0, atol=1e-12)


def test_a_reference_without_an_expression_is_refused_in_one_line():
    class Spiral(Reference):
        duration = 1.0

        def sample(self, times):
            return np.zeros((len(times), 3))

    with pytest.raises(ConfigError, match="Spiral reference cannot be exported") as e:
        Spiral().expression(ca.SX.sym("t"))
    assert "\n" not in str(e.value)
