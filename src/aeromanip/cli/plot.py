"""``aeromanip plot DIR``: re-draw the figures of a saved run (or of its variants)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from aeromanip.errors import ConfigError


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("plot", help="re-draw the figures of a saved run directory")
    p.add_argument("dir", help="a run directory (or a directory of variant runs)")
    p.set_defaults(func=run)


def run_order(root: Path) -> list[str]:
    """The variant names in the order ``DIR/summary.json`` lists them (empty if none)."""
    try:
        data = json.loads((root / "summary.json").read_text())
    except (OSError, ValueError):
        return []
    return [k for k, v in data.items() if isinstance(v, dict)] if isinstance(data, dict) else []


def run(args: argparse.Namespace) -> int:
    """Draw every figure; print their paths."""
    from aeromanip.experiment.plots import plot_comparison, plot_run
    from aeromanip.experiment.runlog import LOG_FILE, RunLog

    root = Path(args.dir)
    if not root.is_dir():
        raise ConfigError(f"{root}: not a run directory")
    if (root / "results.csv").is_file():  # a sweep (aeromanip sweep): its campaign figures
        from aeromanip.sweep.campaign import draw

        paths = draw(root)
    elif (root / LOG_FILE).is_file():
        paths = plot_run(RunLog.load(root, require_rows=True), root / "figures")
    else:
        runs = sorted(p.parent for p in root.glob(f"*/{LOG_FILE}"))
        order = run_order(root)  # the variants' order in the run, where it was saved
        runs.sort(key=lambda d: order.index(d.name) if d.name in order else len(order))
        if not runs:
            raise ConfigError(f"{root}: no {LOG_FILE} here nor in its sub-directories")
        logs = {d.name: RunLog.load(d, require_rows=True) for d in runs}
        paths = []
        for d in runs:
            paths += plot_run(logs[d.name], d / "figures")
        if len(logs) > 1:
            paths += plot_comparison(logs, root / "figures")
    for p in paths:
        print(p)
    return 0
