"""Protocol 2.0 codec, register tables and unit conversion (no serial port)."""

import math

import numpy as np
import pytest

from trajgen.drivers.control_table import (
    MODELS,
    Register,
    describe_hardware_error,
    layout,
    model_named,
    model_numbered,
)
from trajgen.drivers.protocol import (
    BROADCAST_ID,
    Instruction,
    PacketError,
    PacketReader,
    crc16,
    decode,
    encode,
    encode_fast_sync_status,
    encode_status,
    stuff,
    unstuff,
)
from trajgen.drivers.units import JointMap, to_signed, to_unsigned

# Captured from dynamixel-sdk 4.1.0 (docs/dynamixel.md): sync write of Goal Position
# 2048, 1024, -4096 to ids 1, 2, 3, and ping(1).
SYNC_WRITE_BYTES = bytes.fromhex(
    "FF FF FD 00 FE 16 00 83 74 00 04 00 01 00 08 00 00 02 00 04 00 00 03 00 F0 FF FF 3E 87"
)
PING_BYTES = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")


def test_encode_matches_captured_sync_write():
    params = bytes([116, 0, 4, 0])  # Goal Position, 4 bytes
    for servo_id, goal in ((1, 2048), (2, 1024), (3, -4096)):
        params += bytes([servo_id]) + to_unsigned(goal, 4).to_bytes(4, "little")
    assert encode(BROADCAST_ID, Instruction.SYNC_WRITE, params) == SYNC_WRITE_BYTES


def test_encode_matches_captured_ping():
    assert encode(1, Instruction.PING) == PING_BYTES


def test_decode_captured_sync_write():
    packet = decode(SYNC_WRITE_BYTES)
    assert packet.servo_id == BROADCAST_ID
    assert packet.instruction == Instruction.SYNC_WRITE
    assert packet.params[:4] == bytes([0x74, 0, 4, 0])  # Goal Position, 4 bytes
    blocks = [packet.params[4 + 5 * k : 9 + 5 * k] for k in range(3)]
    assert [b[0] for b in blocks] == [1, 2, 3]
    assert int.from_bytes(blocks[0][1:], "little") == 2048
    assert int.from_bytes(blocks[1][1:], "little") == 1024
    assert to_signed(int.from_bytes(blocks[2][1:], "little"), 4) == -4096


def test_crc_of_captured_packets():
    for raw in (SYNC_WRITE_BYTES, PING_BYTES):
        assert crc16(raw[:-2]) == raw[-2] | raw[-1] << 8


def test_crc_against_bitwise_definition(rng):
    def bitwise(data):
        crc = 0
        for byte in data:
            crc ^= byte << 8
            for _ in range(8):
                crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else crc << 1
                crc &= 0xFFFF
        return crc

    for _ in range(20):
        data = rng.integers(0, 256, rng.integers(1, 40)).astype(np.uint8).tobytes()
        assert crc16(data) == bitwise(data)


def test_stuffing_inserts_fd_after_header_pattern():
    body = bytes([0x55, 0x00, 0xFF, 0xFF, 0xFD, 0x07])
    assert stuff(body) == bytes([0x55, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x07])
    assert unstuff(stuff(body)) == body


def test_stuffing_round_trip_random(rng):
    for _ in range(50):
        body = rng.choice([0xFF, 0xFD, 0x00, 0x12], size=rng.integers(1, 30)).astype(np.uint8)
        body = body.tobytes()
        stuffed = stuff(body)
        assert unstuff(stuffed) == body
        # No header pattern survives unescaped: every FF FF FD is followed by FD.
        hits = [i for i in range(len(stuffed) - 2) if stuffed[i : i + 3] == b"\xff\xff\xfd"]
        assert all(stuffed[i + 3 : i + 4] == b"\xfd" for i in hits)


def test_status_with_stuffed_data_decodes_to_original():
    data = bytes([0xFF, 0xFF, 0xFD, 0x01])
    raw = encode_status(3, 0, data)
    assert len(raw) == 11 + len(data) + 1  # one stuffed byte
    packet = decode(raw)
    assert (packet.servo_id, packet.instruction, packet.params) == (3, 0x55, b"\x00" + data)


def test_decode_rejects_bad_crc():
    raw = bytearray(PING_BYTES)
    raw[-1] ^= 0x01
    with pytest.raises(PacketError, match="CRC"):
        decode(bytes(raw))


def test_decode_rejects_bad_header_and_length():
    with pytest.raises(PacketError, match="bad header"):
        decode(b"\xff\xff\xfe\x00" + PING_BYTES[4:])
    with pytest.raises(PacketError, match="length field"):
        decode(SYNC_WRITE_BYTES[:-1])


def test_encode_rejects_bad_id():
    with pytest.raises(ValueError, match="Expected `servo_id` in 0..254, got 300"):
        encode(300, Instruction.PING)


def test_fast_sync_status_layout():
    entries = [(0, 1, b"\x01\x02"), (0x80, 2, b"\x03\x04")]
    raw = encode_fast_sync_status(entries)
    # Header, id FE, LEN = 1 + 2 * (2 + 4), INST 55, then ERR ID DATA CRC2 each.
    assert raw[:8] == bytes([0xFF, 0xFF, 0xFD, 0x00, 0xFE, 13, 0, 0x55])
    assert len(raw) == 7 + 13
    assert raw[8:12] == bytes([0, 1, 1, 2])
    assert crc16(raw[:12]) == raw[12] | raw[13] << 8
    assert raw[14:18] == bytes([0x80, 2, 3, 4])
    assert crc16(raw[:-2]) == raw[-2] | raw[-1] << 8


