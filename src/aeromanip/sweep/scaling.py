"""How a campaign scales with its workers, measured in one command
(``aeromanip sweep ... --scaling 1,2``).

The same campaign is flown from scratch once per worker count, one after the other, each
into ``DIR/workers-<n>/`` (a whole campaign directory: runs, ``results.csv``, figures) on
a fresh local Ray of ``n`` CPUs (or, with ``--address``, on the cluster capped at ``n``
runs at once). The first campaign compiles each problem into the cache; the next ones
find it there, so the figures compare flying, not compiling. Reported per count: the
campaign's wall time (Ray started and stopped, compile check, tables and figures
included) and its fan-out time (first task submitted to last result), and both as a
ratio to the first count's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from aeromanip.errors import ConfigError
from aeromanip.sweep.campaign import Outcome, Settings, run_campaign
from aeromanip.sweep.plan import Plan

SCALING_DIR = "workers-{}"  # DIR/workers-<n>/: the campaign flown on n workers
MAX_COUNTS = 8  # worker counts in one measurement


@dataclass(frozen=True)
class ScalingPoint:
    """One worker count's campaign: its wall and fan-out times [s] and what it did."""

    workers: int
    wall_s: float
    fanout_s: float
    outcome: Outcome


def parse_counts(text: str) -> tuple[int, ...]:
    """``"1,2"`` -> ``(1, 2)``: distinct positive integers (``ConfigError`` otherwise)."""
    try:
        counts = tuple(int(v) for v in text.split(","))
    except ValueError:
        counts = ()
    if not 2 <= len(counts) <= MAX_COUNTS or min(counts) < 1 or len(set(counts)) != len(counts):
        raise ConfigError(
            f"--scaling {text!r}: expected 2 to {MAX_COUNTS} distinct worker counts >= 1, e.g. 1,2"
        )
    return counts


def check_scaling_out(out: Path, counts: tuple[int, ...]) -> None:
    """Each ``DIR/workers-<n>/`` must be new: a measurement flies every run."""
    for n in counts:
        d = out / SCALING_DIR.format(n)
        if d.exists():
            raise ConfigError(
                f"--scaling: {d} exists; a measurement flies every run from scratch: "
                f"use a new --out"
            )


def measure_scaling(
    plan: Plan, out: Path, settings: Settings, counts: tuple[int, ...]
) -> list[ScalingPoint]:
    """Fly ``plan`` once per worker count in ``counts`` (module docstring)."""
    check_scaling_out(out, counts)
    points = []
    for n in counts:
        result = run_campaign(plan, out / SCALING_DIR.format(n), replace(settings, workers=n))
        points.append(ScalingPoint(n, result.wall_s, result.fanout_s, result))
        if result.interrupted is not None:
            break
    return points


def format_scaling(points: list[ScalingPoint]) -> str:
    """A table: workers, runs done and failed, wall and fan-out times [s], and the speed-up
    of each (the first count's time over its own)."""
    if not points:
        return ""
    first = points[0]
    lines = [
        f"{'workers':>7} {'done':>5} {'failed':>6} {'wall s':>8} {'speed-up':>9} "
        f"{'fan-out s':>10} {'speed-up':>9}"
    ]
    for p in points:
        o = p.outcome
        lines.append(
            f"{p.workers:>7} {o.done:>5} {len(o.errors):>6} {p.wall_s:>8.1f} "
            f"{first.wall_s / p.wall_s:>9.2f} {p.fanout_s:>10.1f} "
            f"{first.fanout_s / p.fanout_s if p.fanout_s else float('nan'):>9.2f}"
        )
    return "\n".join(lines)
