"""Controller step time on the flight problem (same code as ``aeromanip bench controller``).

Run: ``python benchmarks/bench_controller.py [results.json]``
"""

import json
import sys

from aeromanip.bench.controller_speed import bench_controller, format_controller

if __name__ == "__main__":
    result = bench_controller()
    print(format_controller(result))
    if len(sys.argv) > 1:
        with open(sys.argv[1], "w") as f:
            json.dump(result, f, indent=2)
