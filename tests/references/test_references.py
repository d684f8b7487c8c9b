"""Reference trajectories: exactness at waypoints, continuity, sinusoid content, CSV, errors."""

from __future__ import annotations

import numpy as np
import pytest

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references import (
    Constant,
    Csv,
    Lissajous,
    SinusoidPhases,
    Waypoints,
    reference_from_table,
)

POINTS = np.array([[1.0, 0.0, 1.0], [1.5, 0.5, 1.2], [1.0, 1.0, 0.8], [0.5, 0.2, 1.0]])
TIMES = np.array([0.0, 4.0, 7.0, 12.0])


def _derivs(ref, t, h=1e-4):
    p = ref.sample(np.array([t - h, t, t + h]))
    v = (p[2] - p[0]) / (2 * h)
    a = (p[2] - 2 * p[1] + p[0]) / h**2
    return v, a


def test_waypoints_pass_through_points_at_their_times():
    ref = Waypoints(POINTS, TIMES)
    np.testing.assert_allclose(ref.sample(TIMES), POINTS, atol=1e-12)
    for t, p in zip(TIMES, POINTS, strict=True):
        np.testing.assert_allclose(ref.position(t), p, atol=1e-12)
    assert ref.duration == pytest.approx(12.0)
    np.testing.assert_allclose(ref.position(-3.0), POINTS[0])
    np.testing.assert_allclose(ref.position(100.0), POINTS[-1])


def test_waypoints_zero_velocity_and_c2_at_boundaries():
    ref = Waypoints(POINTS, TIMES)
    h = 1e-4
    for t in TIMES[1:-1]:
        v, a = _derivs(ref, t, h)
        np.testing.assert_allclose(v, 0.0, atol=1e-6)
        np.testing.assert_allclose(a, 0.0, atol=1e-3)
        # one-sided accelerations on both sides tend to the same (zero) value: C2
        left = ref.sample(np.array([t - 2 * h, t - h, t]))
        right = ref.sample(np.array([t, t + h, t + 2 * h]))
        a_left = (left[2] - 2 * left[1] + left[0]) / h**2
        a_right = (right[2] - 2 * right[1] + right[0]) / h**2
        np.testing.assert_allclose(a_left, a_right, atol=1e-2)


def test_waypoints_min_jerk_midpoint_speed():
    ref = Waypoints([[0, 0, 0], [1, 0, 0]], [0.0, 2.0])
    np.testing.assert_allclose(ref.position(1.0), [0.5, 0, 0], atol=1e-12)
    v, _ = _derivs(ref, 1.0)
    assert v[0] == pytest.approx(1.875 * 1.0 / 2.0, rel=1e-6)  # peak speed 15/8 d/T


def test_waypoints_from_speed_and_hold():
    pts = [[0, 0, 0], [3, 0, 0], [3, 4, 0]]
    ref = Waypoints(pts, speed=1.0, hold_s=2.0)
    np.testing.assert_allclose(ref.times, [0.0, 3.0, 9.0])
    assert ref.duration == pytest.approx(11.0)
    np.testing.assert_allclose(ref.sample(ref.times), pts, atol=1e-12)
    np.testing.assert_allclose(ref.position(4.0), [3, 0, 0])  # dwelling at waypoint 1
    np.testing.assert_allclose(ref.position(5.0), [3, 0, 0])


def test_single_waypoint_is_constant():
    ref = Waypoints([[1, 2, 3]], [0.0], hold_s=5.0)
    np.testing.assert_allclose(ref.sample([0.0, 3.0, 10.0]), [[1, 2, 3]] * 3)
    assert ref.duration == 5.0


def test_sample_matches_position():
    refs = [
        Waypoints(POINTS, TIMES),
        SinusoidPhases([0, 0, 1], "y", [(10, 0.1, 0.1), (20, 0.5, 0.05)]),
        Lissajous([0, 0, 1], [1, 0.5, 0.2], [0.01, 0.02, 0.005], [0, 0.3, 0], 780.0),
        Constant([1, 2, 3]),
    ]
    times = np.linspace(-1.0, 40.0, 57)
    for ref in refs:
        vec = ref.sample(times)
        assert vec.shape == (times.size, 3)
        scalar = np.array([ref.position(t) for t in times])
        np.testing.assert_allclose(vec, scalar, atol=1e-14)


