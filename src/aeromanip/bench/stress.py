"""The controller under stress: binding bounds, a far start, the clearance binding.

Each case is a closed loop of the ``flight`` problem (``bench.controller_speed.KINDS``) flown
by the weighted ``sqp``, ``sqp-rti`` and hierarchical ``sqp`` controllers and by IPOPT
(warm-started, ``tol = 1e-10``) with the same strategy, in this one process; the nominal
flight's hierarchical ``sqp`` is flown too, to scale the hierarchy's step times.

* ``fast``: the flight's reference 25x faster: velocity bounds bind in about a third
  of the steps;
* ``far``: the start 0.9 m from the reference, the platform at its box's corner,
  every joint within 0.1 rad of a limit;
* ``clearance``: the ``clearance`` scenario's reference rises to the base: the
  self-collision constraint (eq. 17) binds.

Targets, per case: no partial step; the hierarchical median within
``HIER_RATIO`` times the nominal one, its p95 within ``P95_MS``; closed-loop costs
within ``SQP_COST`` (``sqp``) and ``RTI_COST`` (``sqp-rti``) of IPOPT's closed loop.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from aeromanip.bench.controller_speed import KINDS, machine, run_variant
from aeromanip.bench.shadow import REF_OPTIONS
from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.codegen import limit_blas_threads

CASES = ("fast", "far", "clearance")
HIER_RATIO = 3.0  # the hierarchical median at most this times the nominal flight's
P95_MS = 10.0  # [ms] the hierarchical step's 95th percentile
SQP_COST = 1.05  # converged sqp: closed-loop cost at most this times IPOPT's
RTI_COST = 1.10  # sqp-rti: at most this times IPOPT's

# row: (strategy, backend, options, the row whose closed-loop cost it is held to)
ROWS: dict[str, tuple[str, str, dict | None, str | None]] = {
    "weighted-ipopt": ("weighted", "ipopt", REF_OPTIONS, None),
    "weighted": ("weighted", "sqp", None, "weighted-ipopt"),
    "rti": ("weighted", "sqp-rti", None, "weighted-ipopt"),
    "hierarchical-ipopt": ("hierarchical", "ipopt", REF_OPTIONS, None),
    "hierarchical": ("hierarchical", "sqp", None, "hierarchical-ipopt"),
}


def bench_stress(
    cases: Sequence[str] | None = None, duration: float = 30.0, warmup: int = 2
) -> dict[str, Any]:
    """Fly every row of ``ROWS`` in each case (default ``CASES``) for ``duration`` [s],
    and the nominal hierarchical flight; the results with each target's verdict."""
    names = list(cases or CASES)
    bad = [c for c in names if c not in KINDS or c == "flight"]
    if bad:
        raise ConfigError(f"stress case {bad[0]!r}: unknown (have: {', '.join(CASES)})")
    limit_blas_threads(1)
    nominal = run_variant("flight", "hierarchical", "sqp", None, duration, warmup)
    out: dict[str, Any] = {
        "machine": machine(),
        "duration_s": duration,
        "nominal_hierarchical_median_ms": nominal["median_ms"],
        "cases": {},
    }
    for case in names:
        rows = {}
        for row, (strategy, backend, options, _) in ROWS.items():
            r = run_variant(case, strategy, backend, options, duration, warmup)
            r.pop("commands")
            rows[row] = r
        out["cases"][case] = {"rows": rows, "targets": _targets(rows, nominal["median_ms"])}
    return out


def _targets(rows: dict[str, dict], nominal_ms: float) -> dict[str, Any]:
    """Each row's closed-loop cost over its IPOPT twin's, and the issue's targets met."""
    h = rows["hierarchical"]
    ratios = {
        name: rows[name]["closed_loop_cost"] / rows[ref]["closed_loop_cost"]
        for name, (_, _, _, ref) in ROWS.items()
        if ref is not None
    }
    hier_ratio = h["median_ms"] / nominal_ms
    return {
        "cost_ratio": ratios,
        "hierarchical_partial_steps": h["partial_steps"],
        "hierarchical_median_over_nominal": hier_ratio,
        "met": {
            "no partial step": h["partial_steps"] == 0,
            f"hierarchical median <= {HIER_RATIO:g}x nominal": hier_ratio <= HIER_RATIO,
            f"hierarchical p95 <= {P95_MS:g} ms": h["p95_ms"] <= P95_MS,
            f"sqp cost <= {SQP_COST:g}x IPOPT's": ratios["weighted"] <= SQP_COST
            and ratios["hierarchical"] <= SQP_COST,
            f"rti cost <= {RTI_COST:g}x IPOPT's": ratios["rti"] <= RTI_COST,
        },
    }


def format_stress(result: dict[str, Any]) -> str:
    """The results as Markdown tables: per case and row, then the targets."""
    lines = [
        f"nominal flight, hierarchical sqp: median "
        f"{result['nominal_hierarchical_median_ms']:.2f} ms",
        "",
        "| case | row | backend | median ms | p95 ms | max ms | fails | partial | cost "
        "| x IPOPT's cost | vel. bound active | bound viol |",
        "|" + "---|" * 12,
    ]
    for case, c in result["cases"].items():
        ratios = c["targets"]["cost_ratio"]
        for row, r in c["rows"].items():
            ratio = f"{ratios[row]:.4f}" if row in ratios else "-"
            lines.append(
                f"| {case} | {row} | {r['backend']} | {r['median_ms']:.2f} | {r['p95_ms']:.2f} "
                f"| {r['max_ms']:.2f} | {r['failures']} | {r['partial_steps']} "
                f"| {r['closed_loop_cost']:.5f} | {ratio} "
                f"| {100 * r['velocity_bound_active_share']:.0f}% "
                f"| {r['max_bound_violation']:.1e} |"
            )
    lines += ["", "| case | target | met |", "|---|---|---|"]
    for case, c in result["cases"].items():
        t = c["targets"]
        for name, ok in t["met"].items():
            lines.append(f"| {case} | {name} | {'yes' if ok else 'NO'} |")
        lines.append(
            f"| {case} | (hierarchical median / nominal) "
            f"| {t['hierarchical_median_over_nominal']:.2f}x |"
        )
    return "\n".join(lines)
