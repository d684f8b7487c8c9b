"""The MAVLink 2 subset both ends speak (the bridge and the SITL autopilot), as PX4 does.

- ``HEARTBEAT`` (1 Hz or more each way): the autopilot's ``base_mode`` has
  ``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`` and, when armed, ``MAV_MODE_FLAG_SAFETY_ARMED``;
  its ``custom_mode`` is PX4's ``main_mode << 16 | sub_mode << 24``.
- ``COMMAND_LONG`` -> ``COMMAND_ACK``: ``MAV_CMD_COMPONENT_ARM_DISARM`` (param1 1 / 0),
  ``MAV_CMD_DO_SET_MODE`` (param1 ``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED``, param2 the PX4
  main mode, param3 the sub mode), ``MAV_CMD_DO_SET_ACTUATOR`` (the arm, see ``arm.py``).
- ``SET_POSITION_TARGET_LOCAL_NED`` in ``MAV_FRAME_LOCAL_NED`` with ``VELOCITY_YAW_RATE``:
  velocity and yaw rate used, position, acceleration and yaw ignored. Its
  ``time_boot_ms`` carries the runtime's mission clock [ms] (0 before the flight starts;
  PX4 ignores it, the SITL logs the reference the vehicle should be at from it).
- State from the autopilot: ``LOCAL_POSITION_NED`` and ``ATTITUDE``; arm joints as
  ``NAMED_VALUE_FLOAT`` ``q1``.. ``qn`` [rad] (see ``arm.py``).

``load_mavutil`` imports pymavlink with MAVLink 2 framing (the ``MAVLINK20`` switch must
be set before its dialect is loaded).
"""

from __future__ import annotations

import errno
import importlib.util
import os
import socket
from types import ModuleType
from typing import Any

from aeromanip.errors import ConfigError
from aeromanip.runtime.transport import LinkError

# PX4 custom modes (px4_custom_mode.h): main modes and the AUTO sub modes used here
PX4_MAIN_AUTO = 4
PX4_MAIN_OFFBOARD = 6
PX4_SUB_AUTO_LOITER = 3
MODES = {"hold": (PX4_MAIN_AUTO, PX4_SUB_AUTO_LOITER), "offboard": (PX4_MAIN_OFFBOARD, 0)}
LINK_SCHEMES = ("udpin", "udpout", "udp", "tcp", "tcpin", "serial")

# MAVLink common enum values (checked against pymavlink by the tests)
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_FRAME_LOCAL_NED = 1
X_IGNORE, Y_IGNORE, Z_IGNORE = 1, 2, 4
VX_IGNORE, VY_IGNORE, VZ_IGNORE = 8, 16, 32
AX_IGNORE, AY_IGNORE, AZ_IGNORE = 64, 128, 256
YAW_IGNORE, YAW_RATE_IGNORE = 1024, 2048
#: SET_POSITION_TARGET_*: velocity + yaw rate, everything else ignored (= 1479, 0x5C7)
VELOCITY_YAW_RATE = X_IGNORE | Y_IGNORE | Z_IGNORE | AX_IGNORE | AY_IGNORE | AZ_IGNORE | YAW_IGNORE

_mavutil: list[ModuleType] = []


def load_mavutil() -> ModuleType:
    """``pymavlink.mavutil`` set to MAVLink 2 and the common dialect (PX4 speaks it)."""
    if _mavutil:
        return _mavutil[0]
    os.environ["MAVLINK20"] = "1"
    try:
        from pymavlink import mavutil
    except ImportError:
        raise ConfigError(
            "--link: MAVLink needs pymavlink: pip install 'aeromanip[mavlink]'"
        ) from None
    mavutil.set_dialect("common")
    _mavutil.append(mavutil)
    return mavutil


def custom_mode(mode: str) -> int:
    """PX4's ``custom_mode`` of ``"hold"`` or ``"offboard"`` (HEARTBEAT encoding)."""
    main, sub = MODES[mode]
    return (main << 16) | (sub << 24)


