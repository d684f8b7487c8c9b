"""Kill rate per module from mutmut's results (``mutmut results --all true``).

Usage, after ``AEROMANIP_CODEGEN=0 OPENBLAS_NUM_THREADS=1 mutmut run --max-children 2``::

    python tools/mutation_report.py            # the table (Markdown) on standard output
    python tools/mutation_report.py --survivors # every mutant not killed, by module

A mutant counts as killed when a test failed (``killed``), it ran past mutmut's time
limit (``timeout``: an infinite loop is a detected bug) or the test process crashed
(``segfault``: the mutant broke a C library's contract); ``survived`` and ``no tests``
count against the module; ``skipped`` and the type-checker's ``caught by type check``
are not counted.

A run in two phases (docs/testing.md: phase A on fast tests in this directory, phase B
on its survivors in another copy with the full selection)::

    python tools/mutation_report.py --phase-b ../mut_b              # the combined table
    python tools/mutation_report.py --phase-b ../mut_b --remaining  # phase B's to-do list

A mutant phase A did not kill takes phase B's verdict once phase B has checked it.

Results of ``tools/mutation_subset.py`` join the table (the no-op control names ending in
``_99999`` are left out)::

    python tools/mutation_report.py --phase-b ../mut_b --regenerated new/*.json --subset s/*.json

``--regenerated``: whole functions whose mutants were generated again (a later commit or
configuration) and checked by ``mutation_subset.py``: the run's records of those functions
are replaced by these. ``--subset``: a mutant the run did not kill and a subset run did
counts as "killed by a subset run". ``--survivors`` then lists what is left.

``--save FILE.json.gz`` writes the verdicts the table counts (mutant name -> status);
``--verdicts FILE.json.gz`` makes the table (or ``--survivors``) from such a file alone,
without mutmut's directories: ``docs/mutation/nmpc-verdicts.json.gz`` holds the
``nmpc/`` verdicts of docs/testing.md::

    python tools/mutation_report.py --verdicts docs/mutation/nmpc-verdicts.json.gz
"""

from __future__ import annotations

import argparse
import gzip
import json
import re
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

LINE = re.compile(r"^\s*(?P<name>aeromanip\.\S+?__mutmut_\d+): (?P<status>.+)$")
KILLED = {"killed", "timeout", "segfault"}  # a test failed, ran too long, or crashed
LATER = "killed by a subset run"  # mutation_subset.py: later tests, or regenerated mutants
NOT_COUNTED = {"skipped", "caught by type check", "not checked"}


def module_of(name: str) -> str:
    """``aeromanip.nmpc.backends.sqp.solver.xǁSqpBackendǁsolve`` ->
    ``nmpc/backends/sqp/solver.py``."""
    mod = re.split(r"\.x[_ǁ]", name, maxsplit=1)[0]
    return mod.removeprefix("aeromanip.").replace(".", "/") + ".py"


def results(where: Path | None = None) -> list[tuple[str, str]]:
    """(mutant name, status) for every mutant of the mutmut directory ``where`` (default:
    the current one)."""
    out = subprocess.run(
        ["mutmut", "results", "--all", "true"],
        capture_output=True,
        text=True,
        check=True,
        cwd=where,
    ).stdout
    return [(m["name"], m["status"].strip()) for m in map(LINE.match, out.splitlines()) if m]


def combined(rows: list[tuple[str, str]], phase_b: list[tuple[str, str]]) -> list[tuple[str, str]]:
    """Phase A's verdicts, with phase B's for the mutants A did not kill (where B has one)."""
    later = {name: status for name, status in phase_b if status not in NOT_COUNTED}
    return [
        (name, status if status in KILLED | NOT_COUNTED else later.get(name, status))
        for name, status in rows
    ]


def function_of(name: str) -> str:
    """The mutated function of a mutant name (the name without ``__mutmut_<n>``)."""
    return name.rsplit("__mutmut_", 1)[0]


def subset_results(paths: list[Path]) -> dict[str, bool]:
    """Mutant name -> killed, from ``mutation_subset.py`` result files (later files add
    kills; the ``_99999`` no-op controls are left out)."""
    out: dict[str, bool] = {}
    for path in paths:
        for name, code in json.loads(path.read_text()).items():
            if not name.endswith("__mutmut_99999"):
                out[name] = out.get(name, False) or code != 0
    return out


