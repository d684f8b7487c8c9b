"""``aeromanip sitl SCENARIO --link URL --out DIR``: a software-in-the-loop PX4 stand-in.

Flies the scenario's robot in the MuJoCo physics in real time and speaks PX4's offboard
MAVLink subset on ``--link`` (``aeromanip.mavlink.sitl``); writes the vehicle's truth log
to ``DIR``. Runs until ``--max-time`` or Ctrl-C / SIGTERM (exit 0: a SITL is stopped so).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

MAX_STATE_HZ = 500.0  # [Hz]
MIN_STATE_HZ = 50.0  # [Hz] PX4 streams its state at least this fast to an offboard link


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("sitl", help="serve a simulated PX4-like vehicle over MAVLink")
    p.add_argument("scenario", help="built-in name or FILE.toml (its robot, start, physics)")
    p.add_argument("--link", required=True, help="e.g. udpout:127.0.0.1:14540 (runtime: udpin)")
    p.add_argument("--out", metavar="DIR", help="truth-log directory (default runs/sitl)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a value")
    p.add_argument("--variant", metavar="NAME", help="the variant whose robot to fly")
    p.add_argument("--max-time", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--state-hz", type=float, default=None, metavar="HZ", help="state rate")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Check everything, then serve the vehicle until stopped."""
    from aeromanip.errors import ConfigError
    from aeromanip.experiment.rundir import check_writable
    from aeromanip.mavlink.protocol import parse_link
    from aeromanip.mavlink.sitl import STATE_HZ
    from aeromanip.mavlink.sitl_run import run_sitl
    from aeromanip.runtime.flight_scenario import one_scenario

    parse_link(args.link)
    state_hz = STATE_HZ if args.state_hz is None else args.state_hz
    if not MIN_STATE_HZ <= state_hz <= MAX_STATE_HZ:
        raise ConfigError(
            f"--state-hz: {state_hz:g} is not in [{MIN_STATE_HZ:g}, {MAX_STATE_HZ:g}]"
        )
    if args.max_time is not None and not 0 < args.max_time < math.inf:
        raise ConfigError(
            f"--max-time: {args.max_time:g} is not a finite number of seconds > 0 "
            "(leave it out to serve until Ctrl-C)"
        )
    sc = one_scenario(args.scenario, args.set or [], args.variant)
    out = Path(args.out or "runs/sitl")
    check_writable(out)
    print(f"sitl: {sc.name} ({sc.robot.name}) on {args.link} -> {out}", flush=True)
    summary, _ = run_sitl(sc, args.link, out, args.max_time, state_hz)
    print(f"sitl: stopped after {summary['sitl_time_s']:.1f} s; truth log in {out}", flush=True)
    return 0
