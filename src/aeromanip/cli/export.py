"""``aeromanip export SCENARIO --out DIR``: the scenario's controller as a C library.

Writes the sources, a header, a Makefile and a closed-loop example (``export.writer``);
with ``--build`` also builds them with ``make`` and flies the example. A controller that
cannot be exported is refused in one line before anything is built.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

BUILD_TIMEOUT_S = 600  # [s] make, generated model included


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("export", help="write the scenario's controller as a C library")
    p.add_argument("scenario", help="built-in name or FILE.toml")
    p.add_argument("--out", metavar="DIR", help="output directory (default export/<scenario>)")
    p.add_argument("--variant", metavar="NAME", help="the variant to export")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scenario value")
    p.add_argument("--build", action="store_true", help="then build it and fly the example")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Check, build the controller, write, and (``--build``) make and fly."""
    from aeromanip.errors import ConfigError
    from aeromanip.experiment.closed_loop import make_controller
    from aeromanip.experiment.rundir import check_writable
    from aeromanip.experiment.scenario import load_scenarios
    from aeromanip.export.writer import ExportRequest, check_scenario, export_controller

    scenarios = load_scenarios(args.scenario, args.set or [], args.variant)
    if len(scenarios) > 1:
        names = ", ".join(scenarios)
        raise ConfigError(f"--variant: the scenario has variants ({names}); name one to export")
    sc = next(iter(scenarios.values()))
    out = Path(args.out or Path("export") / sc.name.replace("/", "-"))
    check_writable(out)
    check_scenario(sc)
    if args.build and shutil.which("make") is None:
        raise ConfigError("--build: 'make' is not installed")
    req = ExportRequest(make_controller(sc), sc.name, _command(args), sc.x0, sc.duration)
    files = export_controller(req, out)
    print(f"{sc.name}: wrote {len(files)} files to {out}")
    if sc.solver_options.get("seed", "ipopt") != "none":
        print("note: the exported step has no IPOPT seed: a cold start is the SQP's from rest "
              "(the Python controller's with controller.solver_options.seed = 'none')")  # fmt: skip
    if not args.build:
        print(f"build and fly it: make -C {shlex.quote(str(out))} run")
        return 0
    return _build_and_fly(out)


def _command(args: argparse.Namespace) -> str:
    """The command line that writes this export (``--out`` and ``--build`` aside)."""
    words = ["aeromanip", "export", args.scenario]
    if args.variant:
        words += ["--variant", args.variant]
    for text in args.set or []:
        words += ["--set", text]
    return shlex.join(words)


def _build_and_fly(out: Path) -> int:
    """``make`` then the example; its summary line printed; make's or the example's
    failure is the exit code."""
    from aeromanip.errors import ExitCode

    build = subprocess.run(["make", "-C", str(out)], capture_output=True, text=True,
                           timeout=BUILD_TIMEOUT_S)  # fmt: skip
    if build.returncode != 0:
        tail = (build.stderr or build.stdout).strip().splitlines()[-1:] or ["no output"]
        print(f"aeromanip: make failed in {out}: {tail[0]}", file=sys.stderr)
        return int(ExitCode.DID_NOT_FLY)
    fly = subprocess.run([str(out / "example" / "example")], capture_output=True, text=True)
    summary = fly.stdout.strip().splitlines()[-1:] or ["no output"]
    print(f"example: {summary[0]}")
    return 0 if fly.returncode == 0 else int(ExitCode.DID_NOT_FLY)
