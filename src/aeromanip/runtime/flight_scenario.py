"""The one scenario a vehicle flies (a real-time flight has no variants side by side)."""

from __future__ import annotations

from collections.abc import Sequence

from aeromanip.errors import ConfigError
from aeromanip.experiment.scenario import Scenario, load_scenarios


def one_scenario(name: str, overrides: Sequence[str], variant: str | None) -> Scenario:
    """The scenario ``name`` (with ``overrides``), or its ``variant``; a scenario with
    several variants and none chosen is a ``ConfigError`` listing them."""
    scenarios = load_scenarios(name, list(overrides), variant)
    if len(scenarios) > 1:
        raise ConfigError(
            f"--variant: {name} has variants {', '.join(scenarios)}: choose one to fly"
        )
    return next(iter(scenarios.values()))
