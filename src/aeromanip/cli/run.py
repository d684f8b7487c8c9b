"""``aeromanip run SCENARIO``: fly a scenario closed loop and write its run directory.

Everything is checked before anything is built or flown (the scenario, the backend's
options, that ``--out`` can be written). Exit codes: 0 the run flew; 2 bad input;
3 the run did not really fly (a step stopped the robot, or more steps failed than the
scenario's ``max_failure_ratio``: the outputs are kept); 5 a write was refused (disk
full, permission, read-only, I/O error): the rows written so far kept, the summary saying
why (``"stopped_by"``); 130 / 143 stopped by SIGINT (Ctrl-C) / SIGTERM, with the rows flown
so far kept and ``"interrupted": true``. A fault the run cannot fly on (a state that is
not finite) stops it with exit 3 (the error's own code if no step was flown), the rows
kept and the summary saying why.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from aeromanip.errors import ExitCode, describe_os_error

if TYPE_CHECKING:
    from aeromanip.experiment.runner import RunResult
    from aeromanip.experiment.scenario import Scenario
    from aeromanip.interrupts import RunInterrupted

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
    ("force_rmse_n", "F RMSE N", "{:.3f}"),
    ("force_contact_share", "contact", "{:.3f}"),
    ("f_n_first_touch_peak_n", "touch N", "{:.2f}"),
    ("ee_tangential_rmse_m", "slide m", "{:.4f}"),
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
    from aeromanip.experiment.scenario import load_scenarios

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
    return _fly_and_report(scenarios, out, args)


def _fly_and_report(scenarios: dict[str, Scenario], out: Path, args: argparse.Namespace) -> int:
    """Fly, print the table, write the exports; one line on stderr for any stop."""
    from aeromanip.experiment.runner import run_scenarios
    from aeromanip.interrupts import RunInterrupted, stop_on_signals

    t0 = time.perf_counter()
    with stop_on_signals():
        result = run_scenarios(scenarios, out, progress=not args.quiet)
    where = result.out_dir.resolve() if result.out_dir else out
    if result.interrupted is None and result.io_error is None and result.error is None:
        try:  # the run's files are in place: a signal from here on says so
            return _report_complete(result, where, args, t0)
        except RunInterrupted as e:
            return _interrupted_after_the_run(e, where)
    print(format_summary(result.summaries))
    steps = sum(sc.steps for sc in scenarios.values())
    flown = sum(int(s.get("steps", 0)) for s in result.summaries.values())
    kept = f"{flown} of {steps} steps flown, kept in {where}"
    if result.interrupted is not None:  # stop at once: ``aeromanip replay DIR --mcap`` later
        print(f"aeromanip: interrupted ({result.interrupted}): {kept}", file=sys.stderr)
        return result.interrupted.exit_code
    if result.error is not None:  # a fault it could not fly on: it did not really fly
        print(f"aeromanip: error: the run stopped: {result.error}; {kept}", file=sys.stderr)
        return ExitCode.DID_NOT_FLY if flown else result.error.exit_code
    from aeromanip.experiment.rundir import RunDirectory

    why = describe_os_error(result.io_error, root=str(RunDirectory(out).staging))
    print(f"aeromanip: error: the run stopped: {why}; {kept}", file=sys.stderr)
    return ExitCode.IO


def _report_complete(result: RunResult, where: Path, args: argparse.Namespace, t0: float) -> int:
    """The table, the exports and the last line of a run that flew to its end."""
    print(format_summary(result.summaries))
    if (code := _export(where, args)) is not None:
        return code
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


def _interrupted_after_the_run(e: RunInterrupted, where: Path) -> int:
    """The one line of a signal that came once the run's files were in place."""
    print(
        f"aeromanip: interrupted ({e}) while writing the exports: the run is complete "
        f"in {where} (aeromanip replay {where} --mcap writes them)",
        file=sys.stderr,
    )
    return e.exit_code


def _export(where: Path, args: argparse.Namespace) -> int | None:
    """``run.mcap`` (and the video); an exit code if a signal or the disk stopped it."""
    from aeromanip.interrupts import RunInterrupted, raise_if_interrupted
    from aeromanip.viz.export import export_run

    try:
        export_run(where, mcap=not args.no_mcap, video=args.video)
        raise_if_interrupted()  # one Python could not raise (e.g. in a weakref callback)
    except RunInterrupted as e:
        return _interrupted_after_the_run(e, where)
    except OSError as e:
        print(
            f"aeromanip: error: exports not written: {describe_os_error(e)}; the run is "
            f"complete in {where}",
            file=sys.stderr,
        )
        return ExitCode.IO
    return None
