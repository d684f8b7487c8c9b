"""Example: the controller flying a vehicle over MAVLink, against the SITL autopilot.

Two processes on 127.0.0.1: ``aeromanip sitl flight`` (a PX4-like autopilot over the MuJoCo
physics, speaking PX4's offboard MAVLink subset) in a subprocess, and here the real-time
runtime: ``MavlinkTransport`` (the link), ``MavlinkActuatorArm`` (the arm's joints through
the autopilot), ``RealtimeFlight`` (the ``flight`` scenario's controller on the wall clock,
2 Hz, setpoints streamed at 50 Hz in between) and ``fly_session`` (the run directory). The
runtime connects, arms, switches to offboard, flies 5 s, and leaves the vehicle holding;
the SITL is then stopped (Ctrl-C) and writes the vehicle's truth log. Every wait is
bounded: the SITL stops by itself after 60 s whatever happens.

Run: ``python examples/mavlink_sitl.py [OUT]`` (default: ``runs/mavlink-example``; about
10 s; needs the ``mavlink`` extra: ``pip install 'aeromanip[mavlink]'``). The same from
two shells: ``aeromanip sitl flight --link udpout:127.0.0.1:14540 --out OUT/sitl`` and
``aeromanip fly flight --link udpin:127.0.0.1:14540 --out OUT/fly --set duration=5``.

Prints the runtime's summary (steps, EE RMSE as measured, deadline misses, setpoint rate)
and the vehicle's truth, then a final line ``mavlink: 10 steps over 127.0.0.1:PORT, EE
RMSE ... mm, ... deadline misses, setpoints ... Hz``.
"""

import signal
import socket
import subprocess
import sys
from pathlib import Path

from aeromanip.experiment import RunLog
from aeromanip.mavlink import MavlinkActuatorArm, MavlinkTransport
from aeromanip.runtime import RealtimeFlight, fly_session, one_scenario

HOST = "127.0.0.1"
MISSION_S = 5.0  # [s]
SITL_MAX_S = 60.0  # [s] the SITL stops by itself after this


def free_udp_port() -> int:
    """A UDP port free on the loopback now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def main(out: Path) -> None:
    port = free_udp_port()
    sitl = subprocess.Popen(
        [sys.executable, "-m", "aeromanip.cli", "sitl", "flight", "--out", str(out / "sitl"),
         "--link", f"udpout:{HOST}:{port}", "--max-time", f"{SITL_MAX_S:g}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        link = f"udpin:{HOST}:{port}"
        sc = one_scenario("flight", [f"duration={MISSION_S:g}"], None)
        transport = MavlinkTransport(link)
        try:
            arm = MavlinkActuatorArm(transport, sc.robot)
            result = fly_session(RealtimeFlight(sc, transport, arm), out / "fly", link, False)
        finally:
            transport.close()
    finally:
        sitl.send_signal(signal.SIGINT)  # the SITL stops on Ctrl-C and writes its truth log
        sitl.communicate(timeout=30)
    s = result.summary
    truth = RunLog.load(out / "sitl")
    print(f"runtime: {result.out_dir}, ended: {s.get('ending', '?')}, steps {s['steps']}")
    print(f"vehicle truth: {out / 'sitl'}, {len(truth)} rows, {truth.meta.get('sim')}")
    print(
        f"mavlink: {s['steps']} steps over {HOST}:{port}, EE RMSE {1e3 * s['ee_rmse_m']:.1f} mm, "
        f"{s['deadline_misses']} deadline misses, setpoints {s['setpoint_rate_hz']:.1f} Hz"
    )
    if result.error is not None or not s.get("flight_ok", True):
        raise SystemExit(f"mavlink: the flight did not complete: {result.error or s}")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "runs/mavlink-example"))
