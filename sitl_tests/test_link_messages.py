"""Encoding of what groundctl sends, checked by decoding with pymavlink itself."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link import messages
from groundctl.link.codec import DatagramParser, Encoder, new_codec


def roundtrip(msg: mavlink.MAVLink_message) -> mavlink.MAVLink_message:
    data = Encoder(new_codec(255, 190)).encode(msg)
    parser = mavlink.MAVLink(None)
    (decoded,) = parser.parse_buffer(data)
    assert decoded.get_srcSystem() == 255 and decoded.get_srcComponent() == 190
    return decoded


@pytest.mark.parametrize(
    ("vel", "acc", "yaw", "mask"),
    [
        (None, None, None, 0x0DF8),
        ((1.0, 2.0, 3.0), None, None, 0x0DC0),
        ((1.0, 2.0, 3.0), (0.1, 0.2, 0.3), None, 0x0C00),
        (None, None, 1.5, 0x09F8),
        ((1.0, 2.0, 3.0), (0.1, 0.2, 0.3), 1.5, 0x0800),
    ],
)
def test_local_ned_type_mask_and_fields(vel, acc, yaw, mask) -> None:
    msg = roundtrip(messages.position_target_local_ned(7, 12345, (10.0, -5.0, -20.0),
                                                       vel, acc, yaw))
    assert msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
    assert msg.type_mask == mask
    assert msg.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED
    assert msg.target_system == 7 and msg.time_boot_ms == 12345
    assert (msg.x, msg.y, msg.z) == (10.0, -5.0, -20.0)
    if vel is not None:
        assert (msg.vx, msg.vy, msg.vz) == vel
    if acc is not None:
        assert [msg.afx, msg.afy, msg.afz] == pytest.approx(acc)
    if yaw is not None:
        assert msg.yaw == 1.5
    assert not msg.type_mask & messages.FORCE_SET


def test_local_ned_rejects_wrong_vector_length() -> None:
    with pytest.raises(ValueError, match="`vel_ned` must have 3 components"):
        messages.position_target_local_ned(1, 0, (0, 0, 0), vel_ned=(1.0, 2.0))


def test_global_int_scales_and_frame() -> None:
    msg = roundtrip(messages.position_target_global_int(
        3, 99, 47.3977419, 8.5455938, 488.5, vel_ned=(1.0, 0.0, -0.5),
        frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT))
    assert msg.lat_int == 473977419 and msg.lon_int == 85455938
    assert msg.alt == pytest.approx(488.5)
    assert msg.coordinate_frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    assert msg.type_mask == 0x0DC0
    with pytest.raises(ValueError, match="`frame`"):
        messages.position_target_global_int(3, 0, 0, 0, 0, frame=mavlink.MAV_FRAME_LOCAL_NED)
    with pytest.raises(ValueError, match="`lat_deg`"):
        messages.position_target_global_int(3, 0, 91.0, 0, 0)


def test_led_control_layout_for_stock_ardupilot() -> None:
    msg = roundtrip(messages.led_rgb(5, 255, 128, 0))
    assert msg.get_type() == "LED_CONTROL"
    assert (msg.target_system, msg.instance, msg.pattern) == (5, 0, 0)
    assert msg.custom_len == 3
    assert list(msg.custom_bytes) == [255, 128, 0] + [0] * 21
    blink = roundtrip(messages.led_rgb(0, 1, 2, 3, blink_hz=4))
    assert blink.target_system == 0 and blink.custom_len == 4
    assert list(blink.custom_bytes[:4]) == [1, 2, 3, 4]
    with pytest.raises(ValueError, match=r"`g` must be in 0\.\.255"):
        messages.led_rgb(1, 0, 256, 0)


def test_command_long_and_interval() -> None:
    msg = roundtrip(messages.command_long(4, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                          (32, messages.message_interval_us(10)),
                                          confirmation=2))
    assert (msg.target_system, msg.target_component, msg.confirmation) == (4, 1, 2)
    assert msg.param1 == 32 and msg.param2 == 100_000 and msg.param7 == 0
    assert messages.message_interval_us(0) == -1
    assert messages.command_name(400) == "MAV_CMD_COMPONENT_ARM_DISARM"
    assert messages.result_name(4) == "MAV_RESULT_FAILED"


def test_gcs_heartbeat() -> None:
    msg = roundtrip(messages.gcs_heartbeat())
    assert msg.type == mavlink.MAV_TYPE_GCS
    assert msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID


def test_encoder_advances_sequence() -> None:
    enc = Encoder(new_codec())
    parser = DatagramParser(new_codec())
    seqs = []
    for _ in range(3):
        (m,) = parser.feed(enc.encode(messages.gcs_heartbeat())).messages
        seqs.append(m.get_seq())
    assert seqs == [0, 1, 2]


def test_parser_counts_garbage_and_truncation_without_raising() -> None:
    enc = Encoder(new_codec(1, 1))
    good = enc.encode(messages.gcs_heartbeat())
    parser = DatagramParser(new_codec())
    res = parser.feed(b"\x00\x01garbage" + good)
    assert len(res.messages) == 1 and res.bad
    res = parser.feed(good[: len(good) // 2])
    assert not res.messages and any("truncated" in r for r in res.bad)
    corrupted = bytearray(good)
    corrupted[-1] ^= 0xFF
    res = parser.feed(bytes(corrupted))
    assert not res.messages and any("CRC" in r for r in res.bad)
    # the parser is not left half-way: the next good packet decodes
    assert len(parser.feed(good).messages) == 1
    assert math.isfinite(len(res.bad))
