"""``aeromanip list``: built-in scenarios and robots, one line each."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("list", help="built-in robots and scenarios, one line each")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the built-ins."""
    from aeromanip.experiment.scenario import builtin_scenarios
    from aeromanip.robot.loader import builtin_robots

    print("scenarios:")
    for name, text in builtin_scenarios().items():
        print(f"  {name:<20} {text}")
    print("robots:")
    for name, text in builtin_robots().items():
        print(f"  {name:<20} {text}")
    return 0