def mode_name(custom: int) -> str:
    """The mode a HEARTBEAT's ``custom_mode`` names: ``hold``, ``offboard`` or ``other``."""
    main, sub = (custom >> 16) & 0xFF, (custom >> 24) & 0xFF
    for name, (m, s) in MODES.items():
        if main == m and (s == 0 or sub == s):
            return name
    return "other"


def parse_link(url: str, what: str = "--link") -> tuple[str, int | None]:
    """A link URL as (pymavlink device, serial baud or ``None``): ``udpin:HOST:PORT``
    (listen; a companion computer's usual end), ``udpout:HOST:PORT``, ``udp:HOST:PORT``,
    ``tcp:HOST:PORT``, ``tcpin:HOST:PORT`` or ``serial:DEVICE:BAUD``; anything else is one
    ``ConfigError`` line naming what is allowed."""
    scheme, _, rest = url.partition(":")
    if scheme == "serial":
        device, _, baud = rest.rpartition(":")
        if device.startswith("/") and baud.isdigit() and int(baud) > 0:
            return device, int(baud)
    elif scheme in LINK_SCHEMES:
        host, _, port = rest.rpartition(":")
        if host and port.isdigit() and 0 < int(port) < 65536:
            return url, None
    raise ConfigError(
        f"{what}: {url!r} is not a MAVLink link; use "
        f"{', '.join(s + ':HOST:PORT' for s in LINK_SCHEMES[:-1])} or serial:DEVICE:BAUD"
    )


TCP_CONNECT_TIMEOUT_S = 5.0  # [s] a tcp: link's peer must accept the connection within this

LINK_FIXES = {  # errno name -> what the user can do
    "EADDRINUSE": "another program (another aeromanip, a ground station) listens on that "
    "port: stop it or use another port",
    "ECONNREFUSED": "nothing listens there: start the autopilot (or aeromanip sitl) first, "
    "or check the port",
    "EADDRNOTAVAIL": "that is not an address of this machine: listen on 0.0.0.0 or on one "
    "of its addresses",
    "EACCES": "not permitted: use a port above 1024, or for a serial device join its "
    "group (dialout)",
    "ENOENT": "no such device: check the cable and the device's name",
    "ETIMEDOUT": "no answer: check the address and the network",
    "": "check the address and the network",
    "ENETUNREACH": "no route to that network: check the address and the network",
    "EHOSTUNREACH": "no route to that host: check the address and the network",
}


def open_link(url: str, source_system: int, source_component: int) -> Any:
    """A pymavlink connection on ``url``; a link that cannot be opened is one
    ``LinkError`` line naming the cause and the fix (a missing pyserial: ``ConfigError``)."""
    device, baud = parse_link(url)
    mavutil = load_mavutil()
    scheme, _, rest = url.partition(":")
    if scheme == "serial":
        if importlib.util.find_spec("serial") is None:
            raise ConfigError("--link: serial links need pyserial: pip install pyserial")
    else:
        host, _, port = rest.rpartition(":")
        try:
            socket.getaddrinfo(host, int(port), socket.AF_INET)
        except (socket.gaierror, UnicodeError) as e:
            why = getattr(e, "strerror", None) or str(e)
            raise LinkError(
                f"--link: {url}: cannot resolve host {host!r} ({why}); use an IPv4 address "
                "or a name this machine resolves"
            ) from None
    kw: dict[str, Any] = {} if baud is None else {"baud": baud}
    if scheme == "tcp":  # one bounded try (pymavlink's own retries sleep and print)
        kw["retries"] = 0
    try:
        if scheme == "tcp":
            host, _, port = rest.rpartition(":")
            socket.create_connection((host, int(port)), timeout=TCP_CONNECT_TIMEOUT_S).close()
        return mavutil.mavlink_connection(
            device, source_system=source_system, source_component=source_component, **kw
        )
    except OSError as e:
        name = errno.errorcode.get(e.errno or 0, "")
        fix = LINK_FIXES.get(name, "check the link")
        cause = f"{e.strerror or e}" + (f" ({name})" if name else "")
        raise LinkError(f"--link: {url}: {cause}; {fix}") from None
    except ValueError as e:  # pymavlink's own checks (e.g. an IPv6 address)
        raise ConfigError(f"--link: {url!r}: {e}") from None
