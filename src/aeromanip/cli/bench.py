"""``aeromanip bench``: timing of kinematics evaluations and controller steps."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from aeromanip.errors import ConfigError

DURATION_S = 60.0  # [s] closed loop per controller variant


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("bench", help="measure evaluation and controller step times")
    p.add_argument(
        "what",
        nargs="?",
        default="all",
        choices=[
            "all",
            "kinematics",
            "controller",
            "profile",
            "stress",
            "peer",
            "render",
            "horizon",
        ],
        help="what to measure; 'profile' (where a step's time goes: QP, compiled model, "
        "Python), 'stress' (binding bounds, a far start, the clearance binding), "
        "'peer' (do-mpc on the flight problem, needs the 'bench' extra) and "
        "'horizon' (cold builds at N = 10..100, tens of minutes) are not part of 'all'",
    )
    p.add_argument(
        "--variant",
        action="append",
        metavar="NAME",
        help="controller variant to run (repeatable; default: all)",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=DURATION_S,
        help=f"closed loop per variant [s] (default {DURATION_S:g})",
    )
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    p.set_defaults(func=run)


def _check_json_path(path: Path) -> None:
    """Fail before measuring if the results could not be written."""
    if path.is_dir():
        raise ConfigError(f"--json: {path} is a directory")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ConfigError(f"--json: {path}: {parent} is not a directory")
    try:
        with path.open("a"):
            pass
    except OSError as e:
        raise ConfigError(f"--json: cannot write {path}: {e.strerror}") from None


def _bench_render() -> dict:
    """Replay rendering speed (needs the ``viz`` extra and an offscreen GL)."""
    from aeromanip.bench.render_speed import bench_render, format_render

    r = bench_render()
    print(format_render(r))
    print()
    return r


def _bench_peer(duration: float) -> dict:
    """do-mpc beside aeromanip on the flight problem (needs the ``bench`` extra)."""
    from aeromanip.bench.peer_dompc import bench_peer, format_peer, import_dompc

    import_dompc()  # fail at once, with the install hint, if it is missing
    print(f"do-mpc peer, flight problem, {duration:g} s closed loop per row:")
    r = bench_peer(duration=duration)
    print(format_peer(r))
    print()
    return r


def run(args: argparse.Namespace) -> int:
    """Measure and print (and write ``--json``)."""
    from aeromanip.bench.controller_speed import VARIANTS, bench_controller, format_controller
    from aeromanip.bench.kinematics_speed import bench_kinematics, format_kinematics

    names = args.variant or list(VARIANTS)
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise ConfigError(f"--variant {unknown[0]}: unknown (have: {', '.join(VARIANTS)})")
    if not 0 < args.duration <= 3600:
        raise ConfigError(f"--duration: must be in (0, 3600] s, got {args.duration}")
    if args.json:
        _check_json_path(Path(args.json))
    results = {}
    if args.what in ("kinematics", "all"):
        for robot in ("planar-2dof", "x8-3dof"):
            r = bench_kinematics(robot)
            results[f"kinematics/{robot}"] = r
            print(format_kinematics(r))
            print()
    if args.what in ("controller", "all"):
        print(f"controller step, flight problem, {args.duration:g} s closed loop per variant:")
        r = bench_controller(names, duration=args.duration)
        results["controller"] = r
        print(format_controller(r))
        print()
    if args.what == "profile":
        from aeromanip.bench.profile import PROFILED, bench_profile, format_profile

        print(f"where the step's time goes, flight problem, {args.duration:g} s closed loop:")
        r = bench_profile(args.variant or list(PROFILED), duration=args.duration)
        results["profile"] = r
        print(format_profile(r))
        print()
    if args.what == "stress":
        from aeromanip.bench.stress import bench_stress, format_stress

        print(f"controller under stress, {args.duration:g} s closed loop per case and row:")
        r = bench_stress(duration=args.duration)
        results["stress"] = r
        print(format_stress(r))
        print()
    if args.what == "peer":
        results["peer"] = _bench_peer(args.duration)
    if args.what in ("render", "all"):
        results["render"] = _bench_render()
    if args.what == "horizon":
        from aeromanip.bench.horizon import bench_horizon, format_horizon

        print("horizon scaling, flight problem, 5 s horizon, cold builds in fresh processes:")
        rows = bench_horizon()
        results["horizon"] = rows
        print(format_horizon(rows))
        print()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
        print(f"wrote {args.json}")
    return 0
