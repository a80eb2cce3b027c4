"""The emScon packet encoder and decoder (drivers/trackers/emscon_protocol.py), byte by byte: the layouts are those of
the TPI's ES_C_API_Def.h (little-endian, 4-byte packing); CESAPI's client confirms them against the emulator in
test_emscon_cesapi.py."""

from __future__ import annotations

import struct

import pytest

from drivers.errors import BadReading
from drivers.trackers import emscon_protocol as es
from drivers.trackers import emscon_server as served


def test_commands_are_header_command_and_parameters() -> None:
    assert es.command(es.C_START_MEASUREMENT) == bytes.fromhex("0c000000 00000000 31000000")
    assert es.set_units() == bytes.fromhex("20000000 00000000 05000000" + "00000000" * 5)
    assert es.set_units(1, 1, 0, 0, 0)[12:20] == bytes.fromhex("01000000 01000000")
    assert es.set_coordinate_system(es.CS_RHR) == bytes.fromhex("10000000 00000000 1a000000 00000000")
    assert es.set_stationary_params(1500) == bytes.fromhex("14000000 00000000 1c000000 dc050000 00000000")
    assert es.set_reflector(3) == bytes.fromhex("10000000 00000000 28000000 03000000")
    env = es.set_environment(20.5, 1013.25, 45.0)
    assert len(env) == 36 and struct.unpack("<iII3d", env) == (36, 0, 20, 20.5, 1013.25, 45.0)
    settings = es.set_system_settings((2, 0, 0, 1, 1, 0, 0, 1, 1))
    assert len(settings) == 48 and settings[:12] == bytes.fromhex("30000000 00000000 2f000000")


def test_frame_splits_a_stream_and_keeps_an_incomplete_packet() -> None:
    stream = (served.reply(es.C_SET_UNITS) + served.status_change(27)
              + served.reply(es.C_GET_REFLECTOR, 0, struct.pack("<i", 2)))
    for cut in range(len(stream) + 1):
        first, rest = es.frame(stream[:cut])
        second, left = es.frame(rest + stream[cut:])
        assert left == b"" and [es.decode(p) for p in first + second] == [
            es.Reply(es.C_SET_UNITS, 0), es.StatusChange(27), es.Reply(es.C_GET_REFLECTOR, 0, b"\x02\x00\x00\x00")]


@pytest.mark.parametrize("junk", [b"\xff\xff\xff\x7f\x00\x00\x00\x00", b"\x04\x00\x00\x00\x00\x00\x00\x00",
                                  struct.pack("<iI", es.MAX_PACKET + 1, 0)])
def test_a_header_that_is_no_packet_is_a_bad_reading(junk: bytes) -> None:
    with pytest.raises(BadReading, match="out of step"):
        es.frame(junk + b"\x00" * 8)


def test_single_result_round_trip() -> None:
    packet = served.single_result((1.25, -0.5, 0.75), (2e-5, 3e-5, 4e-5), (21.0, 990.0, 40.0))
    assert len(packet) == 156 and struct.unpack_from("<iI", packet) == (156, es.DT_SINGLE)
    result = es.decode(packet)
    assert isinstance(result, es.SingleResult)
    assert result.values == (1.25, -0.5, 0.75) and result.std == (2e-5, 3e-5, 4e-5)
    assert (result.temperature, result.pressure, result.humidity) == (21.0, 990.0, 40.0)
    assert result.status == 0 and not result.try_mode and result.std_total == pytest.approx(
        (2e-5**2 + 3e-5**2 + 4e-5**2) ** 0.5)
    # the values sit right after status, mode and try-mode flag: byte 20 (4-byte packing: no padding before the doubles)
    assert struct.unpack_from("<3d", packet, 20) == (1.25, -0.5, 0.75)


def test_answers_of_a_known_command_must_have_its_size() -> None:
    good = served.reply(es.C_GET_ENVIRONMENT, 0, served.environment_body((20.0, 1000.0, 50.0)))
    assert es.environment(es.decode(good).body) == (20.0, 1000.0, 50.0)
    with pytest.raises(BadReading, match="GetEnvironmentParams has 16 data bytes, not 24"):
        es.decode(served.reply(es.C_GET_ENVIRONMENT, 0, b"\x00" * 16))
    with pytest.raises(BadReading, match="SetUnits has 4 data bytes, not 0"):
        es.decode(served.reply(es.C_SET_UNITS, 0, b"\x00" * 4))
    assert es.decode(served.reply(es.C_GET_ENVIRONMENT, 57)) == es.Reply(es.C_GET_ENVIRONMENT, 57)  # refused: no data
    with pytest.raises(BadReading, match="unknown type 99"):
        es.decode(struct.pack("<iII", 12, 99, 0))
    with pytest.raises(BadReading, match="continuous 6-DoF result of 12 bytes is too short"):
        es.decode(struct.pack("<iII", 12, es.DT_PROBE_CONTINUOUS, 0))
    with pytest.raises(BadReading, match="status change packet of 16 bytes"):
        es.decode(struct.pack("<iIII", 16, es.DT_STATUS_CHANGE, 27, 0))


