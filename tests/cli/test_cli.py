"""The command line: clear one-line errors with exit code 2, list, a short run."""

import subprocess
import sys

import pytest

from aeromanip.cli import main


def run_cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "aeromanip.cli", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "nosuch"], "unknown scenario 'nosuch'"),
        (["run", "flight", "--set", "controller.horizn=5"], "controller.horizn: unknown key"),
        (["run", "flight", "--set", "nosuch.key=1"], "unknown key 'nosuch'"),
        (
            ["run", "flight", "--set", "controller.horizon=abc"],
            "controller.horizon: expected an integer, got 'abc'",
        ),
        (
            ["run", "flight", "--set", "controller.dt=-0.5"],
            "controller.dt: must be in [0.001, 60], got -0.5",
        ),
        (
            ["run", "flight", "--set", "controller.strategy=lexicographic"],
            "controller.strategy: 'lexicographic' is not one of",
        ),
        (["run", "flight", "--set", "noequals"], "expected KEY=VALUE"),
        (["run", "planar", "--variant", "cond-max"], "unknown variant"),
        (["run", "flight", "--set", "initial_state=[0, 0, 1]"], "initial_state: expected 7"),
        (["plot", "/nonexistent/dir"], "not a run directory"),
    ],
)
def test_bad_input_is_one_clear_line_and_exit_2(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err
    assert len(err.splitlines()) == 1 and "Traceback" not in err


def test_a_typo_in_a_key_is_named_with_its_likely_meaning(tmp_path, capsys):
    from importlib import resources

    flight = (resources.files("aeromanip") / "scenarios" / "flight.toml").read_text()
    missing = tmp_path / "missing.toml"  # a required key spelt wrong
    missing.write_text(flight.replace("duration = 780.0", "duraton = 780.0", 1))
    assert main(["run", str(missing)]) == 2
    assert "duration: missing required key (is 'duraton' a typo?)" in capsys.readouterr().err
    extra = tmp_path / "extra.toml"  # an optional key spelt wrong
    extra.write_text('extends = "flight"\n[controller]\nhorizn = 5\n')
    assert main(["run", str(extra)]) == 2
    assert "controller.horizn: unknown key (did you mean 'horizon'?)" in capsys.readouterr().err
    # a missing key's hint never names a key that is there and right
    flight_no_duration = "\n".join(
        ln for ln in flight.splitlines() if not ln.startswith("duration =")
    )
    missing.write_text(flight_no_duration)
    assert main(["run", str(missing)]) == 2
    err = capsys.readouterr().err
    assert "duration: missing required key" in err and "typo" not in err


def test_malformed_toml_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n[controller\n")
    assert main(["run", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "malformed TOML" in err and str(bad) in err


def test_list_names_scenarios_and_robots(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in (
        "planar",
        "waypoints",
        "waypoints-unbounded",
        "flight",
        "flight-cog",
        "x8-3dof",
        "planar-2dof",
    ):
        assert name in out


def test_run_from_the_console_prints_summary_and_outputs(tmp_path):
    out = tmp_path / "run"
    proc = run_cli("run", "flight", "--set", "duration=5", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "EE RMSE" in proc.stdout and str(out) in proc.stdout
    assert "tilt deg" in proc.stdout  # flight flies in physics: tilt and arm torque shown
    assert (out / "summary.json").is_file() and (out / "figures" / "ee_tracking.png").is_file()
    proc = run_cli("run", "nosuch")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr


def test_replot_keeps_the_variants_in_run_order(tmp_path):
    from aeromanip.cli.plot import run_order as _run_order

    (tmp_path / "summary.json").write_text(
        '{"cond-off": {"x": 1}, "cond-default": {"x": 2}, "cond-high": {"x": 3}}'
    )
    assert _run_order(tmp_path) == ["cond-off", "cond-default", "cond-high"]
    (tmp_path / "summary.json").write_text('{"steps": 3}')  # a single run's summary
    assert _run_order(tmp_path) == []
    assert _run_order(tmp_path / "missing") == []
