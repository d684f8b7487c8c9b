"""Run mutmut's mutants against chosen test files, with mutmut's own trampolines.

For a module whose mutants mutmut would test with most of the suite each (a function
nearly every test calls). Usage, in a copy of the repository whose ``mutants/`` mutmut has
generated (its tests are ``mutants/tests``; copy new test files there)::

    python tools/mutation_subset.py mutants names.txt results.json tests/test_a.py ...

``names.txt``: one mutant name a line (``aeromanip.robot.spec.x_validate__mutmut_3``).
Per mutant, a child forked from one process that imported ``mutants/src/aeromanip`` sets
``MUTANT_UNDER_TEST`` and runs ``pytest -x`` on the files; its exit code is stored in
``results.json`` (0: survived; a child past ``--timeout`` seconds counts as a timeout, a
kill). A mutant these files kill is killed by the suite: the count is a lower bound.
Results already in ``results.json`` are kept (the run resumes).

A control (a mutant name no function has, so every function runs as written) runs first
and last: it must pass. If it fails first, nothing is run; if it fails last, the run's
verdicts are not to be trusted and the exit code is 1. Each child has Python's own SIGINT
handler, whatever the shell gave this process (a background job's SIGINT is ignored).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from pathlib import Path

CONTROL = "aeromanip.x__mutation_subset_control__mutmut_0"  # no function has this name


def run_one(name: str, pytest_args: list[str], timeout_s: int, logs: Path | None) -> int:
    """Fork a child that runs pytest with ``name`` as the mutant under test; its exit code
    (0: the tests pass, i.e. the mutant survived)."""
    import pytest

    pid = os.fork()
    if pid == 0:  # the child: one mutant, its output to a log or nowhere, a time limit
        os.environ["MUTANT_UNDER_TEST"] = name
        signal.signal(signal.SIGINT, signal.default_int_handler)
        sink = str(logs / f"{name}.log") if logs else os.devnull
        fd = os.open(sink, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        signal.alarm(timeout_s)
        try:
            code = int(pytest.main(pytest_args))
        except BaseException:
            code = 99
        os._exit(code)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status)


def _control(when: str, pytest_args: list[str], args: argparse.Namespace) -> bool:
    t0 = time.time()
    code = run_one(CONTROL, pytest_args, args.timeout, args.logs)
    print(f"{code:4d} {time.time() - t0:6.1f}s control ({when})", flush=True)
    if code != 0:
        print(
            f"the control failed {when} (exit {code}): the unmutated code fails these tests"
            f" here; see {args.logs or 'a run with --logs'}",
            file=sys.stderr,
        )
    return code == 0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mutants", type=Path, help="mutmut's mutants/ directory")
    p.add_argument("names", type=Path, help="file of mutant names, one a line")
    p.add_argument("results", type=Path, help="JSON file: mutant name -> exit code")
    p.add_argument("tests", nargs="+", help="test files, relative to mutants/")
    p.add_argument("--timeout", type=int, default=120, help="seconds per mutant")
    p.add_argument("--logs", type=Path, help="directory for each child's pytest output")
    args = p.parse_args()
    mdir = args.mutants.resolve()
    names_file, results = args.names.resolve(), args.results.resolve()
    if args.logs:
        args.logs = args.logs.resolve()
        args.logs.mkdir(parents=True, exist_ok=True)
    os.chdir(mdir)
    sys.path.insert(0, str(mdir / "src"))
    os.environ.setdefault("AEROMANIP_CODEGEN", "0")
    os.environ["MUTANT_UNDER_TEST"] = ""
    import aeromanip  # the mutated copy

    if not aeromanip.__file__.startswith(str(mdir)):
        raise SystemExit(f"imported {aeromanip.__file__}, not the copy in {mdir}")
    names = names_file.read_text().split()
    out = json.loads(results.read_text()) if results.exists() else {}
    # --tb=no: a traceback through a mutated module (every mutant's copy of each function)
    # takes pytest seconds to parse, longer than the tests
    pytest_args = ["-x", "-q", "--tb=no", "-rfE", "-p", "no:cacheprovider", "-p", "no:randomly"]
    pytest_args += args.tests
    if not _control("first", pytest_args, args):
        return 1
    for name in names:
        if name in out:
            continue
        t0 = time.time()
        out[name] = run_one(name, pytest_args, args.timeout, args.logs)
        print(f"{out[name]:4d} {time.time() - t0:6.1f}s {name}", flush=True)
        results.write_text(json.dumps(out, indent=0))
    survived = sorted(n for n in names if out.get(n) == 0)
    print(f"{len(names) - len(survived)} of {len(names)} killed; survived:", *survived, sep="\n")
    return 0 if _control("last", pytest_args, args) else 1


if __name__ == "__main__":
    raise SystemExit(main())
