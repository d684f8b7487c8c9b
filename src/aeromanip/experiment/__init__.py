"""Closed-loop experiments: scenarios (TOML, extends, variants), the runner, run logs, plots.

Exports:

* ``load_scenarios`` (a built-in name or a TOML file, ``--set`` overrides, variants ->
  ``Scenario`` each), ``build_scenario`` (from a parsed table), ``builtin_scenarios``;
* ``run_scenarios`` (into a run directory: ``config.toml``, ``log.csv``,
  ``summary.json``, figures), ``run_one``, ``RunResult``;
* ``simulate`` (a scenario flown in memory -> ``RunLog``), ``fly`` (rows to a sink),
  ``make_controller``, ``make_simulator``;
* ``RunLog`` (a run's log and meta, ``RunLog.load(dir)``), ``read_summary``,
  ``write_summary``;
* ``plot_run``, ``plot_comparison`` (the paper's figures of saved runs);
* ``identify`` (the vehicle's rate response time constants from step responses).
"""

from __future__ import annotations

from aeromanip.registry import lazy_exports

# each import on first use: a run log reader need not load the plots or the physics
_LAZY = {
    "Scenario": "aeromanip.experiment.scenario",
    "build_scenario": "aeromanip.experiment.scenario",
    "builtin_scenarios": "aeromanip.experiment.scenario",
    "load_scenarios": "aeromanip.experiment.scenario",
    "RunResult": "aeromanip.experiment.runner",
    "run_one": "aeromanip.experiment.runner",
    "run_scenarios": "aeromanip.experiment.runner",
    "fly": "aeromanip.experiment.closed_loop",
    "make_controller": "aeromanip.experiment.closed_loop",
    "make_simulator": "aeromanip.experiment.closed_loop",
    "simulate": "aeromanip.experiment.closed_loop",
    "RunLog": "aeromanip.experiment.runlog",
    "read_summary": "aeromanip.experiment.runlog",
    "write_summary": "aeromanip.experiment.runlog",
    "plot_comparison": "aeromanip.experiment.plots",
    "plot_run": "aeromanip.experiment.plots",
    "identify": "aeromanip.experiment.identification",
}

__all__ = sorted(_LAZY)

__getattr__, __dir__ = lazy_exports(__name__, _LAZY, globals())
