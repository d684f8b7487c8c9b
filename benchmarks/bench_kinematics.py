"""Kinematics evaluation time (same code as ``aeromanip bench kinematics``).

Run: ``python benchmarks/bench_kinematics.py [results.json]``
"""

import json
import sys

from aeromanip.bench.kinematics_speed import bench_kinematics, format_kinematics

if __name__ == "__main__":
    results = {robot: bench_kinematics(robot) for robot in ("planar-2dof", "x8-3dof")}
    for r in results.values():
        print(format_kinematics(r), end="\n\n")
    if len(sys.argv) > 1:
        with open(sys.argv[1], "w") as f:
            json.dump(results, f, indent=2)
