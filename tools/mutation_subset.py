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
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from pathlib import Path


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mutants", type=Path, help="mutmut's mutants/ directory")
    p.add_argument("names", type=Path, help="file of mutant names, one a line")
    p.add_argument("results", type=Path, help="JSON file: mutant name -> exit code")
    p.add_argument("tests", nargs="+", help="test files, relative to mutants/")
    p.add_argument("--timeout", type=int, default=120, help="seconds per mutant")
    args = p.parse_args()
    mdir = args.mutants.resolve()
    names_file, results = args.names.resolve(), args.results.resolve()
    os.chdir(mdir)
    sys.path.insert(0, str(mdir / "src"))
    os.environ.setdefault("AEROMANIP_CODEGEN", "0")
    os.environ["MUTANT_UNDER_TEST"] = ""
    import pytest

    import aeromanip  # the mutated copy

    if not aeromanip.__file__.startswith(str(mdir)):
        raise SystemExit(f"imported {aeromanip.__file__}, not the copy in {mdir}")
    names = names_file.read_text().split()
    out = json.loads(results.read_text()) if results.exists() else {}
    # --tb=no: a traceback through a mutated module (every mutant's copy of each function)
    # takes pytest seconds to parse, longer than the tests
    pytest_args = ["-x", "-q", "--tb=no", "-p", "no:cacheprovider", "-p", "no:randomly"]
    pytest_args += args.tests
    for name in names:
        if name in out:
            continue
        t0 = time.time()
        pid = os.fork()
        if pid == 0:  # the child: quiet, one mutant, a time limit
            os.environ["MUTANT_UNDER_TEST"] = name
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.dup2(null, 2)
            signal.alarm(args.timeout)
            try:
                code = int(pytest.main(pytest_args))
            except BaseException:
                code = 99
            os._exit(code)
        _, status = os.waitpid(pid, 0)
        out[name] = os.waitstatus_to_exitcode(status)
        print(f"{out[name]:4d} {time.time() - t0:6.1f}s {name}", flush=True)
        results.write_text(json.dumps(out, indent=0))
    survived = sorted(n for n in names if out.get(n) == 0)
    print(f"{len(names) - len(survived)} of {len(names)} killed; survived:", *survived, sep="\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
