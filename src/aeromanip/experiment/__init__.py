"""Closed-loop experiments: scenarios (TOML, extends, variants), the runner, run logs, plots."""
