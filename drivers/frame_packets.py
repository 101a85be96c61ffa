"""The two packets of every stream frame, built and checked without the SDK.

A frame to ``n`` servos is one Sync Write of Goal Position and, when it reads
back, one Fast Sync Read of a register block. Through ``dynamixel-sdk`` both
are built byte by byte in Python lists, checksummed in a Python loop over every
byte and parsed by a header search per byte; that is most of the driver's cost
per frame (docs/realtime.md). Here each is laid out once for its servos and
registers:

- ``SyncWritePacket``: the header, LEN, instruction, address and size are
  fixed, and so is the CRC state after them; a frame packs only the ids and
  values (one ``struct`` call) and runs the CRC over those bytes. Byte
  stuffing is done where the data needs it (which the SDK's TX path drops).
- ``FastSyncReadPacket``: the request never changes (built once); its reply
  has one expected length, so it is read at once, and ``check`` trusts it only
  after the same checks as the SDK path and ``ServoBus`` made there: header,
  reserved byte, instruction, CRC, then the id (broadcast), the LEN field
  (the block asked), each part's id in request order; every servo's ERR byte
  is returned for the caller to judge. The values come out of one ``struct``
  unpack, signed where the register is signed.

The packet layout and CRC are those of ``drivers.protocol`` (Protocol 2.0,
ROBOTIS e-Manual); ``tests/test_frame_packets.py`` checks both packets byte
for byte against the SDK's and against ``protocol.encode``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

from .errors import BadArgument
from .protocol import BROADCAST_ID, HEADER, STUFF_MARK, Instruction, crc16, stuff

# Status packet layout (e-Manual, Protocol 2.0): ID at byte 4, LEN at 5..6, INST at 7.
_ID, _LEN, _INST = 4, 5, 7
_STATUS_HEAD = 8  # header 4, ID, LEN 2, INST: where a fast sync read's first part starts
_PART_EXTRA = 4  # ERR, ID, CRC 2 around each servo's data in a fast sync read reply
_UNSIGNED = {1: "B", 2: "H", 4: "I"}
_SIGNED = {1: "b", 2: "h", 4: "i"}


def sync_write_bytes(n_servos: int, size: int) -> int:
    """Bytes of a Sync Write of one ``size``-byte register to ``n_servos`` (unstuffed):
    header 4, ID, LEN 2, INST, address 2, size 2, CRC 2, and an id and the data per servo."""
    return 14 + n_servos * (1 + size)


class SyncWritePacket:
    """Sync Write of one register to fixed servos, laid out once.

    Parameters
    ----------
    address : int
        Register address.
    size : int
        Register size (bytes): 1, 2 or 4.
    ids : sequence of int
        Servos, in the order their values are given to ``encode``.

    Raises
    ------
    BadArgument
        If ``size`` is not 1, 2 or 4, or there is no servo.
    """

    def __init__(self, address: int, size: int, ids: Sequence[int]) -> None:
        if size not in _UNSIGNED:
            raise BadArgument(f"Expected `size` 1, 2 or 4 bytes, got {size}.")
        if not ids:
            raise BadArgument("Expected at least one servo id, got none.")
        self.ids = tuple(int(i) for i in ids)
        self.size = size
        n = len(self.ids)
        length = 3 + 4 + n * (1 + size)  # INST, address 2, size 2, params, CRC 2
        self._head = HEADER + bytes([BROADCAST_ID, length & 0xFF, length >> 8])
        self._body_head = bytes([Instruction.SYNC_WRITE]) + struct.pack("<HH", address, size)
        self._crc_head = crc16(self._head + self._body_head)
        self._prefix = self._head + self._body_head
        self._params = struct.Struct("<" + ("B" + _UNSIGNED[size]) * n)
        self._low, self._high = -(1 << (8 * size - 1)), (1 << (8 * size)) - 1
        self._wrap = 1 << (8 * size)

    def encode(self, values: Sequence[int]) -> bytes:
        """The packet for ``values`` (one per servo, in ``ids`` order), as it goes on the wire.

        Values are two's-complement encoded into ``size`` bytes (signed or
        unsigned values both fit, as ``drivers.units.to_unsigned``).

        Raises
        ------
        BadArgument
            If the number of values is not the number of servos, or a value
            does not fit ``size`` bytes.
        """
        if len(values) != len(self.ids):
            raise BadArgument(f"Expected {len(self.ids)} values, got {len(values)}.")
        flat = []
        low, high, wrap = self._low, self._high, self._wrap
        for servo_id, value in zip(self.ids, values, strict=True):
            value = int(value)
            if not low <= value <= high:
                raise BadArgument(f"Expected `value` in {low}..{high}, got {value}.")
            flat.append(servo_id)
            flat.append(value + wrap if value < 0 else value)
        params = self._params.pack(*flat)
        if STUFF_MARK in params:
            return self._stuffed(params)
        crc = crc16(params, self._crc_head)
        return self._prefix + params + bytes((crc & 0xFF, crc >> 8))

    def _stuffed(self, params: bytes) -> bytes:
        """The packet when its data holds ``FF FF FD``: stuffed, LEN counted after stuffing."""
        body = stuff(self._body_head + params)
        length = len(body) + 2
        packet = HEADER + bytes([BROADCAST_ID, length & 0xFF, length >> 8]) + body
        crc = crc16(packet)
        return packet + bytes((crc & 0xFF, crc >> 8))


class FastSyncReadPacket:
    """Fast Sync Read of one register block from fixed servos: the request, and its reply's checks.

    Parameters
    ----------
    start : int
        First address of the block.
    fields : sequence of (int, int, bool)
        The registers to decode: (address, size in bytes, signed), inside the
        block.
    length : int
        Block length (bytes) from ``start``.
    ids : sequence of int
        Servos, answering in this order.

    Attributes
    ----------
    request : bytes
        The request packet (never changes).
    reply_bytes : int
        The length of a sound reply, header to CRC.
    length_field : int
        Its LEN field: INST + (ERR, ID, data, CRC 2) per servo.
    """

    def __init__(
        self, start: int, fields: Sequence[tuple[int, int, bool]], length: int, ids: Sequence[int]
    ) -> None:
        if not ids:
            raise BadArgument("Expected at least one servo id, got none.")
        self.ids = tuple(int(i) for i in ids)
        self.length = length
        params = struct.pack("<HH", start, length) + bytes(self.ids)
        body = bytes([Instruction.FAST_SYNC_READ]) + params
        request_length = len(body) + 2
        packet = HEADER + bytes([BROADCAST_ID, request_length & 0xFF, request_length >> 8]) + body
        crc = crc16(packet)
        self.request = packet + bytes((crc & 0xFF, crc >> 8))
        self._part = length + _PART_EXTRA
        self.length_field = 1 + self._part * len(self.ids)
        self.reply_bytes = 7 + self.length_field
        # One unpack of the whole reply: per servo ERR, ID, then each field.
        layout = ["<", "x" * _STATUS_HEAD]
        for _ in self.ids:
            at = 0
            layout.append("BB")
            for address, size, signed in sorted(fields):
                offset = address - start
                if offset < at or offset + size > length or size not in _UNSIGNED:
                    raise BadArgument(
                        f"Expected fields inside the block {start}..{start + length - 1} "
                        f"without overlap, got address {address} size {size}."
                    )
                layout.append("x" * (offset - at) + (_SIGNED if signed else _UNSIGNED)[size])
                at = offset + size
            layout.append("x" * (length - at) + "xx")
        by_address = sorted(range(len(fields)), key=lambda i: fields[i][0])
        self._perm = [by_address.index(i) for i in range(len(fields))]
        self._n_fields = len(fields)
        self._reply = struct.Struct("".join(layout))

    def check(self, packet: bytes) -> tuple[str | None, tuple[int, ...], list[list[int]]]:
        """Check one status packet (header to CRC, as framed by ``frame_status``) and decode it.

        Returns
        -------
        problem : str or None
            None when every check passed; else what arrived against what was
            asked (a reply from another id or of another length).
        errors : tuple of int
            Each servo's ERR byte, in ``ids`` order (empty when ``problem``).
        values : list of list of int
            Per servo (``ids`` order), the fields' values in the order the
            fields were given (empty when ``problem``).
        """
        if packet[_ID] != BROADCAST_ID:
            return f"reply from id {packet[_ID]}, expected {BROADCAST_ID}", (), []
        length = packet[_LEN] | packet[_LEN + 1] << 8
        if length != self.length_field or len(packet) != self.reply_bytes:
            return f"reply of length {length} (LEN field), expected {self.length_field}", (), []
        flat = self._reply.unpack(packet)
        stride = 2 + self._n_fields
        errors, values = [], []
        perm = self._perm
        for k, servo_id in enumerate(self.ids):
            row = flat[k * stride : (k + 1) * stride]
            if row[1] != servo_id:
                return f"reply part {k} from id {row[1]}, expected {servo_id}", (), []
            errors.append(row[0])
            values.append([row[2 + p] for p in perm])
        return None, tuple(errors), values


def frame_status(buffer: bytearray, max_length: int) -> tuple[str, int]:
    """Find one status packet at the start of ``buffer``, as the SDK's receive loop does.

    Garbage before a header is dropped from ``buffer`` (in place), and so is a
    header whose reserved byte, instruction (not STATUS) or LEN (above
    ``max_length``) cannot be a status packet's.

    Parameters
    ----------
    buffer : bytearray
        Bytes received so far; trimmed in place to start at the packet.
    max_length : int
        Largest LEN accepted (the SDK's ``RXPACKET_MAX_LEN``).

    Returns
    -------
    state : {"more", "crc", "ok"}
        "more": fewer bytes than the packet needs (the second value says how
        many in all); "crc": a whole packet whose CRC is wrong; "ok": a whole
        packet with a sound CRC.
    total : int
        Bytes of the packet (header to CRC); at least 11 while unknown.
    """
    while True:
        start = buffer.find(STUFF_MARK)
        if start < 0:
            del buffer[: max(0, len(buffer) - 2)]  # keep a possible partial header
            return "more", 11
        del buffer[:start]
        if len(buffer) < 11:
            return "more", 11
        length = buffer[_LEN] | buffer[_LEN + 1] << 8
        if (
            buffer[3] != 0
            or buffer[_ID] > BROADCAST_ID
            or buffer[_INST] != Instruction.STATUS
            or length > max_length
        ):
            del buffer[0]
            continue
        total = 7 + length
        if len(buffer) < total:
            return "more", total
        crc = buffer[total - 2] | buffer[total - 1] << 8
        return ("ok" if crc16(buffer[: total - 2]) == crc else "crc"), total
