"""The SITL's parameter and mission protocols, byte for byte as PX4 answers them
(``sitl_params``' citations of ``mavlink_parameters.cpp`` and ``mavlink_mission.cpp``).

Requests are packed by a pymavlink client (sysid 255, compid 190) and parsed by the
SITL's side; the answers are parsed back from the bytes: no socket, no clock. That the
parameters change the flight is checked in real time in ``test_sitl_param_flight``.
"""

import struct

import pytest

from aeromanip.mavlink.protocol import load_mavutil
from aeromanip.mavlink.sitl_params import PARAMS, Parameters

pytest.importorskip("pymavlink")

ME = (255, 190)
DOES_NOT_EXIST, VALUE_OUT_OF_RANGE, TYPE_UNSUPPORTED, TYPE_MISMATCH = 1, 2, 6, 7


class Wire:
    """Bytes written by one MAVLink end, read by the other."""

    def __init__(self) -> None:
        self.data = bytearray()

    def write(self, b: bytes) -> None:
        self.data += b


class Link:
    """The SITL's end (sysid 1, compid 1) and a client's, joined by two ``Wire``s."""

    def __init__(self) -> None:
        m = load_mavutil().mavlink
        self.m = m
        self.to_sitl, self.to_client = Wire(), Wire()
        self.client = m.MAVLink(self.to_sitl, srcSystem=ME[0], srcComponent=ME[1])
        self.mav = m.MAVLink(self.to_client, srcSystem=1, srcComponent=1)  # the SITL's
        self.texts: list[str] = []
        self.params = Parameters(self, 1, lambda text, severity: self.texts.append(text))
        self._sitl_parser = m.MAVLink(None)
        self._client_parser = m.MAVLink(None)

    def send(self, name: str, *fields) -> list:
        """The client sends ``name``; the SITL handles it; its answers, parsed."""
        getattr(self.client, f"{name.lower()}_send")(*fields)
        msgs = self._sitl_parser.parse_buffer(bytes(self.to_sitl.data)) or []
        self.to_sitl.data.clear()
        for msg in msgs:
            self.params.handlers()[msg.get_type()](msg)
        out = self._client_parser.parse_buffer(bytes(self.to_client.data)) or []
        self.to_client.data.clear()
        return out


def int32(value: float) -> int:
    """A PARAM_VALUE's INT32 (bytewise in the float, as PX4 sends it)."""
    return struct.unpack("<i", struct.pack("<f", value))[0]


def as_float(i: int) -> float:
    return struct.unpack("<f", struct.pack("<i", i))[0]


def test_the_list_has_every_parameter_with_its_index_count_and_type():
    link = Link()
    values = link.send("PARAM_REQUEST_LIST", 1, 1)
    assert [v.param_id for v in values] == [p.name for p in PARAMS]
    assert [v.param_index for v in values] == list(range(len(PARAMS)))
    assert {v.param_count for v in values} == {len(PARAMS)}
    by_name = {v.param_id: v for v in values}
    assert by_name["COM_OBL_RC_ACT"].param_type == link.m.MAV_PARAM_TYPE_INT32
    assert int32(by_name["COM_OBL_RC_ACT"].param_value) == 5  # Hold
    assert by_name["MPC_XY_VEL_MAX"].param_type == link.m.MAV_PARAM_TYPE_REAL32
    assert by_name["MPC_XY_VEL_MAX"].param_value == 12.0  # PX4's default
    assert by_name["COM_OF_LOSS_T"].param_value == 0.5
    assert link.send("PARAM_REQUEST_LIST", 2, 1) == []  # another system's


def test_reads_by_name_and_index_and_unknown_ones_are_errors():
    link = Link()
    (v,) = link.send("PARAM_REQUEST_READ", 1, 1, b"MPC_Z_VEL_MAX_DN", -1)
    assert (v.param_id, v.param_value, v.param_index) == ("MPC_Z_VEL_MAX_DN", 1.5, 4)
    (v,) = link.send("PARAM_REQUEST_READ", 1, 0, b"", 0)
    assert v.param_id == PARAMS[0].name
    (e,) = link.send("PARAM_REQUEST_READ", 1, 1, b"SYS_AUTOSTART", -1)
    assert e.get_type() == "PARAM_ERROR" and (e.param_id, e.error) == ("SYS_AUTOSTART", 1)
    assert (e.target_system, e.target_component) == ME
    (e,) = link.send("PARAM_REQUEST_READ", 1, 1, b"", 99)
    assert (e.param_index, e.error) == (99, DOES_NOT_EXIST)