def test_reflector_names_are_utf16_and_status_bodies_decode() -> None:
    body = served.reflector_body(3, 2, 6, 0.00635, "RRR 0.5in")
    assert len(body) == 84 and body[20:38] == "RRR 0.5in".encode("utf-16-le")
    assert es.reflector_entry(body) == es.ReflectorEntry(3, 2, 6, 0.00635, "RRR 0.5in")
    status = es.SystemStatus(0, 5, 3, 2, (3, 6, 7), 2, 0, 392001)
    raw = served.system_status_body(status)
    assert len(raw) == es.REPLY_BODY[es.C_GET_SYSTEM_STATUS] == 40 and es.system_status(raw) == status
    assert es.decode(served.error_packet(49, 10004)) == es.ErrorPacket(49, 10004)
    assert es.status_text(10004) == "status 10004 (measurement status not ready)" and es.status_text(7) == "status 7"
    assert es.software_version(served.text_field("3.6.1")) == "3.6.1"


def test_continuous_time_params_are_four_int32() -> None:
    # SetContinuousTimeModeParamsCT: 28 bytes, GetContinuousTimeModeParamsRT: 32 (the header's layout, pack 4)
    assert es.set_continuous_time_params(4) == bytes.fromhex("1c000000 00000000 1e000000 04000000" + "00000000" * 3)
    answer = served.reply(es.C_GET_CONTINUOUS_TIME, 0, struct.pack("<iiiI", 4, 0, 0, 0))
    assert len(answer) == 32 and es.continuous_time_params(es.decode(answer).body) == (4, 0, False, 0)
    with pytest.raises(BadReading, match="GetContinuousTimeModeParams has 8 data bytes, not 16"):
        es.decode(served.reply(es.C_GET_CONTINUOUS_TIME, 0, b"\x00" * 8))


def test_continuous_result_layout_and_round_trip() -> None:
    # MultiMeasResultT: a 48-byte head (header, status, lNumberOfResults, measMode, bIsTryMode, 3 doubles), then
    # 36 bytes per MeasValueT (status, lTime1, lTime2, 3 doubles); MeasValue2T: 92 (sizes of the header's structs)
    values = [[1.0, 2.0, 3.0], [-1.5, 0.25, 2.0]]
    packet = served.multi_result([0, 3], [5001, 5001], [4000, 8000], values, (20.5, 1001.0, 45.0))
    head = struct.pack("<iIIiIi3d", 120, es.DT_MULTI, 0, 2, es.MM_CONTINUOUS_TIME, 0, 20.5, 1001.0, 45.0)
    points = struct.pack("<Iii3d", 0, 5001, 4000, *values[0]) + struct.pack("<Iii3d", 3, 5001, 8000, *values[1])
    assert packet == head + points
    result = es.decode(packet)
    assert isinstance(result, es.MultiResult) and result.std is None and result.mode == es.MM_CONTINUOUS_TIME
    assert result.point_status.tolist() == [0, 3] and result.time1.tolist() == [5001, 5001]
    assert result.time2.tolist() == [4000, 8000] and result.values.tolist() == values
    assert (result.temperature, result.pressure, result.humidity) == (20.5, 1001.0, 45.0)
    extended = served.multi_result([0], [7], [1], [values[0]], (20.0, 1000.0, 50.0), std=[[3e-6, 4e-6, 0.0]])
    assert len(extended) == 48 + 92 and struct.unpack_from("<iI", extended) == (140, es.DT_MULTI2)
    assert struct.unpack_from("<7d", extended, 48 + 36) == (3e-6, 4e-6, 0.0, 5e-6, 0.0, 0.0, 0.0)
    assert es.decode(extended).std.tolist() == [[3e-6, 4e-6, 0.0]]
    with pytest.raises(BadReading, match="says it holds 3 points"):
        es.decode(packet[:12] + struct.pack("<i", 3) + packet[16:])


def test_6dof_probe_result_layout_and_round_trip() -> None:
    # ProbeStationaryResultT: 376 bytes; the tip at byte 48, the quaternion at 184, the environment at 352
    packet = served.probe_stationary_result((1.0, 2.0, 3.0), (1e-5, 2e-5, 2e-5), (0.5, 0.5, 0.5, 0.5), (0.1, 0.2, 0.3),
                                        (1e-4, 1e-4, 2e-4), (21.0, 990.0, 40.0), probe_id=7)
    assert len(packet) == 376 and struct.unpack_from("<iI", packet) == (376, es.DT_PROBE_STATIONARY)
    assert struct.unpack_from("<3d", packet, 48) == (1.0, 2.0, 3.0)
    assert struct.unpack_from("<4d", packet, 184) == (0.5, 0.5, 0.5, 0.5)
    assert struct.unpack_from("<3d", packet, 352) == (21.0, 990.0, 40.0)
    result = es.decode(packet)
    assert isinstance(result, es.ProbeResult) and result.probe_id == 7 and result.mode == es.MM_6D_STATIONARY
    assert result.quaternion == (0.5, 0.5, 0.5, 0.5) and result.angles == (0.1, 0.2, 0.3)
    assert result.position_std == (1e-5, 2e-5, 2e-5) and result.angles_std == (1e-4, 1e-4, 2e-4)
