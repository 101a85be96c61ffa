"""The stream frame's own packets (drivers.frame_packets) against the SDK and drivers.protocol."""

from __future__ import annotations

import numpy as np
import pytest
from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

from trajgen.drivers.errors import BadArgument
from trajgen.drivers.frame_packets import FastSyncReadPacket, SyncWritePacket, frame_status
from trajgen.drivers.protocol import (
    BROADCAST_ID,
    Instruction,
    decode,
    encode,
    encode_fast_sync_status,
    encode_status,
)

IDS = (1, 2, 3)
# Present Current (2, signed), Present Velocity (4, signed), Present Position (4, signed).
FIELDS = [(126, 2, True), (128, 4, True), (132, 4, True)]


class _RecordingPort:
    """Just enough of an SDK PortHandler to capture what a packet handler writes."""

    is_using = False

    def __init__(self) -> None:
        self.written = b""

    def clearPort(self):  # noqa: N802 (SDK name)
        pass

    def writePort(self, packet):  # noqa: N802 (SDK name)
        self.written = bytes(packet)
        return len(packet)

    def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK name)
        pass


def _sdk_sync_write(address, size, values: dict[int, int]) -> bytes:
    param = []
    for servo_id, value in values.items():
        param.append(servo_id)
        param.extend((value % (1 << (8 * size))).to_bytes(size, "little"))
    port = _RecordingPort()
    Protocol2PacketHandler().syncWriteTxOnly(port, address, size, param, len(param))
    return port.written


def test_sync_write_is_the_packet_captured_from_the_sdk():
    # docs/dynamixel.md: Goal Position 2048, 1024, -4096 to ids 1, 2, 3.
    captured = bytes.fromhex(
        "FF FF FD 00 FE 16 00 83 74 00 04 00 01 00 08 00 00 02 00 04 00 00 03 00 F0 FF FF 3E 87"
    )
    assert SyncWritePacket(116, 4, IDS).encode([2048, 1024, -4096]) == captured


@pytest.mark.parametrize("size", [1, 2, 4])
def test_sync_write_equals_the_sdk_byte_for_byte(size):
    rng = np.random.default_rng(7)
    ids = (1, 4, 9, 200)
    packet = SyncWritePacket(116, size, ids)
    for _ in range(200):
        values = [int(v) for v in rng.integers(0, 1 << (8 * size), size=len(ids))]
        values = [v for v in values if b"\xff\xff\xfd" not in v.to_bytes(size, "little")]
        if len(values) < len(ids):
            continue
        assert packet.encode(values) == _sdk_sync_write(
            116, size, dict(zip(ids, values, strict=True))
        )


def test_sync_write_is_byte_stuffed_where_its_data_holds_the_header():
    # 0xFFFDFFFF: bytes FF FF FD FF; the SDK's TX path would send it unstuffed.
    value = 0xFFFDFFFF - (1 << 32)
    packet = SyncWritePacket(116, 4, (1, 2)).encode([value, 7])
    params = (
        bytes([116, 0, 4, 0, 1]) + (value % (1 << 32)).to_bytes(4, "little") + b"\x02\x07\0\0\0"
    )
    assert packet == encode(BROADCAST_ID, Instruction.SYNC_WRITE, params)
    assert b"\xff\xff\xfd\xfd" in packet
    assert decode(packet).params == params


def test_sync_write_refuses_values_that_do_not_fit():
    packet = SyncWritePacket(116, 2, IDS)
    with pytest.raises(BadArgument, match=r"Expected `value` in -32768\.\.65535, got 65536"):
        packet.encode([0, 65536, 0])
    with pytest.raises(BadArgument, match="Expected 3 values, got 2"):
        packet.encode([0, 1])
    with pytest.raises(BadArgument, match="Expected `size` 1, 2 or 4 bytes, got 3"):
        SyncWritePacket(116, 3, IDS)


def test_fast_sync_read_request_equals_the_sdk():
    port = _RecordingPort()
    Protocol2PacketHandler().syncReadTx(port, 126, 10, list(IDS), len(IDS), True)
    spec = FastSyncReadPacket(126, FIELDS, 10, IDS)
    assert spec.request == port.written
    assert spec.reply_bytes == 7 + 1 + 3 * 14 == 50


def _reply(entries):
    return encode_fast_sync_status(entries)


def _data(current, velocity, position):
    return (
        current.to_bytes(2, "little", signed=True)
        + velocity.to_bytes(4, "little", signed=True)
        + position.to_bytes(4, "little", signed=True)
    )


def test_fast_sync_read_decodes_signed_values_in_the_order_asked():
    # Fields asked out of address order: position, current, velocity.
    fields = [FIELDS[2], FIELDS[0], FIELDS[1]]
    spec = FastSyncReadPacket(126, fields, 10, IDS)
    reply = _reply(
        [(0, 1, _data(-5, 300, 2048)), (0x80, 2, _data(7, -2, -10)), (0, 3, _data(0, 0, 1 << 20))]
    )
    problem, errors, values = spec.check(reply)
    assert problem is None
    assert errors == (0, 0x80, 0)
    assert values == [[2048, -5, 300], [-10, 7, -2], [1 << 20, 0, 0]]


def test_fast_sync_read_reply_is_refused_unless_every_part_is_what_was_asked():
    spec = FastSyncReadPacket(126, FIELDS, 10, IDS)
    good = [(0, i, _data(0, 0, 2048)) for i in IDS]
    swapped = [good[0], good[2], good[1]]
    assert spec.check(_reply(swapped))[0] == "reply part 1 from id 3, expected 2"
    short = [good[0], (0, 2, _data(0, 0, 2048)[:8]), good[2]]
    assert spec.check(_reply(short))[0] == "reply of length 41 (LEN field), expected 43"
    unicast = encode_status(1, 0, bytes(41))  # same length, one servo's status packet
    assert spec.check(unicast)[0] == "reply from id 1, expected 254"
    assert spec.check(_reply(good))[0] is None


def test_frame_status_finds_the_packet_as_the_sdk_does():
    reply = _reply([(0, i, _data(0, 0, 2048)) for i in IDS])
    # Garbage, then a header that is not a status packet (instruction PING), then the reply.
    ping = encode(1, Instruction.PING)
    buffer = bytearray(b"\x00\xff\x12" + ping + reply)
    assert frame_status(buffer, 1024) == ("ok", len(reply))
    assert bytes(buffer) == reply
    part = bytearray(reply[:20])
    assert frame_status(part, 1024) == ("more", len(reply))
    assert frame_status(bytearray(reply[:9]), 1024) == ("more", 11)
    corrupt = bytearray(reply[:-1] + bytes([reply[-1] ^ 0xFF]))
    assert frame_status(corrupt, 1024) == ("crc", len(reply))
    too_long = bytearray(reply)
    too_long[5:7] = (2000).to_bytes(2, "little")
    assert frame_status(too_long, 1024) == ("more", 11)
