"""``aeromanip identify [SCENARIO]``: the rate response time constants of its simulator.

Prints a table (time constant, fit quality, position error of the fitted model and of
the paper's ``tau = 0``) and writes ``DIR/response.toml`` to paste into the scenario as
``[controller.response]``, with the records and a figure (``experiment.identification``).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    from aeromanip.experiment.identification import STEP_DURATION, STEP_SHARE

    p = sub.add_parser("identify", help="fit the simulator's rate responses (step responses)")
    p.add_argument("scenario", nargs="?", default="flight", help="built-in name or FILE.toml")
    p.add_argument(
        "--out", metavar="DIR", help="output directory (default runs/<scenario>-identify)"
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scenario value")
    p.add_argument(
        "--step",
        type=float,
        default=STEP_SHARE,
        metavar="SHARE",
        help=f"step size, share of each DoF's velocity limit (default {STEP_SHARE})",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=STEP_DURATION,
        metavar="S",
        help=f"record length after the step [s] (default {STEP_DURATION})",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Identify, print, write."""
    from aeromanip.config import check_range
    from aeromanip.experiment.identification import format_fits, identify, write_identification
    from aeromanip.experiment.rundir import check_writable
    from aeromanip.experiment.scenario import load_scenarios

    check_range(args.step, "--step", 0.0, 1.0, positive=True)
    check_range(args.duration, "--duration", 0.1, 60.0)
    sc = next(iter(load_scenarios(args.scenario, args.set or []).values()))
    out = Path(args.out or Path("runs") / f"{sc.name.split('/')[0]}-identify")
    check_writable(out)
    results = identify(sc, args.step, args.duration)
    print(f"{sc.name}: {sc.sim} simulator, steps of {args.step:g} x the velocity limits")
    print(format_fits([f for _, f in results]))
    for path in write_identification(results, out):
        print(f"wrote {path}")
    return 0
