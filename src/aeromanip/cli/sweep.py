"""``aeromanip sweep SCENARIO``: a parameter sweep or Monte-Carlo campaign on Ray.

Each run is a Ray task flying the scenario with its overrides into ``DIR/runs/<id>/``;
``DIR/results.csv`` has one row per run, ``DIR/figures/`` the campaign's figures. Without
``--address`` an embedded local Ray is started; with it the campaign joins that cluster.
Everything is checked before Ray starts (options, keys, every run's scenario, ``--out``).
Exit codes: 0 every run finished; 2 bad input; 3 some runs failed (recorded in
``results.csv`` and ``failed.json``; the command re-runs them); 130 / 143 interrupted
(re-run the command to resume).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aeromanip.errors import ConfigError, ExitCode

if TYPE_CHECKING:  # the sweep package (and Ray) load when the command runs
    from aeromanip.sweep.axes import SweepSpec
    from aeromanip.sweep.campaign import Outcome, Settings
    from aeromanip.sweep.plan import Plan


MAX_WORKERS = 4096
SPREAD_METRICS = (
    "ee_rmse_m",
    "ee_max_err_m",
    "cog_xy_mean_m",
    "cond_mean",
    "roll_pitch_mean_deg",
    "solve_ms_median",
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("sweep", help="run a parameter sweep or Monte-Carlo campaign on Ray")
    p.add_argument("scenario", help="built-in name or FILE.toml")
    p.add_argument("--out", metavar="DIR", required=True, help="the campaign's directory")
    _add_campaign_options(p.add_argument)
    _add_execution_options(p.add_argument)
    p.set_defaults(func=run)


def _add_campaign_options(add: Callable[..., Any]) -> None:
    """What the campaign flies: the swept and drawn keys, seeds, fixed overrides."""
    add(
        "--grid",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help="sweep a scenario key (any --set key; 'variant' for variants); repeatable",
    )
    add(
        "--random",
        action="append",
        default=[],
        metavar="KEY=LO:HI[:log]",
        help="draw a key uniformly (integers if LO, HI are; log-uniform with :log)",
    )
    add("--samples", type=int, metavar="N", help="random draws (with --random)")
    add("--random-seed", type=int, metavar="S", help="seed of the draws (default 0)")
    add("--seeds", type=int, metavar="K", help="repeat each run with seeds 0..K-1")
    add(
        "--seed-key",
        metavar="KEY",
        help="the key --seeds sets (default physics.seed: the physics noise)",
    )
    add(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scenario value in every run",
    )
    add("--variant", metavar="NAME", help="fly only this variant of the scenario")


def _add_execution_options(add: Callable[..., Any]) -> None:
    """Where and how it runs, and what it reports."""
    add("--address", metavar="ADDRESS", help="join this Ray cluster (default: a local Ray)")
    add("--workers", type=int, metavar="N", help="runs at once (default: all CPUs)")
    add(
        "--max-retries",
        type=int,
        metavar="N",
        help="retries of a run whose worker died (default 3)",
    )
    add(
        "--pareto",
        metavar="A,B",
        help="the two metrics of the Pareto plot, both minimised "
        "(default ee_rmse_m,cog_xy_mean_m; '' for none)",
    )
    add("--metrics", metavar="A,B,...", help="metrics plotted (default: those that vary)")
    add("--no-run-figures", action="store_true", help="skip each run's own figures")
    add(
        "--scaling",
        metavar="N1,N2",
        help="measure: fly the whole campaign once per worker count, into DIR/workers-<n>/, "
        "and print the wall times and speed-ups",
    )
    add("--quiet", action="store_true", help="no progress bar")
    add("--check", action="store_true", help="check everything, list the runs, run nothing")


def _names(text: str | None, option: str, count: int | None = None) -> tuple[str, ...] | None:
    if not text:
        return None
    names = tuple(n.strip() for n in text.split(","))
    if any(not n for n in names) or (count is not None and len(names) != count):
        want = f"{count} comma-separated metric names" if count else "metric names A,B,..."
        raise ConfigError(f"{option} {text!r}: expected {want}")
    return names


def _check_numbers(args: argparse.Namespace) -> None:
    if args.workers is not None and not 1 <= args.workers <= MAX_WORKERS:
        raise ConfigError(f"--workers: must be in [1, {MAX_WORKERS}], got {args.workers}")
    if args.max_retries is not None and not 0 <= args.max_retries <= 100:
        raise ConfigError(f"--max-retries: must be in [0, 100], got {args.max_retries}")


def spread(rows: list[dict[str, str]], metrics: list[str]) -> str:
    """Mean, std, min and max of ``metrics`` over the finished runs, one line each."""
    from aeromanip.sweep.results import number

    done = [r for r in rows if r.get("status") == "done"]
    lines = [f"{'metric':<24}{'mean':>12}{'std':>12}{'min':>12}{'max':>12}   ({len(done)} runs)"]
    for m in metrics:
        v = [x for x in (number(r.get(m)) for r in done) if math.isfinite(x)]
        if v:
            mean = sum(v) / len(v)
            std = math.sqrt(sum((x - mean) ** 2 for x in v) / len(v))
            lines.append(f"{m:<24}" + "".join(f"{x:>12.4g}" for x in (mean, std, min(v), max(v))))
    return "\n".join(lines)


def _spec(args: argparse.Namespace) -> SweepSpec:
    from aeromanip.sweep.axes import make_spec

    _check_numbers(args)
    optional = {"random_seed": args.random_seed, "seed_key": args.seed_key}
    return make_spec(
        args.grid,
        args.random,
        args.samples,
        args.seeds,
        base=args.set,
        variant=args.variant,
        **{k: v for k, v in optional.items() if v is not None},  # else make_spec's defaults
    )


def run(args: argparse.Namespace) -> int:
    """Check, plan, run the campaign, report (exit codes: module docstring)."""
    from aeromanip.experiment.rundir import check_writable
    from aeromanip.nmpc.backends.codegen import cache_dir
    from aeromanip.sweep.campaign import DEFAULT_PARETO, Settings, run_campaign
    from aeromanip.sweep.fanout import MAX_RETRIES, check_ray
    from aeromanip.sweep.plan import check_metric_names, plan_campaign

    spec = _spec(args)
    pareto = DEFAULT_PARETO if args.pareto is None else _names(args.pareto, "--pareto", 2)
    metrics = _names(args.metrics, "--metrics")
    counts = _scaling_counts(args)
    out = Path(args.out)
    check_writable(out)
    check_ray(args.address)
    plan = plan_campaign(args.scenario, spec)
    for option, names in (("--metrics", metrics), ("--pareto", args.pareto and pareto)):
        check_metric_names(plan, names or (), option)
    n, bad = len(plan.runs), len(plan.invalid)
    print(
        f"sweep {args.scenario}: {n} runs over {', '.join(plan.spec.keys)}; "
        f"{len(plan.example)} distinct problem(s) -> {out}"
    )
    for run_id, error in plan.invalid.items():
        print(f"  {run_id}: does not build, recorded as failed: {error}", file=sys.stderr)
    if args.check:
        print(f"ok: {n - bad} runs to fly, {bad} that do not build")
        return 0
    settings = Settings(
        workers=args.workers,
        address=args.address,
        figures=not args.no_run_figures,
        cache_dir=cache_dir().absolute(),  # the driver's cache, for every worker
        quiet=args.quiet,
        metrics=metrics,
        pareto=pareto,
        max_retries=MAX_RETRIES if args.max_retries is None else args.max_retries,
    )
    if counts:
        return scaling_report(plan, out, settings, counts)
    return report(run_campaign(plan, out, settings), pareto or ())


def _scaling_counts(args: argparse.Namespace) -> tuple[int, ...]:
    """The worker counts of ``--scaling`` (empty without it), checked with ``--out``."""
    if not args.scaling:
        return ()
    from aeromanip.sweep.scaling import check_scaling_out, parse_counts

    if args.workers is not None:
        raise ConfigError(f"--workers {args.workers}: --scaling sets the workers of each campaign")
    counts = parse_counts(args.scaling)
    check_scaling_out(Path(args.out), counts)
    return counts


def scaling_report(plan: Plan, out: Path, settings: Settings, counts: tuple[int, ...]) -> int:
    """Fly the campaign once per worker count; print the table (exit codes as ``report``)."""
    from aeromanip.sweep.scaling import format_scaling, measure_scaling

    points = measure_scaling(plan, out, settings, counts)
    print(f"campaign of {len(plan.runs)} runs, flown from scratch per worker count:")
    print(format_scaling(points))
    last = points[-1].outcome
    if last.interrupted is not None:
        print(f"aeromanip: interrupted ({last.interrupted})", file=sys.stderr)
        return last.interrupted.exit_code
    failed = sum(len(p.outcome.errors) for p in points)
    if failed:
        print(
            f"aeromanip: {failed} run(s) failed: see {out}/workers-*/failed.json", file=sys.stderr
        )
        return ExitCode.DID_NOT_FLY
    return 0


def report(result: Outcome, pareto: tuple[str, ...]) -> int:
    """Print what the campaign did; return the exit code (module docstring)."""
    from aeromanip.sweep.results import read_results

    c = result.compiled
    if c:
        print(
            f"compiled once: {c['problems']} problem(s) in the driver in {c['seconds']} s "
            f"({c.get('libraries_built')} libraries built); "
            f"built in the workers: {result.worker_built}"
        )
        for error in c.get("failed", [])[:1]:  # the runs of that problem fail with it too
            print(
                f"aeromanip: {len(c['failed'])} problem(s) did not build: {error}", file=sys.stderr
            )
    print(
        f"{result.ran} run(s) flown now, {result.skipped} done before; {result.done} of "
        f"{result.runs} done, {len(result.errors)} failed; {result.wall_s:.1f} s"
    )
    if result.results is not None:
        rows = read_results(result.results)
        shown = [m for m in dict.fromkeys((*SPREAD_METRICS, *pareto)) if rows and m in rows[0]]
        print(spread(rows, shown))
        print(f"results: {result.results}")
    for p in result.figures:
        print(p)
    if result.figure_error:
        print(f"aeromanip: figures not drawn: {result.figure_error}", file=sys.stderr)
    if result.interrupted is not None:
        print(
            f"aeromanip: interrupted ({result.interrupted}); run the command again to resume",
            file=sys.stderr,
        )
        return result.interrupted.exit_code
    if result.errors:
        where = result.results.parent / "failed.json" if result.results else "failed.json"
        print(f"aeromanip: {len(result.errors)} run(s) failed: see {where}", file=sys.stderr)
        return ExitCode.DID_NOT_FLY
    return 0