def test_sinusoid_amplitude_and_frequency_recovered():
    center = np.array([0.0, 0.2, 1.0])
    ref = SinusoidPhases(center, 1, [(20.0, 0.1, 0.2), (40.0, 0.4, 0.1)])
    assert ref.duration == pytest.approx(60.0)
    for start, dur, amp, freq in ((0.0, 20.0, 0.1, 0.2), (20.0, 40.0, 0.4, 0.1)):
        t = start + np.arange(0.0, dur, 0.01)
        y = ref.sample(t)[:, 1] - center[1]
        assert np.max(np.abs(y)) == pytest.approx(amp, rel=1e-3)
        spec = np.abs(np.fft.rfft(y))
        f = np.fft.rfftfreq(y.size, d=0.01)
        assert f[np.argmax(spec)] == pytest.approx(freq, abs=1.0 / dur)
        np.testing.assert_allclose(ref.sample(t)[:, [0, 2]], np.tile(center[[0, 2]], (t.size, 1)))


def test_sinusoid_continuous_at_phase_boundaries_and_holds_end():
    # 7.5 s at 0.1 Hz ends at a crest: the next phase must start from there
    ref = SinusoidPhases([0, 0, 0], [0, 2, 0], [(7.5, 0.1, 0.1), (10.0, 0.3, 0.25)])
    eps = 1e-9
    for tb in ref.phase_starts[1:]:
        np.testing.assert_allclose(ref.position(tb - eps), ref.position(tb), atol=1e-8)
    end = ref.position(ref.duration)
    np.testing.assert_allclose(ref.position(ref.duration + 5.0), end)
    np.testing.assert_allclose(ref.position(7.5), [0, -0.1, 0], atol=1e-12)
    np.testing.assert_allclose(ref.position(0.0), [0, 0, 0])


def test_lissajous_is_smooth_loop():
    ref = Lissajous([0, 0, 1], [1, 1, 0.2], [0.01, 0.02, 0.01], duration=100.0)
    np.testing.assert_allclose(ref.position(0.0), [0, 0, 1])
    np.testing.assert_allclose(ref.position(25.0), [1, 0, 1.2], atol=1e-12)
    np.testing.assert_allclose(ref.position(100.0), ref.position(0.0), atol=1e-12)


def _write(path, text):
    path.write_text(text)
    return path


def test_csv_interpolation_and_hold(tmp_path):
    f = _write(tmp_path / "r.csv", "t,x,y,z,extra\n0,0,0,1,9\n2,1,2,1,9\n4,1,2,3,9\n")
    ref = Csv(f)
    assert ref.duration == 4.0
    np.testing.assert_allclose(ref.position(1.0), [0.5, 1.0, 1.0])
    np.testing.assert_allclose(ref.position(3.0), [1.0, 2.0, 2.0])
    np.testing.assert_allclose(ref.position(-1.0), [0, 0, 1])
    np.testing.assert_allclose(ref.position(9.0), [1, 2, 3])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("t,x,z\n0,0,0\n", "missing column 'y'"),
        ("t,x,y,z\n0,0,0,0\n1,1,1,1\n1,2,2,2\n", "line 4: t must be strictly increasing"),
        ("t,x,y,z\n0,0,nan,0\n", "line 2, column 'y': must be finite"),
        ("t,x,y,z\n0,0,abc,0\n", "line 2, column 'y': not a number"),
        ("t,x,y,z\n", "no data rows"),
        ("", "empty file"),
    ],
)
def test_csv_errors(tmp_path, text, match):
    f = _write(tmp_path / "bad.csv", text)
    with pytest.raises(ConfigError, match=match):
        Csv(f)


def test_csv_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=r"reference\.file: cannot read"):
        Csv(tmp_path / "nope.csv")


