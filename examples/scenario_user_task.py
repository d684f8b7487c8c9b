"""Example: a user task whose constructor options come from a scenario TOML.

``examples/scenarios/user-task.toml`` names the task ``PlatformHeight`` of
``examples/user_task.py`` as ``kind = "user_task:PlatformHeight"`` and passes its
constructor's ``z_ref`` as a key: the task class has no ``from_table`` of its own.
The scenario is flown in the ideal kinematic loop for 6 s (about 5 s of wall time).

Run: ``python examples/scenario_user_task.py`` (the script's folder is on the import
path, so ``user_task`` imports; with the CLI: ``PYTHONPATH=examples aeromanip run
examples/scenarios/user-task.toml``).

Prints the option the task received, then a final line
``user task: z_ref 1.150 m, final z 1.150 m, EE RMSE ... mm``.
"""

from pathlib import Path

import numpy as np

from aeromanip.experiment import load_scenarios, simulate

SCENARIO = Path(__file__).resolve().parent / "scenarios" / "user-task.toml"


def main() -> None:
    (sc,) = load_scenarios(SCENARIO).values()
    height = next(e.task for e in sc.problem.entries if e.name == "height")
    print(f"task 'height' is {type(height).__name__}(z_ref={height.z_ref})")
    log = simulate(sc)
    ee = np.stack([log.column(f"ee_{c}") for c in "xyz"], axis=1)
    ref = np.stack([log.column(f"ref_{c}") for c in "xyz"], axis=1)
    settled = log.column("t") >= 3.0  # the last 3 s
    rmse = float(np.sqrt(np.mean(np.sum((ee - ref)[settled] ** 2, axis=1))))
    print(
        f"user task: z_ref {height.z_ref:.3f} m, final z {log.column('z')[-1]:.3f} m, "
        f"EE RMSE {1e3 * rmse:.3f} mm"
    )


if __name__ == "__main__":
    main()
