"""Failures injected into the virtual bus: bad replies, servo events after a frame.

``Fault`` says what fails and when; ``FaultInjection`` (a part of
``VirtualBus``) applies the faults to replies and after Goal Position sync
writes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from trajgen.drivers.protocol import (
    BROADCAST_ID,
    Instruction,
    decode,
    encode_fast_sync_status,
    encode_status,
    word,
)
from trajgen.servo_table import hardware_error_mask

from ..errors import BadArgument

_OVERLOAD_BIT = hardware_error_mask("overload")
# Faults that change replies, and faults that happen to a servo after a frame.
_REPLY_FAULTS = ("drop", "corrupt", "delay", "late", "short", "wrong_id", "glitch")
_FRAME_FAULTS = ("close", "overload", "watchdog", "reboot", "set")
# Present Position's address on every X-series model (for the glitch fault).
_PRESENT_POSITION_ADDRESS = 132


@dataclass(frozen=True)
class Fault:
    """A failure injected into the virtual bus.

    Attributes
    ----------
    kind : {"drop", "corrupt", "delay", "late", "short", "wrong_id", "glitch", "close", \
"overload", "watchdog", "reboot", "set"}
        drop: replies are not sent. corrupt: replies get a wrong CRC. delay:
        replies come ``delay_s`` late (off the wire: the bus is free meanwhile).
        late: the servo starts its reply ``delay_s`` after its Return Delay
        Time (on the wire: with ``WireTiming``, a host packet sent meanwhile
        collides with it). short: servo ``servo_id``'s reply
        loses ``n_bytes`` data bytes but stays well formed (valid CRC; in a
        fast sync read, its part of the one packet). wrong_id: servo
        ``servo_id``'s reply carries id ``reply_id`` (valid CRC). close: the
        pty master closes (the port goes away). overload: servo ``servo_id``
        latches hardware error bit 5 (torque off, since the default Shutdown
        covers it). watchdog: servo ``servo_id``'s Bus Watchdog trips.
        glitch: servo ``servo_id``'s Present Position replies read
        ``offset_ticks`` off (valid CRC; its part of a group read too).
        reboot: servo ``servo_id`` reboots (RAM to its initial values, torque
        off) and answers again at once. set: servo ``servo_id``'s register
        ``register`` takes ``value`` (e.g. Present Temperature 78).
    at_frame : int
        Number of Goal Position sync writes received before the fault starts.
    servo_id : int or None
        The servo affected (required for short, wrong_id, overload and
        watchdog); None means every servo's replies.
    count : int or None
        How many replies drop / corrupt / delay / late / short / wrong_id affect;
        None: all from then on.
    delay_s : float
        Extra delay (s) for ``kind="delay"`` and ``kind="late"``.
    n_bytes : int or None
        Data bytes a short reply loses; None: all of them (an empty reply).
    reply_id : int or None
        The id a wrong_id reply carries; None: ``servo_id + 1``.
    offset_ticks : int
        How far a glitch reply is off (ticks).
    register : str or None
        The register a set fault writes.
    value : int
        The value a set fault writes.
    address : int or None
        Only replies to reads (READ, SYNC_READ, FAST_SYNC_READ) of this start
        address are affected; None: any reply. (short and wrong_id leave fast
        bulk read replies alone.)
    """

    kind: Literal[
        "drop",
        "corrupt",
        "delay",
        "late",
        "short",
        "wrong_id",
        "glitch",
        "close",
        "overload",
        "watchdog",
        "reboot",
        "set",
    ]
    at_frame: int = 0
    servo_id: int | None = None
    count: int | None = None
    delay_s: float = 0.0
    n_bytes: int | None = None
    reply_id: int | None = None
    address: int | None = None
    offset_ticks: int = 0
    register: str | None = None
    value: int = 0

    def __post_init__(self) -> None:
        kinds = _REPLY_FAULTS + _FRAME_FAULTS
        if self.kind not in kinds:
            raise BadArgument(f"Expected `kind` in {kinds}, got {self.kind!r}.")
        if self.kind not in ("drop", "corrupt", "delay", "late", "close") and self.servo_id is None:
            raise BadArgument(f"Expected a `servo_id` for a {self.kind} fault, got None.")


class FaultInjection:
    """The faults of a ``VirtualBus`` (its ``_faults``, ``servos``, plant and frames)."""

    def _active(self, kinds: tuple[str, ...]):
        for entry in self._faults:
            fault, remaining = entry
            if fault.kind in kinds and self.frames_received >= fault.at_frame:
                yield entry

    def _after_frame(self) -> list | None:
        """Apply faults that start at this frame; None to close the port."""
        for entry in list(self._active(_FRAME_FAULTS)):
            fault = entry[0]
            self._faults.remove(entry)
            if fault.kind == "close":
                return None
            if fault.kind == "reboot":
                self.servos[fault.servo_id].reboot(self._plant_ticks(fault.servo_id))
                self._after_reset(fault.servo_id)
            elif fault.kind == "set":
                self.servos[fault.servo_id].set(fault.register, fault.value)
            elif fault.kind == "overload":
                j = self._joint[fault.servo_id]
                self.servos[fault.servo_id].raise_hardware_error(_OVERLOAD_BIT)
                self.plant.set_torque_enabled(j, self.servos[fault.servo_id].torque_on)
            else:
                self._trip_watchdog(fault.servo_id)
        return []

    def _apply_reply_faults(self, replies: list, request) -> list[tuple[int, bytes, float, float]]:
        """Replies as sent: [(servo id, bytes, extra delay off the wire (s), late on it (s))]."""
        inst = request.instruction
        reads = (Instruction.READ, Instruction.SYNC_READ, Instruction.FAST_SYNC_READ)
        address = word(request.params, 0) if inst in reads and len(request.params) >= 2 else None
        reshapable = inst != Instruction.FAST_BULK_READ
        out = []
        for reply in replies:
            servo_id, data = reply[0], reply[1]
            # A fast read reply carries every servo in it.
            members = reply[2] if len(reply) == 3 else [servo_id]
            extra_s = late_s = 0.0
            dropped = False
            for entry in self._active(_REPLY_FAULTS):
                fault, remaining = entry
                if fault.servo_id is not None and fault.servo_id not in members:
                    continue
                if fault.address is not None and fault.address != address:
                    continue
                if fault.kind in ("short", "wrong_id", "glitch") and not reshapable:
                    continue
                if remaining is not None:
                    if remaining <= 0:
                        continue
                    entry[1] = remaining - 1
                if fault.kind == "drop":
                    dropped = True
                elif fault.kind == "corrupt":
                    data = data[:-1] + bytes([data[-1] ^ 0xFF])
                elif fault.kind in ("short", "wrong_id", "glitch"):
                    data = _reshape_reply(data, members, fault, address)
                elif fault.kind == "late":
                    late_s += fault.delay_s
                else:
                    extra_s += fault.delay_s
            if not dropped:
                out.append((servo_id, data, extra_s, late_s))
        return out


def _reshape_reply(
    reply: bytes, members: Sequence[int], fault: Fault, address: int | None
) -> bytes:
    """A well-formed reply (valid CRC) with ``fault.servo_id``'s part short, re-addressed,
    or (a read from ``address``) its Present Position off by ``fault.offset_ticks``.

    ``reply`` is a status packet, or a fast sync read reply whose parts are
    ``ERR ID DATA CRC2`` for ``members`` in order, all of one data size.
    """
    packet = decode(reply)
    reply_id = fault.servo_id + 1 if fault.reply_id is None else fault.reply_id

    def reshaped(servo_id: int, error: int, data: bytes) -> tuple[int, int, bytes]:
        if fault.kind == "wrong_id":
            return reply_id, error, data
        if fault.kind == "glitch":
            return servo_id, error, _glitched(data, address, fault.offset_ticks)
        keep = 0 if fault.n_bytes is None else max(0, len(data) - fault.n_bytes)
        return servo_id, error, data[:keep]

    if packet.servo_id != BROADCAST_ID:  # one servo's status packet
        servo_id, error, data = reshaped(packet.servo_id, packet.params[0], packet.params[1:])
        return encode_status(servo_id, error, data)
    body = reply[8:]  # after INST: every part, the last CRC2 included
    size = len(body) // len(members) - 4
    entries = []
    for k, member in enumerate(members):
        part = body[k * (size + 4) : (k + 1) * (size + 4)]
        servo_id, error, data = part[1], part[0], part[2 : 2 + size]
        if member == fault.servo_id:
            servo_id, error, data = reshaped(servo_id, error, data)
        entries.append((error, servo_id, data))
    return encode_fast_sync_status(entries)


def _glitched(data: bytes, address: int | None, offset_ticks: int) -> bytes:
    """``data`` read from ``address`` with Present Position (132, 4 bytes) moved by the offset."""
    k = None if address is None else _PRESENT_POSITION_ADDRESS - address
    if k is None or not 0 <= k <= len(data) - 4:
        return data
    value = int.from_bytes(data[k : k + 4], "little", signed=True) + offset_ticks
    return data[:k] + value.to_bytes(4, "little", signed=True) + data[k + 4 :]