def test_packet_reader_splits_and_skips_garbage():
    reader = PacketReader()
    stream = b"\x00\x13" + PING_BYTES + SYNC_WRITE_BYTES
    reader.feed(stream[:7])
    assert reader.packets() == []
    reader.feed(stream[7:20])
    assert reader.packets() == [PING_BYTES]
    reader.feed(stream[20:])
    assert reader.packets() == [SYNC_WRITE_BYTES]


def test_signed_decoding():
    assert to_signed(0xFFFF_FFFF, 4) == -1
    assert to_signed(0x8000_0000, 4) == -(2**31)
    assert to_signed(0x7FFF_FFFF, 4) == 2**31 - 1
    assert to_signed(0xFFFE, 2) == -2
    assert to_signed(0xFF, 1) == -1
    assert to_signed(2048, 4) == 2048
    with pytest.raises(ValueError, match="Expected `size` 1, 2 or 4 bytes, got 3"):
        to_signed(1, 3)
    with pytest.raises(ValueError, match=r"Expected `value` in 0..255, got 256"):
        to_signed(256, 1)


def test_signed_round_trip(rng):
    for size in (1, 2, 4):
        bits = 8 * size
        values = rng.integers(-(2 ** (bits - 1)), 2 ** (bits - 1), 50)
        for v in values.tolist():
            assert to_signed(to_unsigned(v, size), size) == v
    with pytest.raises(ValueError, match="Expected `value` to fit in 2 bytes, got 70000"):
        to_unsigned(70000, 2)


def test_layout_agrees_with_emanual_addresses():
    # e-Manual X-series control table (docs/dynamixel.md), same for the four models.
    expected = {
        Register.MODEL_NUMBER: (0, 2),
        Register.RETURN_DELAY_TIME: (9, 1),
        Register.OPERATING_MODE: (11, 1),
        Register.TORQUE_ENABLE: (64, 1),
        Register.HARDWARE_ERROR_STATUS: (70, 1),
        Register.BUS_WATCHDOG: (98, 1),
        Register.GOAL_POSITION: (116, 4),
        Register.PRESENT_CURRENT: (126, 2),
        Register.PRESENT_VELOCITY: (128, 4),
        Register.PRESENT_POSITION: (132, 4),
    }
    for model in MODELS.values():
        table = layout(model)
        for register, address in expected.items():
            assert table[register] == address, (model.name, register)


def test_models_and_names():
    assert model_named("XL430-W250").number == 1060
    assert model_named(" xl430-w250") is MODELS["XL430-W250"]
    assert model_numbered(1020) is MODELS["XM430-W350"]
    assert model_numbered(30) == "mx_28"
    assert model_numbered(9999) == "unknown"
    with pytest.raises(ValueError, match="unknown model 'XM999'"):
        model_named("XM999")


def test_current_conversion_round_trip():
    xm, xl = MODELS["XM430-W350"], MODELS["XL430-W250"]
    assert xm.current_a(100) == pytest.approx(0.269)
    assert xm.current_raw(0.269) == 100
    # XL430: Present Load in 0.1 % of stall current (1.4 A).
    assert xl.current_a(1000) == pytest.approx(1.4)
    assert xl.current_raw(-0.7) == -500


def test_describe_hardware_error():
    assert describe_hardware_error(0x20) == "overload"
    assert describe_hardware_error(0x24) == "overheating, overload"


def test_joint_map_default_formula():
    joints = JointMap()
    q = np.array([0.0, math.pi / 2, -math.pi])
    np.testing.assert_array_equal(joints.to_ticks(q), [2048, 3072, 0])
    np.testing.assert_allclose(joints.to_rad(joints.to_ticks(q)), q)


def test_joint_map_direction_and_zero(rng):
    joints = JointMap(ids=(4, 5, 6), directions=(1, -1, 1), zeros=(2048, 1000, 3000))
    q = rng.uniform(-3, 3, (20, 3))
    ticks = joints.to_ticks(q)
    np.testing.assert_array_equal(ticks[:, 1], 1000 - np.rint(q[:, 1] * 4096 / (2 * math.pi)))
    assert np.max(np.abs(joints.to_rad(ticks) - q)) <= 0.5 * 2 * math.pi / 4096 + 1e-12


def test_joint_map_rejects_bad_input():
    with pytest.raises(ValueError, match=r"Expected distinct `ids` in 0..252, got \(1, 1, 2\)"):
        JointMap(ids=(1, 1, 2))
    with pytest.raises(ValueError, match=r"Expected `directions` of \+1 or -1, got \(1, 2, 1\)"):
        JointMap(directions=(1, 2, 1))
    with pytest.raises(ValueError, match="one non-zero length, got 2, 3, 2"):
        JointMap(ids=(1, 2), directions=(1, 1, 1))
    two = JointMap(ids=(11, 12))  # directions and zeros default per id
    assert two.directions == (1, 1) and two.zeros == (2048, 2048)
    with pytest.raises(TypeError, match=r"Expected `ids\[0\]` to be an integer, got 1.0"):
        JointMap(ids=(1.0, 2, 3))
    with pytest.raises(ValueError, match=r"Expected `q_rad` of shape \(..., 3\), got \(2,\)"):
        JointMap().to_ticks(np.zeros(2))
    with pytest.raises(ValueError, match="Expected finite `q_rad`"):
        JointMap().to_ticks(np.array([0.0, np.nan, 0.0]))
