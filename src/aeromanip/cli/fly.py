"""``aeromanip fly SCENARIO --link URL --out DIR``: fly a vehicle in real time.

The scenario's controller runs on the wall clock at its control rate and drives a PX4
autopilot in offboard mode over MAVLink (``aeromanip.runtime``, ``aeromanip.mavlink``);
the arm's joint targets go through the autopilot (``MAV_CMD_DO_SET_ACTUATOR``). The run
directory is the output contract's, written as it flies. Exit codes: 0 the mission flew;
2 bad input; 3 it flew but did not really fly (as ``aeromanip run``); 4 the link was lost,
the autopilot refused (arming, offboard), its telemetry could not be flown on (not finite,
out of range, stale: the vehicle commanded to hold), or it left offboard or disarmed (a
pilot, a kill switch: nothing commanded); 130 / 143
stopped by SIGINT / SIGTERM, the vehicle left holding; 5 a row could not be written (disk
full, permission, read-only, I/O error): the flight stopped, the vehicle left holding.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from aeromanip.errors import ExitCode

if TYPE_CHECKING:
    from aeromanip.experiment.scenario import Scenario


MIN_STREAM_HZ = 20.0  # [Hz] between solves (PX4 leaves offboard below 2 Hz)
MAX_STREAM_HZ = 250.0  # [Hz]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("fly", help="fly a vehicle in real time over MAVLink (PX4 offboard)")
    p.add_argument("scenario", help="built-in name or FILE.toml")
    p.add_argument(
        "--link", required=True, help="e.g. udpin:0.0.0.0:14540, serial:/dev/ttyUSB0:921600"
    )
    p.add_argument("--out", metavar="DIR", help="output directory (default runs/fly-<scenario>)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a value")
    p.add_argument("--variant", metavar="NAME", help="the variant to fly")
    p.add_argument("--stream-hz", type=float, default=None, metavar="HZ", help="setpoint rate")
    p.add_argument(
        "--no-joint-feedback",
        action="store_true",
        help="the arm's servos report nothing: take the targets sent as the joints",
    )
    p.add_argument("--check", action="store_true", help="check the inputs, connect to nothing")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Check, connect, fly; the exit code says how it ended (module docstring)."""
    from aeromanip.errors import ConfigError
    from aeromanip.experiment.rundir import check_writable
    from aeromanip.mavlink.arm import check_arm
    from aeromanip.mavlink.protocol import parse_link
    from aeromanip.runtime.flight_scenario import one_scenario
    from aeromanip.runtime.streamer import STREAM_HZ

    parse_link(args.link)
    stream_hz = STREAM_HZ if args.stream_hz is None else args.stream_hz
    if not MIN_STREAM_HZ <= stream_hz <= MAX_STREAM_HZ:
        raise ConfigError(
            f"--stream-hz: {stream_hz:g} is not in [{MIN_STREAM_HZ:g}, {MAX_STREAM_HZ:g}]"
        )
    sc = one_scenario(args.scenario, args.set or [], args.variant)
    check_arm(sc.robot)
    out = Path(args.out or Path("runs") / f"fly-{sc.name.replace('/', '-')}")
    check_writable(out)
    if args.check:
        print(f"{sc.name}: {sc.steps} steps at {1 / sc.problem.dt:g} Hz on {args.link}: ok")
        return 0
    return _fly(sc, args.link, out, stream_hz, not args.no_joint_feedback)


def _fly(sc: Scenario, link: str, out: Path, stream_hz: float, feedback: bool) -> int:
    from aeromanip.mavlink.arm import MavlinkActuatorArm
    from aeromanip.mavlink.bridge import MavlinkTransport
    from aeromanip.runtime.loop import RealtimeFlight
    from aeromanip.runtime.session import fly_session

    transport = MavlinkTransport(link)
    try:
        arm = MavlinkActuatorArm(transport, sc.robot, feedback=feedback)
        flight = RealtimeFlight(sc, transport, arm, stream_hz=stream_hz)
        print(f"fly: {sc.name} on {link}: waiting for the autopilot", flush=True)
        result = fly_session(flight, out, link)
    finally:
        transport.close()
    s = result.summary
    print(
        f"fly: {s.get('steps', 0)} steps, EE RMSE {s.get('ee_rmse_m', float('nan')):.4f} m "
        f"(as measured), {s['deadline_misses']} deadline misses, setpoints "
        f"{s['setpoint_rate_hz']:.1f} Hz; run in {result.out_dir}",
        flush=True,
    )
    if result.io_error is not None:
        why = s.get("stopped_by", str(result.io_error))
        print(
            f"aeromanip: error: the flight stopped (vehicle holding): {why}; "
            f"{s.get('steps', 0)} steps kept in {result.out_dir}",
            file=sys.stderr,
        )
        return ExitCode.IO
    if result.error is not None:
        print(f"aeromanip: {result.error}; run kept in {result.out_dir}", file=sys.stderr)
        return ExitCode.LINK
    if result.fault is not None:  # it did not really fly
        held = " (vehicle holding)" if s.get("steps") else ""  # flying: held, then raised
        print(
            f"aeromanip: error: the flight stopped{held}: {result.fault}; "
            f"{s.get('steps', 0)} steps kept in {result.out_dir}",
            file=sys.stderr,
        )
        return ExitCode.DID_NOT_FLY
    if result.interrupted is not None:
        where = result.out_dir
        print(f"aeromanip: interrupted: vehicle holding; run kept in {where}", file=sys.stderr)
        return result.interrupted.exit_code
    if not s.get("flight_ok", True):
        print(f"aeromanip: the run did not fly: {s['flight_problem']}", file=sys.stderr)
        return ExitCode.DID_NOT_FLY
    return 0
