"""Example: replay a saved run: fly a scenario into a run directory, render PNG stills.

``run_scenarios`` flies the built-in ``waypoints`` scenario (hierarchical variant, 6 s,
ideal inner loop) into ``OUT/run/`` (the run-directory contract: ``config.toml``,
``log.csv``, ``summary.json``, ``robot.xml``...); ``aeromanip.viz.replay`` then renders
that directory alone (any saved run can be replayed) with MuJoCo, headless (EGL or
OSMesa), to a PNG still at 1 s and at 5 s. A ``.gif`` or ``.mp4`` path renders a video.

Run: ``python examples/replay_still.py [OUT]`` (default: ``runs/replay-example``; a
few seconds; needs the ``viz`` extra: ``pip install 'aeromanip[viz]'``). The same from a
shell: ``aeromanip run waypoints --variant hierarchical --set duration=6 --out OUT/run``
then ``aeromanip replay OUT/run --out OUT/still.png --at 5``.

Prints each still's path and size, then a final line ``replay: OUT/still-5s.png,
640x480 px, rendered in ... s``.
"""

import sys
from pathlib import Path

from aeromanip.experiment import load_scenarios, run_scenarios
from aeromanip.viz import replay

SIZE = (640, 480)  # [px]


def main(out: Path) -> None:
    scenarios = load_scenarios("waypoints", ["duration=6"], only="hierarchical")
    run_scenarios(scenarios, out / "run", progress=False, figures=False)
    for at in (1.0, 5.0):
        still = replay(out / "run", out / f"still-{at:g}s.png", at=at, size=SIZE)
        print(f"{still.path}: {still.size[0]}x{still.size[1]} px at t = {at:g} s")
    print(
        f"replay: {still.path}, {still.size[0]}x{still.size[1]} px, "
        f"rendered in {still.wall_s:.2f} s"
    )


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "runs/replay-example"))
