"""Command line: ``aeromanip run | list | plot | bench``.

Errors a user can cause (unknown names, bad values, malformed files) print one line and
exit with code 2, without a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from aeromanip.errors import AeromanipError, ConfigError


def _cmd_list(args: argparse.Namespace) -> int:
    from aeromanip.experiment.scenario import builtin_scenarios
    from aeromanip.robot.loader import builtin_robots

    print("scenarios:")
    for name, text in builtin_scenarios().items():
        print(f"  {name:<20} {text}")
    print("robots:")
    for name, text in builtin_robots().items():
        print(f"  {name:<20} {text}")
    return 0


SUMMARY_COLUMNS = (
    ("ee_rmse_m", "EE RMSE m", "{:.4f}"),
    ("ee_max_err_m", "EE max m", "{:.4f}"),
    ("cog_xy_mean_m", "CoG xy m", "{:.4f}"),
    ("cond_mean", "cond", "{:.2f}"),
    ("min_clearance_m", "clear m", "{:.3f}"),
    ("max_bound_violation", "bound viol", "{:.1e}"),
    ("solve_ms_median", "solve ms", "{:.1f}"),
    ("solver_failures", "fails", "{:d}"),
)
PHYSICS_COLUMNS = (  # shown when a run has them
    ("roll_pitch_mean_deg", "tilt deg", "{:.3f}"),
    ("arm_torque_mean_nm", "arm N m", "{:.4f}"),
)


def _format_summary(summaries: dict[str, dict]) -> str:
    columns = SUMMARY_COLUMNS + tuple(
        c for c in PHYSICS_COLUMNS if any(c[0] in s for s in summaries.values())
    )
    head = f"{'run':<22}" + "".join(f"{h:>12}" for _, h, _ in columns)
    lines = [head]
    for variant, s in summaries.items():
        cells = []
        for key, _, fmt in columns:
            v = s.get(key)
            cells.append(f"{'-' if v is None else fmt.format(v):>12}")
        lines.append(f"{(variant or s['scenario']):<22}" + "".join(cells))
    return "\n".join(lines)


def _cmd_run(args: argparse.Namespace) -> int:
    from aeromanip.experiment.runner import run_scenarios
    from aeromanip.experiment.scenario import load_scenarios

    scenarios = load_scenarios(args.scenario, args.set or [], args.variant)
    first = next(iter(scenarios.values()))
    out = Path(args.out or Path("runs") / first.name.split("/")[0])
    steps = sum(sc.steps for sc in scenarios.values())
    print(f"running {args.scenario}: {len(scenarios)} run(s), {steps} control steps -> {out}")
    t0 = time.perf_counter()
    summaries = run_scenarios(scenarios, out, progress=not args.quiet)
    print(_format_summary(summaries))
    print(f"done in {time.perf_counter() - t0:.1f} s; outputs in {out.resolve()}")
    return 0


def _run_order(root: Path) -> list[str]:
    """The variant names in the order ``DIR/summary.json`` lists them (empty if none)."""
    try:
        data = json.loads((root / "summary.json").read_text())
    except (OSError, ValueError):
        return []
    return [k for k, v in data.items() if isinstance(v, dict)] if isinstance(data, dict) else []


def _cmd_plot(args: argparse.Namespace) -> int:
    from aeromanip.experiment.plots import plot_comparison, plot_run
    from aeromanip.experiment.runlog import LOG_FILE, RunLog

    root = Path(args.dir)
    if (root / LOG_FILE).is_file():
        paths = plot_run(RunLog.load(root), root / "figures")
    else:
        runs = sorted(p.parent for p in root.glob(f"*/{LOG_FILE}"))
        order = _run_order(root)  # the variants' order in the run, where it was saved
        runs.sort(key=lambda d: order.index(d.name) if d.name in order else len(order))
        if not runs:
            raise ConfigError(f"{root}: no {LOG_FILE} here nor in its sub-directories")
        logs = {}
        paths = []
        for d in runs:
            logs[d.name] = RunLog.load(d)
            paths += plot_run(logs[d.name], d / "figures")
        if len(logs) > 1:
            paths += plot_comparison(logs, root / "figures")
    for p in paths:
        print(p)
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from aeromanip.bench.controller import VARIANTS, bench_controller, format_controller
    from aeromanip.bench.kinematics import bench_kinematics, format_kinematics

    names = args.variant or list(VARIANTS)
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise ConfigError(f"--variant {unknown[0]}: unknown (have: {', '.join(VARIANTS)})")
    if not args.duration > 0:
        raise ConfigError(f"--duration: must be > 0 s, got {args.duration}")
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
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
        print(f"wrote {args.json}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``aeromanip`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="aeromanip", description="NMPC for aerial manipulators (Lunni et al., ICUAS 2017)"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="run a scenario closed loop and write its outputs")
    p.add_argument("scenario", nargs="?", default="flight", help="built-in name or FILE.toml")
    p.add_argument("--out", metavar="DIR", help="output directory (default runs/<scenario>)")
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a scenario value, e.g. --set controller.backend=fatrop",
    )
    p.add_argument("--variant", metavar="NAME", help="run only this variant")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_run)
    p = sub.add_parser("plot", help="re-draw the figures of a saved run directory")
    p.add_argument("dir", help="a run directory (or a directory of variant runs)")
    p.set_defaults(func=_cmd_plot)
    p = sub.add_parser("list", help="built-in robots and scenarios, one line each")
    p.set_defaults(func=_cmd_list)
    p = sub.add_parser("bench", help="measure evaluation and controller step times")
    p.add_argument("what", nargs="?", default="all", choices=["all", "kinematics", "controller"])
    p.add_argument(
        "--variant",
        action="append",
        metavar="NAME",
        help="controller variant to run (repeatable; default: all)",
    )
    p.add_argument(
        "--duration", type=float, default=60.0, help="closed loop per variant [s] (default 60)"
    )
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    p.set_defaults(func=_cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``aeromanip`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except AeromanipError as e:
        print(f"aeromanip: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. piped into `head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("aeromanip: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