def test_factory_kinds(tmp_path):
    wp = reference_from_table(
        Table(
            {"kind": "waypoints", "points": POINTS.tolist(), "times": TIMES.tolist()}, "reference"
        )
    )
    assert isinstance(wp, Waypoints)
    np.testing.assert_allclose(wp.sample(TIMES), POINTS, atol=1e-12)

    sin = reference_from_table(
        Table(
            {
                "kind": "sinusoids",
                "center": [0, 0, 1],
                "axis": "y",
                "phases": [
                    {"duration": 10, "amplitude": 0.1, "frequency": 0.1},
                    {"duration": 20, "amplitude": 0.5, "frequency": 0.05},
                ],
            }
        )
    )
    assert isinstance(sin, SinusoidPhases)
    assert sin.duration == 30.0
    np.testing.assert_allclose(sin.direction, [0, 1, 0])

    const = reference_from_table(Table({"kind": "constant", "point": [1, 2, 3]}))
    np.testing.assert_allclose(const.position(5.0), [1, 2, 3])

    _write(tmp_path / "traj.csv", "t,x,y,z\n0,0,0,0\n1,1,1,1\n")
    c = reference_from_table(Table({"kind": "csv", "file": "traj.csv"}), base_dir=tmp_path)
    np.testing.assert_allclose(c.position(0.5), [0.5, 0.5, 0.5])

    lis = reference_from_table(
        Table(
            {
                "kind": "lissajous",
                "center": [0, 0, 1],
                "amplitude": [1, 1, 0.1],
                "frequency": [0.01, 0.02, 0.01],
                "duration": 780,
            }
        )
    )
    assert isinstance(lis, Lissajous)
    assert lis.duration == 780.0

    spd = reference_from_table(
        Table({"kind": "waypoints", "points": [[0, 0, 0], [1, 0, 0]], "speed": 0.5, "hold": 1})
    )
    assert spd.duration == pytest.approx(3.0)


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"kind": "spline"}, r"scenario.reference.kind: 'spline' is not one of"),
        ({"point": [0, 0, 0]}, "scenario.reference.kind: missing required key"),
        ({"kind": "constant", "point": [0, 0, 0], "pont": 1}, "scenario.reference.pont: unknown"),
        ({"kind": "constant", "point": [0, 0]}, "scenario.reference.point: expected 3 numbers"),
        (
            {"kind": "waypoints", "points": [[0, 0, 0], [1, 0, 0]], "times": [0, 0]},
            r"scenario.reference.times\[1\]: times must be strictly increasing",
        ),
        (
            {"kind": "waypoints", "points": [[0, 0, 0], [1, 0, 0]], "times": [0]},
            "scenario.reference.times: expected 2 times",
        ),
        (
            {"kind": "waypoints", "points": [[0, 0, 0], [1, 0]], "times": [0, 1]},
            r"scenario.reference.points\[1\]: expected 3 numbers",
        ),
        (
            {"kind": "waypoints", "points": [[0, 0, 0], [1, 0, 0]]},
            "scenario.reference: give exactly one of 'times' and 'speed'",
        ),
        (
            {"kind": "waypoints", "points": [[0, 0, 0], [1, 0, 0]], "speed": -1},
            "scenario.reference.speed: must be > 0",
        ),
        (
            {"kind": "sinusoids", "center": [0, 0, 0], "axis": "w", "phases": []},
            "scenario.reference.axis: 'w' is not one of",
        ),
        (
            {
                "kind": "sinusoids",
                "center": [0, 0, 0],
                "axis": "y",
                "phases": [{"duration": 0, "amplitude": 0.1, "frequency": 0.1}],
            },
            r"scenario.reference.phases\[0\].duration: must be > 0",
        ),
        (
            {
                "kind": "sinusoids",
                "center": [0, 0, 0],
                "axis": "y",
                "phases": [{"duration": 1, "amplitude": 0.1, "freq": 0.1}],
            },
            r"scenario.reference.phases\[0\].frequency: missing required key",
        ),
        (
            {
                "kind": "sinusoids",
                "center": [0, 0, 0],
                "axis": [0, 0, 0],
                "phases": [{"duration": 1, "amplitude": 0.1, "frequency": 0.1}],
            },
            "scenario.reference.axis: direction must be non-zero",
        ),
        ({"kind": "csv", "file": "/nonexistent/x.csv"}, "scenario.reference.file: cannot read"),
        (
            {
                "kind": "lissajous",
                "center": [0, 0, 0],
                "amplitude": [1, 1, 1],
                "frequency": [0.1, -0.1, 0.1],
            },
            r"scenario.reference.frequency: must be in \[0, 100\] Hz",
        ),
    ],
)
def test_factory_errors_name_key_path(data, match):
    with pytest.raises(ConfigError, match=match):
        reference_from_table(Table(data, "scenario.reference"))


def test_what_a_reference_tells_the_experiment_markers_and_phases():
    """``markers()``: a waypoint reference's points, none for the others; ``motion_phases()``:
    a sinusoid reference's phases back to back, each as long as given, along its unit
    direction; none for the others."""
    pts = [[0.0, 0.0, 1.0], [0.5, 0.0, 1.0], [0.5, 0.5, 1.2]]
    wp = Waypoints(pts, [0.0, 2.0, 5.0])
    np.testing.assert_array_equal(wp.markers(), pts)
    assert wp.motion_phases() is None
    sin = SinusoidPhases([0, 0, 1], [0, 2, 0], [(10.0, 0.1, 0.1), (20.0, 0.5, 0.05)])
    assert sin.markers() is None
    (a0, a1, da), (b0, b1, db) = sin.motion_phases()
    assert (a0, a1, b0, b1) == (0.0, 10.0, 10.0, 30.0)
    np.testing.assert_allclose(da, [0.0, 1.0, 0.0])
    np.testing.assert_allclose(db, [0.0, 1.0, 0.0])
    assert Constant([0.1, 0.2, 0.3]).markers() is None
    assert Constant([0.1, 0.2, 0.3]).motion_phases() is None
