"""Example: a parameter sweep on a local Ray of 2 workers (a tiny grid).

The built-in ``waypoints`` scenario (hierarchical variant), shortened to 6 s, is flown
for each weight of the arm-CoG task in ``{0, 1}``: ``make_spec`` turns the grid into runs
with stable ids, ``plan_campaign`` builds each run's scenario (nothing flown yet),
``run_campaign`` compiles each distinct problem once and fans the runs out as Ray tasks
into ``OUT/runs/<id>/`` (one run directory each), then writes ``OUT/results.csv``. Run it
again on the same ``OUT`` and it skips what is complete.

Run: ``python examples/sweep_local.py [OUT]`` (default: a temporary directory; about
10 s, most of it Ray starting; needs the ``sweep`` extra: ``pip install
'aeromanip[sweep]'``). The same from a shell: ``aeromanip sweep waypoints --variant
hierarchical --set duration=6 --grid tasks.cog.weight=0,1 --workers 2 --out OUT``.

Prints a row per run (weight, EE RMSE, mean arm-CoG offset), then a final line
``sweep: 2 runs on 2 workers; CoG offset ... mm (weight 0) -> ... mm (weight 1)``.
"""

import sys
import tempfile
from pathlib import Path

from aeromanip.sweep import Settings, make_spec, plan_campaign, read_results, run_campaign

GRID = "tasks.cog.weight=0,1"
BASE = ["duration=6"]  # [s]


def main(out: Path) -> None:
    spec = make_spec([GRID], base=BASE, variant="hierarchical")
    plan = plan_campaign("waypoints", spec)
    outcome = run_campaign(plan, out, Settings(workers=2, figures=False, quiet=True))
    if outcome.errors:
        raise SystemExit(f"sweep: runs failed: {outcome.errors}")
    rows = sorted(read_results(out / "results.csv"), key=lambda r: float(r["tasks.cog.weight"]))
    print(f"{'cog weight':>10} {'EE RMSE mm':>11} {'CoG offset mm':>14}  run")
    for r in rows:
        print(
            f"{float(r['tasks.cog.weight']):10g} {1e3 * float(r['ee_rmse_m']):11.3f} "
            f"{1e3 * float(r['cog_xy_mean_m']):14.2f}  {out / 'runs' / r['run_id']}"
        )
    cog = [1e3 * float(r["cog_xy_mean_m"]) for r in rows]
    print(
        f"sweep: {len(rows)} runs on 2 workers; CoG offset {cog[0]:.2f} mm (weight 0) -> "
        f"{cog[1]:.2f} mm (weight 1)"
    )


if __name__ == "__main__":
    if len(sys.argv) > 1:
        main(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            main(Path(tmp) / "sweep")
