"""A campaign's plan: every run listed and built (nothing flown or compiled) before Ray
starts, and grouped by the problem its controller solves.

A run whose scenario does not build (a value out of range in one corner of a grid) is
kept as invalid, with its error, and recorded as failed; if no run builds, the command
itself is wrong (an unknown key, a bad ``--set``) and ``plan_campaign`` raises.

Runs that differ only in keys that do not enter the NMPC's Functions (``NOT_PROBLEM``:
the simulator, its seed and noise, the duration, the initial state, the reference, which
the NLP takes as parameters) share a problem, compiled once (``campaign.precompile``).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aeromanip.errors import AeromanipError, ConfigError
from aeromanip.experiment.sources import scenario_source
from aeromanip.sweep.axes import VARIANT_KEY, Run, SweepSpec, with_variants
from aeromanip.sweep.tasks import build_run, one_line

NOT_PROBLEM = (
    "name",
    "description",
    "duration",
    "sim",
    "physics",
    "initial_state",
    "max_failure_ratio",
    "reference",
)


@dataclass
class Plan:
    """The runs of a campaign, checked: those whose scenario does not build are
    ``invalid`` (id -> error); the others are grouped by problem."""

    scenario: str
    data: dict[str, Any]
    base_dir: Path
    spec: SweepSpec
    runs: list[Run]
    invalid: dict[str, str] = field(default_factory=dict)
    problem_of: dict[str, str] = field(default_factory=dict)  # run id -> problem key
    example: dict[str, Run] = field(default_factory=dict)  # problem key -> its first run
    sims: set[str] = field(default_factory=set)


def problem_key(resolved: dict[str, Any]) -> str:
    """A hash of what shapes the NMPC's Functions in a resolved scenario."""
    shaped = {k: v for k, v in resolved.items() if k not in NOT_PROBLEM}
    if isinstance(shaped.get("controller"), dict):
        shaped["controller"] = {k: v for k, v in shaped["controller"].items() if k != "time_budget"}
    blob = json.dumps(shaped, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _variant_names(data: dict[str, Any]) -> list[str]:
    variants = data.get("variants")
    return list(variants) if isinstance(variants, dict) else []


def _check_variants(scenario: str, data: dict[str, Any], spec: SweepSpec) -> None:
    """Swept variants exist, and no variant flown sets a swept key (it would win)."""
    names = _variant_names(data)
    axis = next((a for a in spec.grid if a.key == VARIANT_KEY), None)
    for v in axis.values if axis else ():
        if v not in names:
            have = ", ".join(names) or "none"
            raise ConfigError(f"--grid variant={v}: {scenario} has no such variant (have: {have})")
    flown = list(axis.values) if axis else [spec.variant] if spec.variant else []
    for v in flown:
        over = data["variants"].get(v) if v in names else None
        keys = _dotted_keys(over) if isinstance(over, dict) else set()
        for key in spec.keys:
            if key in keys:
                raise ConfigError(
                    f"{key}: variant {v} of {scenario} sets it, overriding the swept values; "
                    f"sweep a variant that does not (--variant NAME) or drop the key"
                )


def _dotted_keys(table: dict[str, Any], prefix: str = "") -> set[str]:
    out = set()
    for k, v in table.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        out |= _dotted_keys(v, key) if isinstance(v, dict) else {key}
    return out


def plan_campaign(scenario: str, spec: SweepSpec) -> Plan:
    """Read the scenario, list the runs, build each run's scenario (nothing flown or
    compiled). Raises ``ConfigError`` if no run builds (a bad key: the whole command is
    wrong); runs that do not build while others do are kept as ``invalid``."""
    data, base_dir = scenario_source(scenario)
    spec = with_variants(spec, _variant_names(data))
    _check_variants(scenario, data, spec)
    plan = Plan(scenario, data, base_dir, spec, spec.runs())
    for run in plan.runs:
        try:
            sc = build_run(data, base_dir, run.overrides, run.variant)
        except AeromanipError as e:
            plan.invalid[run.run_id] = _as_given(spec, one_line(e).removeprefix("ConfigError: "))
            continue
        key = problem_key(sc.resolved)
        plan.problem_of[run.run_id] = key
        plan.example.setdefault(key, run)  # not the Scenario: memory stays flat in big sweeps
        plan.sims.add(sc.sim)
    if len(plan.invalid) == len(plan.runs):
        raise ConfigError(next(iter(plan.invalid.values())))
    if spec.seeds > 1 and spec.seed_key.startswith("physics.") and plan.sims == {"kinematic"}:
        raise ConfigError(
            f"--seeds {spec.seeds}: {spec.seed_key} changes nothing with sim = kinematic "
            f"(no noise); fly physics: --set sim=physics"
        )
    return plan


def _as_given(spec: SweepSpec, message: str) -> str:
    """An error about a swept override names the option it came from, not ``--set``."""
    flags = {a.key: a.flag for a in spec.axes()} | {a.key: "--random" for a in spec.random}
    key = message.removeprefix("--set ").split("=", 1)[0]
    if message.startswith("--set ") and key in flags:
        return flags[key] + message.removeprefix("--set")
    return message


def scenario_hash(data: dict[str, Any]) -> str:
    """A hash of a scenario's table (a campaign's runs are of one scenario)."""
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def check_metric_names(plan: Plan, names: tuple[str, ...], option: str) -> None:
    """Before the fan-out: every name is a column ``results.csv`` will have (a run's
    summary computed on a one-row log of the campaign's columns, nothing flown), or an
    entry of one of its tables (``steps_by_status.fallback``)."""
    from aeromanip.experiment.closed_loop import log_columns, make_simulator, run_meta
    from aeromanip.experiment.runlog import TEXT_COLUMNS, RunLog
    from aeromanip.experiment.runner import summarize
    from aeromanip.sweep.results import FIXED_COLUMNS, TASK_COLUMNS, flatten

    known = {*FIXED_COLUMNS, *TASK_COLUMNS, *plan.spec.keys}
    sims: set[str] = set()
    for run in plan.example.values():
        sc = build_run(plan.data, plan.base_dir, run.overrides, run.variant)
        if sc.sim in sims:
            continue
        sims.add(sc.sim)
        columns = log_columns(sc, make_simulator(sc))
        row = {c: ["ok"] if c in TEXT_COLUMNS else [0.0] for c in columns}
        known |= set(flatten(summarize(sc, RunLog(row, run_meta(sc)))))
    tables = {k.split(".")[0] for k in known if "." in k}
    for name in names:
        table, dot, _ = name.partition(".")
        if name not in known and not (dot and table in tables):
            shown = ", ".join(sorted(k for k in known if k.endswith(("_m", "_ms", "_mean")))[:8])
            raise ConfigError(f"{option} {name}: not a column of results.csv (e.g. {shown})")
