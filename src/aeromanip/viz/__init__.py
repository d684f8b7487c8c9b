"""See a run: 3D replay videos (MuJoCo, headless) and MCAP logs for Foxglove.

``replay(run_dir, out)`` renders a saved run (its variants side by side) to MP4, GIF or a
PNG still; ``write_mcap(run_dir)`` writes ``run.mcap`` (transforms, robot description,
scene, every log column, stamped with simulation time). Both read only the run directory
(``log.csv``, ``meta.json``, ``robot.xml``, ``robot.urdf``), so any saved run can be
replayed. The packages they need are the ``viz`` extra: ``pip install 'aeromanip[viz]'``.

Exports: ``replay`` (-> ``ReplayResult``), ``write_mcap``, ``write_mcaps`` (every run of
a directory with variants).
"""

from aeromanip.viz.mcap_log import write_mcap, write_mcaps
from aeromanip.viz.replay import ReplayResult, replay

__all__ = ["ReplayResult", "replay", "write_mcap", "write_mcaps"]