def test_a_set_is_echoed_with_the_stored_value_and_changes_what_is_read():
    link = Link()
    (v,) = link.send("PARAM_SET", 1, 1, b"MPC_XY_VEL_MAX", 0.1, 9)
    assert v.get_type() == "PARAM_VALUE" and v.param_value == struct.unpack(
        "<f", struct.pack("<f", 0.1))[0]  # fmt: skip
    assert link.params["MPC_XY_VEL_MAX"] == v.param_value
    (v,) = link.send("PARAM_REQUEST_READ", 1, 1, b"MPC_XY_VEL_MAX", -1)
    assert v.param_value == link.params["MPC_XY_VEL_MAX"]
    (v,) = link.send("PARAM_SET", 1, 1, b"COM_OBL_RC_ACT", as_float(5), 6)  # INT32 bytewise
    assert int32(v.param_value) == 5


@pytest.mark.parametrize(
    ("name", "value", "kind", "error"),
    [
        (b"NO_SUCH_PARAM", 1.0, 9, DOES_NOT_EXIST),
        (b"COM_OF_LOSS_T", 1.0, 3, TYPE_UNSUPPORTED),  # INT16: PX4 has INT32 and REAL32
        (b"COM_OBL_RC_ACT", 5.0, 9, TYPE_MISMATCH),
        (b"COM_OF_LOSS_T", float("nan"), 9, VALUE_OUT_OF_RANGE),
        (b"COM_OF_LOSS_T", float("inf"), 9, VALUE_OUT_OF_RANGE),
        (b"COM_OF_LOSS_T", 61.0, 9, VALUE_OUT_OF_RANGE),
        (b"MPC_Z_VEL_MAX_UP", 0.4, 9, VALUE_OUT_OF_RANGE),
        (b"COM_OBL_RC_ACT", as_float(3), 6, VALUE_OUT_OF_RANGE),  # Return: not flown here
    ],
)
def test_a_bad_set_is_a_param_error_and_changes_nothing(name, value, kind, error):
    link = Link()
    before = dict(link.params.values)
    (e,) = link.send("PARAM_SET", 1, 1, name, value, kind)
    assert e.get_type() == "PARAM_ERROR"
    assert (e.param_id, e.error, e.target_system, e.target_component) == (
        name.decode(), error, *ME)  # fmt: skip
    assert link.params.values == before
    if error == VALUE_OUT_OF_RANGE:  # said in words, with the range
        assert len(link.texts) == 1 and "refused: allowed" in link.texts[0]


def test_a_set_for_another_system_is_ignored():
    link = Link()
    assert link.send("PARAM_SET", 3, 1, b"COM_OF_LOSS_T", 2.0, 9) == []
    assert link.params["COM_OF_LOSS_T"] == 0.5


@pytest.mark.parametrize("mission_type", [0, 1, 2])  # mission, fence, rally
def test_missions_are_empty_and_an_upload_finds_no_space(mission_type):
    link = Link()
    (count,) = link.send("MISSION_REQUEST_LIST", 1, 190, mission_type)
    assert count.get_type() == "MISSION_COUNT"
    assert (count.count, count.mission_type, count.target_system, count.target_component) == (
        0, mission_type, *ME)  # fmt: skip
    (ack,) = link.send("MISSION_COUNT", 1, 1, 3, mission_type)
    assert (ack.type, ack.mission_type) == (link.m.MAV_MISSION_NO_SPACE, mission_type)
    (ack,) = link.send("MISSION_COUNT", 1, 1, 0, mission_type)
    assert ack.type == link.m.MAV_MISSION_ACCEPTED
    (ack,) = link.send("MISSION_CLEAR_ALL", 1, 0, mission_type)
    assert ack.type == link.m.MAV_MISSION_ACCEPTED
    assert link.send("MISSION_REQUEST_LIST", 1, 2, mission_type) == []  # a camera's
