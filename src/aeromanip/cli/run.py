"""``aeromanip run SCENARIO``: fly a scenario closed loop and write its run directory.

Everything is checked before anything is built or flown (the scenario, the backend's
options, that ``--out`` can be written). Exit codes: 0 the run flew; 2 bad input;
3 the run did not really fly (a step stopped the robot, or more steps failed than the
scenario's ``max_failure_ratio``: the outputs are kept); 130 / 143 stopped by SIGINT
(Ctrl-C) / SIGTERM, with the rows flown so far kept and ``"interrupted": true``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from aeromanip.errors import ExitCode

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


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
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
    p.add_argument("--video", action="store_true", help="render DIR/replay.mp4 after the run")
    p.add_argument(
        "--no-mcap", action="store_true", help="do not write run.mcap (Foxglove) in each run"
    )
    p.add_argument(
        "--check", action="store_true", help="check the scenario and --out, build and fly nothing"
    )
    p.set_defaults(func=run)


def format_summary(summaries: dict[str, dict]) -> str:
    """The table of the runs' main metrics, one row per variant."""
    columns = SUMMARY_COLUMNS + tuple(
        c for c in PHYSICS_COLUMNS if any(c[0] in s for s in summaries.values())
    )
    head = f"{'run':<22}" + "".join(f"{h:>12}" for _, h, _ in columns)
    lines = [head]
    for variant, s in summaries.items():
        cells = []
        for key, _, fmt in columns:
            v = s.get(key)
            ok = isinstance(v, int | float) and v == v  # not None, not NaN
            cells.append(f"{fmt.format(v) if ok else '-':>12}")
        lines.append(f"{(variant or s.get('scenario', '')):<22}" + "".join(cells))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Check, fly, report; the exit code says whether the run flew (module docstring)."""
    from aeromanip.experiment.rundir import check_writable
    from aeromanip.experiment.runner import run_scenarios
    from aeromanip.experiment.scenario import load_scenarios
    from aeromanip.interrupts import stop_on_signals

    scenarios = load_scenarios(args.scenario, args.set or [], args.variant)
    first = next(iter(scenarios.values()))
    out = Path(args.out or Path("runs") / first.name.split("/")[0])
    check_writable(out)
    if args.video:  # fail now, not after the run, if it cannot be rendered
        from aeromanip.viz.export import check_video

        check_video()
    steps = sum(sc.steps for sc in scenarios.values())
    if args.check:
        print(f"{args.scenario}: {len(scenarios)} run(s), {steps} control steps -> {out}: ok")
        return 0
    print(f"running {args.scenario}: {len(scenarios)} run(s), {steps} control steps -> {out}")
    t0 = time.perf_counter()
    with stop_on_signals():
        result = run_scenarios(scenarios, out, progress=not args.quiet)
    print(format_summary(result.summaries))
    where = result.out_dir.resolve() if result.out_dir else out
    from aeromanip.viz.export import export_run

    if result.interrupted is not None:  # stop at once: ``aeromanip replay DIR --mcap`` later
        flown = sum(int(s.get("steps", 0)) for s in result.summaries.values())
        print(
            f"aeromanip: interrupted ({result.interrupted}): {flown} of {steps} steps flown, "
            f"kept in {where}",
            file=sys.stderr,
        )
        return result.interrupted.exit_code
    export_run(where, mcap=not args.no_mcap, video=args.video)
    print(f"done in {time.perf_counter() - t0:.1f} s; outputs in {where}")
    problems = [
        f"{v or s.get('scenario')}: {s['flight_problem']}"
        for v, s in result.summaries.items()
        if not s.get("flight_ok", True)
    ]
    if problems:
        print(f"aeromanip: the run did not fly: {'; '.join(problems)}", file=sys.stderr)
        return ExitCode.DID_NOT_FLY
    return 0
