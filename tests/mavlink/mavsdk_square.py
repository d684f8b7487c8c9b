"""A stock MAVSDK offboard app, written as MAVSDK-Python's asyncio API is documented
(``mavsdk`` >= 4: ``mavsdk.asyncio``), with nothing of aeromanip: it connects, waits for a
healthy armable vehicle, reads and sets a parameter, arms, flies a 1 m square with
``set_velocity_ned``, returns to its start with ``set_position_ned``, flies forward with
``set_velocity_body``, holds, and tries to disarm.

``fly(url)`` returns what the app saw: its telemetry (``position_velocity_ned`` with the
event loop's clock, ``time.monotonic``; ``odometry``, stamped by the vehicle), flight
modes, status texts, parameter values and the answers to its actions.
"""

import asyncio

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.offboard import (
    OffboardAsync,
    PositionNedYaw,
    VelocityBodyYawspeed,
    VelocityNedYaw,
)
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

SPEED = 0.5  # [m/s] along each side of the square
SIDE_S = 2.0  # [s] per side: 1 m
SQUARE = ((SPEED, 0.0), (0.0, SPEED), (-SPEED, 0.0), (0.0, -SPEED))  # north, east


async def record(gen, out: list, loop) -> None:
    """Keep every item of the subscription ``gen`` with the loop's time."""
    async for item in gen:
        out.append((loop.time(), item))


async def fly(url: str) -> dict:
    """Fly the app against the vehicle on ``url``; what it saw (module docstring)."""
    loop = asyncio.get_running_loop()
    seen: dict = {"positions": [], "odometry": [], "modes": [], "texts": [], "phases": {}}
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as mavsdk:
        await mavsdk.add_any_connection(url)
        drone = await mavsdk.first_autopilot(timeout_s=10.0)
        assert drone is not None, "no autopilot"
        seen["phases"]["connected"] = loop.time()
        telemetry = TelemetryAsync(drone)
        await telemetry.set_rate_odometry(50.0)  # stamped: the vehicle's time of each
        tasks = [
            asyncio.ensure_future(record(telemetry.subscribe_odometry(), seen["odometry"], loop)),
            asyncio.ensure_future(record(telemetry.subscribe_position_velocity_ned(),
                                         seen["positions"], loop)),
            asyncio.ensure_future(record(telemetry.subscribe_flight_mode(), seen["modes"], loop)),
            asyncio.ensure_future(record(telemetry.subscribe_status_text(), seen["texts"], loop)),
        ]  # fmt: skip
        try:
            await fly_square(drone, telemetry, seen, loop)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
    return seen


async def fly_square(drone, telemetry: TelemetryAsync, seen: dict, loop) -> None:
    """The flight itself (module docstring)."""
    async for health in telemetry.subscribe_health():
        if health.is_global_position_ok and health.is_home_position_ok and health.is_armable:
            seen["health"] = vars(health)
            break
    seen["phases"]["healthy"] = loop.time()
    param = ParamAsync(drone)
    seen["loss_timeout"] = await param.get_param_float("COM_OF_LOSS_T")
    await param.set_param_float("MPC_XY_VEL_MAX", 2.0)
    seen["xy_vel_max"] = await param.get_param_float("MPC_XY_VEL_MAX")
    seen["loss_action"] = await param.get_param_int("COM_OBL_RC_ACT")

    action, offboard = ActionAsync(drone), OffboardAsync(drone)
    await action.arm()
    seen["phases"]["armed"] = loop.time()
    heading = (await telemetry.attitude_euler()).yaw_deg
    await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, heading))
    await offboard.start()  # as MAVSDK's example: one setpoint, then start
    seen["phases"]["offboard"] = loop.time()
    start = (await telemetry.position_velocity_ned()).position
    seen["legs"] = []  # when each side's setpoint was sent (a loaded machine sleeps long)
    for north, east in SQUARE:
        await offboard.set_velocity_ned(VelocityNedYaw(north, east, 0.0, heading))
        seen["legs"].append(loop.time())
        await asyncio.sleep(SIDE_S)
    seen["phases"]["square_done"] = loop.time()
    back = PositionNedYaw(start.north_m, start.east_m, start.down_m, heading)
    seen["start"] = (start.north_m, start.east_m, start.down_m)
    await offboard.set_position_ned(back)
    await asyncio.sleep(4.0)
    seen["phases"]["position_done"] = loop.time()
    await offboard.set_velocity_body(VelocityBodyYawspeed(0.3, 0.0, 0.0, 0.0))  # forward
    await asyncio.sleep(2.0)
    seen["phases"]["body_done"] = loop.time()
    await offboard.stop()  # Hold
    await asyncio.sleep(1.0)
    seen["phases"]["held"] = loop.time()
    try:
        await action.disarm()
        seen["disarm"] = "accepted"
    except ActionError as e:
        seen["disarm"] = e.result.name
    await asyncio.sleep(0.5)
