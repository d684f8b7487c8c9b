"""A uniform random sample of mutmut's mutants, stratified per module, and its kill rate.

For code where a full run is too slow (``nmpc/``: ~15 s per mutant). Usage, after mutmut
has generated the mutants (``mutants/``, e.g. by a ``mutmut run`` restricted to a glob)::

    python tools/mutation_sample.py pick nmpc --size 220 --seed 18 > sample.txt
    AEROMANIP_CODEGEN=0 mutmut run --max-children 1 $(cat sample.txt)
    python tools/mutation_sample.py report sample.txt [--killed-also extra.txt]

``pick`` draws ``round(size * N_m / N)`` mutants (at least 2) from each module ``m`` under
``src/aeromanip/<prefix>``; ``report`` prints, per package, the stratified kill rate (each
module weighted by its share ``N_m / N`` of the package's mutants) with a 95 % Wilson
interval on the sample's effective size, then (several packages) the same over them all
(``pick "" ...`` samples every mutated module). ``--killed-also`` names mutants killed
outside mutmut (e.g. by new tests run with ``MUTANT_UNDER_TEST``); they count as killed.
"""

from __future__ import annotations

import argparse
import json
import math
import random
from collections import defaultdict
from pathlib import Path

ROOT = Path("mutants/src/aeromanip")
# mutmut's exit codes: a test failed, timed out, or the test process crashed (segfault)
KILLED = {1, 3, 36, -24, 24, 152, 255, -11, -9}
NOT_COUNTED = {34, 37}  # skipped, caught by the type checker


def mutants(prefix: str) -> dict[str, list[str]]:
    """Module (``nmpc/backends/sqp/dense_qp.py``) -> its mutant names, from mutmut's
    ``.meta`` files."""
    out = {}
    for meta in sorted((ROOT / prefix).rglob("*.py.meta")):
        names = sorted(json.loads(meta.read_text())["exit_code_by_key"])
        if names:
            out[str(meta.relative_to(ROOT))[: -len(".meta")]] = names
    return out


def exit_codes() -> dict[str, int | None]:
    codes: dict[str, int | None] = {}
    for meta in ROOT.rglob("*.py.meta"):
        codes.update(json.loads(meta.read_text())["exit_code_by_key"])
    return codes


def wilson(k: float, n: float, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion ``k / n``."""
    p = k / n
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    mid = (p + z * z / (2 * n)) / (1 + z * z / n)
    return mid - half, mid + half


def pick(prefix: str, size: int, seed: int) -> list[str]:
    rng = random.Random(seed)
    mods = mutants(prefix)
    total = sum(len(v) for v in mods.values())
    out = []
    for names in mods.values():
        out += sorted(rng.sample(names, max(2, round(size * len(names) / total))))
    return out


def _row(label: str, mods: dict[str, list[int]], sizes: dict[str, int]) -> str:
    """One table row: the stratified kill rate of ``mods`` (module -> 0/1 per sampled
    mutant), each module weighted by its share of their mutants, and its interval."""
    n_all = sum(sizes[m] for m in mods)
    rate = sum(sizes[m] / n_all * sum(v) / len(v) for m, v in mods.items())
    var = sum((sizes[m] / n_all) ** 2 * rate * (1 - rate) / len(v) for m, v in mods.items())
    n_eff = rate * (1 - rate) / var if var > 0 else sum(len(v) for v in mods.values())
    lo, hi = wilson(rate * n_eff, n_eff)
    n, k = sum(len(v) for v in mods.values()), sum(sum(v) for v in mods.values())
    rates = f"{100 * rate:.1f} % | {100 * lo:.1f} - {100 * hi:.1f} %"
    return f"| {label} | {n_all} | {n} | {k} | {rates} |"


def report(sample: list[str], killed_also: set[str]) -> str:
    codes = exit_codes()
    module_of = {n: m for m, names in mutants("").items() for n in names}
    per: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(list))
    for name in sample:
        code = codes.get(name)
        if code in NOT_COUNTED:
            continue
        if code is None and name not in killed_also:
            raise SystemExit(f"{name}: not run yet")
        mod = module_of[name]
        per[str(Path(mod).parent)][mod].append(int(name in killed_also or code in KILLED))
    lines = ["| package | mutants | sampled | killed | kill rate (stratified) | 95 % interval |"]
    lines.append("|---|---|---|---|---|---|")
    sizes = {m: len(v) for m, v in mutants("").items()}
    for pkg in sorted(per):
        lines.append(_row(f"`{pkg}/`", per[pkg], sizes))
    if len(per) > 1:  # every module sampled, each weighted by its share of them all
        every = {m: v for mods in per.values() for m, v in mods.items()}
        lines.append(_row("**all**", every, sizes))
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("pick", help="print a stratified random sample of mutant names")
    a.add_argument("prefix", help="folder under src/aeromanip, e.g. nmpc")
    a.add_argument("--size", type=int, default=220)
    a.add_argument("--seed", type=int, default=18)
    b = sub.add_parser("report", help="kill rate of a sample, per package, with its interval")
    b.add_argument("sample", type=Path)
    b.add_argument("--killed-also", type=Path)
    args = p.parse_args()
    if args.cmd == "pick":
        print("\n".join(pick(args.prefix, args.size, args.seed)))
    else:
        names = args.sample.read_text().split()
        also = set(args.killed_also.read_text().split()) if args.killed_also else set()
        print(report(names, also))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
