"""Dynamixel Protocol 2.0 packets: CRC, byte stuffing, encoding and decoding.

The driver sends packets through ``dynamixel-sdk``; this module is the second,
independent implementation used by the virtual servo bus and by tests.

Packet layout: ``FF FF FD 00 | ID | LEN_L LEN_H | INST | params | CRC_L CRC_H``,
where LEN counts INST + params + CRC. Inside INST..params every ``FF FF FD``
is followed by an extra ``FD`` (byte stuffing). A status packet has INST
``0x55`` and its first parameter is the ERR byte.

References: ROBOTIS e-Manual, "DYNAMIXEL Protocol 2.0".
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from .errors import BadArgument, PacketError

HEADER = b"\xff\xff\xfd\x00"
STUFF_MARK = HEADER[:3]  # what byte stuffing follows with an extra FD
BROADCAST_ID = 0xFE
_MIN_LENGTH = 3  # INST + CRC


class Instruction(IntEnum):
    """Protocol 2.0 instruction codes."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class StatusError(IntEnum):
    """Low 7 bits of a status packet's ERR byte (bit 7 is the Alert flag)."""

    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


ALERT_BIT = 0x80


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16 of Protocol 2.0 (polynomial 0x8005, initial value 0, not reflected).

    Parameters
    ----------
    data : bytes
        Bytes to checksum (everything before the CRC field).
    crc : int, optional
        Running value to continue from.

    Returns
    -------
    int
        The CRC, 0..65535.
    """
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert an ``FD`` after every ``FF FF FD`` in ``body`` (INST + params)."""
    if STUFF_MARK not in body:
        return bytes(body)
    out = bytearray()
    for byte in body:
        out.append(byte)
        if byte == 0xFD and out[-3:-1] == b"\xff\xff" and len(out) >= 3:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the ``FD`` that follows every ``FF FF FD`` in ``body``."""
    if STUFF_MARK not in body:
        return bytes(body)
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        stuffed = body[i + 1 : i + 2] == b"\xfd" and out[-3:] == b"\xff\xff\xfd"
        i += 2 if stuffed else 1
    return bytes(out)


def encode(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """Build a packet with byte stuffing and CRC.

    Parameters
    ----------
    servo_id : int
        0..253, or ``BROADCAST_ID`` (254).
    instruction : int
        Instruction code (``Instruction``).
    params : bytes
        Parameters, unstuffed (for a status packet, ERR byte first).

    Returns
    -------
    bytes
        The packet as it goes on the wire.

    Raises
    ------
    ValueError
        If ``servo_id`` is out of range.
    """
    if not 0 <= servo_id <= BROADCAST_ID:
        raise BadArgument(f"Expected `servo_id` in 0..254, got {servo_id}.")
    body = stuff(bytes([instruction]) + bytes(params))
    length = len(body) + 2
    packet = HEADER + bytes([servo_id, length & 0xFF, length >> 8]) + body
    crc = crc16(packet)
    return packet + bytes([crc & 0xFF, crc >> 8])


def encode_status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    """Build a status packet (INST 0x55) with ERR byte ``error``."""
    return encode(servo_id, Instruction.STATUS, bytes([error]) + bytes(params))


def encode_fast_sync_status(entries: list[tuple[int, int, bytes]]) -> bytes:
    """Build the single status packet that answers a Fast Sync Read or Fast Bulk Read.

    Parameters
    ----------
    entries : list of (error, servo_id, data)
        One per servo, in request order.

    Returns
    -------
    bytes
        ``FF FF FD 00 FE LEN 55`` then ``ERR ID DATA CRC2`` per servo, where each
        CRC2 is the running CRC of the packet so far and the last one is the
        packet's CRC. Not byte-stuffed (as the e-Manual specifies).
    """
    length = 1 + sum(len(data) + 4 for _, _, data in entries)
    packet = bytearray(HEADER + bytes([BROADCAST_ID, length & 0xFF, length >> 8, 0x55]))
    crc = crc16(packet)
    for error, servo_id, data in entries:
        part = bytes([error, servo_id]) + bytes(data)
        crc = crc16(part, crc)  # the running CRC of the packet so far
        packet += part
        check = bytes([crc & 0xFF, crc >> 8])
        crc = crc16(check, crc)
        packet += check
    return bytes(packet)


@dataclass(frozen=True)
class Packet:
    """A decoded packet.

    Attributes
    ----------
    servo_id : int
        ID field.
    instruction : int
        INST field.
    params : bytes
        Parameters with stuffing removed (ERR first for a status packet).
    """

    servo_id: int
    instruction: int
    params: bytes


def decode(packet: bytes) -> Packet:
    """Decode one complete packet.

    Parameters
    ----------
    packet : bytes
        Exactly one packet, header to CRC.

    Returns
    -------
    Packet

    Raises
    ------
    PacketError
        If the header, length or CRC is wrong.
    """
    packet = bytes(packet)
    if packet[:4] != HEADER:
        raise PacketError(f"bad header {packet[:4].hex(' ')}")
    if len(packet) < 10:
        raise PacketError(f"packet too short ({len(packet)} bytes)")
    length = packet[5] | packet[6] << 8
    if length < _MIN_LENGTH or len(packet) != 7 + length:
        raise PacketError(f"length field {length} does not match {len(packet)} bytes")
    crc = packet[-2] | packet[-1] << 8
    if crc16(packet[:-2]) != crc:
        raise PacketError(f"CRC {crc:#06x} != computed {crc16(packet[:-2]):#06x}")
    body = unstuff(packet[7:-2])
    return Packet(packet[4], body[0], body[1:])


class PacketReader:
    """Incremental splitter of a byte stream into packets (for the virtual bus).

    ``feed`` bytes as they arrive; ``packets`` yields each complete packet's
    raw bytes. Garbage before a header is skipped.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> None:
        """Append received bytes."""
        self._buffer += data

    def packets(self) -> list[bytes]:
        """Complete packets found so far (raw bytes), removed from the buffer."""
        found = []
        while True:
            start = self._buffer.find(HEADER)
            if start < 0:
                # Keep a possible partial header at the end.
                del self._buffer[: max(0, len(self._buffer) - 3)]
                return found
            del self._buffer[:start]
            if len(self._buffer) < 7:
                return found
            total = 7 + (self._buffer[5] | self._buffer[6] << 8)
            if len(self._buffer) < total:
                return found
            found.append(bytes(self._buffer[:total]))
            del self._buffer[:total]


def word(params: bytes, k: int) -> int:
    """The little-endian 16-bit word at ``params[k]``."""
    return params[k] | params[k + 1] << 8