def with_subsets(
    rows: list[tuple[str, str]],
    regenerated: list[Path],
    subset: list[Path],
    override: Path | None = None,
) -> list[tuple[str, str]]:
    """The run's verdicts, corrected by ``override`` (name -> status), with whole
    functions replaced by ``regenerated`` results and the kills of ``subset`` runs added
    (see the module docstring)."""
    status = dict(rows)
    if override is not None:
        status.update(json.loads(override.read_text()))
    fresh = subset_results(regenerated)
    replaced = {function_of(name) for name in fresh}
    status = {name: s for name, s in status.items() if function_of(name) not in replaced}
    status.update({name: LATER if killed else "survived" for name, killed in fresh.items()})
    for name, killed in subset_results(subset).items():
        if killed and status.get(name) not in KILLED | NOT_COUNTED | {None}:
            status[name] = LATER
    return sorted(status.items())


def table(rows: list[tuple[str, str]]) -> str:
    """Markdown: per module, mutants, killed (by the run, by subset runs), survived,
    no tests, kill rate."""
    per: dict[str, Counter] = defaultdict(Counter)
    for name, status in rows:
        per[module_of(name)][status] += 1
    lines = [
        "| module | mutants | killed by the run | killed by subset runs | survived | no tests "
        "| kill rate | not checked |",
        "|---|---|---|---|---|---|---|---|",
    ]
    total = Counter()
    for mod in sorted(per):
        c = per[mod]
        total.update(c)
        lines.append(_row(mod, c))
    lines.append(_row("**all core modules**", total))
    return "\n".join(lines)


def _row(label: str, c: Counter) -> str:
    killed = sum(c[s] for s in KILLED)
    counted = sum(v for s, v in c.items() if s not in NOT_COUNTED)
    rate = f"{100 * (killed + c[LATER]) / counted:.1f} %" if counted else "-"
    return (
        f"| {label} | {counted} | {killed} | {c[LATER]} | {c['survived']} | {c['no tests']} "
        f"| {rate} | {sum(c[s] for s in NOT_COUNTED)} |"
    )


def main() -> int:
    """Print the table, or the mutants not killed."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--survivors", action="store_true", help="list the mutants not killed")
    p.add_argument("--phase-b", type=Path, metavar="DIR", help="phase B's mutmut directory")
    p.add_argument(
        "--remaining", action="store_true", help="phase A's unkilled mutants B has not checked"
    )
    p.add_argument("--regenerated", type=Path, nargs="*", default=[], metavar="JSON")
    p.add_argument("--subset", type=Path, nargs="*", default=[], metavar="JSON")
    p.add_argument("--override", type=Path, metavar="JSON", help="name -> status, by hand")
    p.add_argument("--save", type=Path, metavar="FILE", help="write the verdicts (gzip JSON)")
    p.add_argument("--verdicts", type=Path, metavar="FILE", help="read them instead of a run")
    args = p.parse_args()
    if args.remaining and args.phase_b is None:
        p.error("--remaining needs --phase-b DIR")
    if args.verdicts is not None:
        saved = json.loads(gzip.decompress(args.verdicts.read_bytes()))
        return _report(sorted(saved.items()), args)
    rows = results()
    if args.phase_b is not None:
        phase_b = results(args.phase_b)
        if args.remaining:
            done = {name for name, status in phase_b if status not in NOT_COUNTED}
            for name, status in rows:
                if status not in KILLED | NOT_COUNTED and name not in done:
                    print(name)
            return 0
        rows = combined(rows, phase_b)
    rows = with_subsets(rows, args.regenerated, args.subset, args.override)
    if args.save is not None:
        data = json.dumps(dict(rows), indent=0, sort_keys=True).encode()
        args.save.write_bytes(gzip.compress(data, mtime=0))
    return _report(rows, args)


def _report(rows: list[tuple[str, str]], args: argparse.Namespace) -> int:
    """Print the table, or with ``--survivors`` the mutants not killed."""
    if args.survivors:
        for name, status in sorted(rows):
            if status not in KILLED | NOT_COUNTED | {LATER}:
                print(f"{module_of(name)}\t{name}\t{status}")
    else:
        print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
