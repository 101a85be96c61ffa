"""The virtual bus's instruction handlers: what each servo answers to each instruction.

``InstructionHandlers`` (a part of ``VirtualBus``) holds the 14 Protocol 2.0
instructions the bus answers, how packets are addressed (ID, Secondary ID,
broadcast; two servos on one id collide) and which Status Return Level
answers what.
"""

from __future__ import annotations

import functools
import itertools
import operator

import numpy as np

from trajgen.drivers.protocol import (
    ALERT_BIT,
    BROADCAST_ID,
    Instruction,
    StatusError,
    encode_fast_sync_status,
    encode_status,
    word,
)
from trajgen.drivers.units import rad_to_servo_ticks
from trajgen.drivers.virtual.servo import FACTORY_RESET_KEEPS

SECONDARY_ID = "Secondary(Shadow) ID"
# CLEAR's fixed parameters after the option byte 0x01 (multi-turn clear).
_CLEAR_PARAMS = bytes([0x01, 0x44, 0x58, 0x4C, 0x22])
# Status Return Level (68): which instructions get a status packet.
_ANSWERED_AT_LEVEL = {
    0: {Instruction.PING},
    1: {
        Instruction.PING,
        Instruction.READ,
        Instruction.SYNC_READ,
        Instruction.FAST_SYNC_READ,
        Instruction.BULK_READ,
        Instruction.FAST_BULK_READ,
    },
}


class InstructionHandlers:
    """Instruction handlers of a ``VirtualBus`` (its ``servos``, plant, goals)."""

    def _addressed(self, servo_id: int, *, acting: bool = False) -> list[int]:
        """The servos (by power-up id) whose ID register is ``servo_id``, or all on broadcast.

        ``acting``: also those whose Secondary ID is ``servo_id`` (a servo acts
        on a packet to its Secondary ID, and never answers it).
        """
        if servo_id == BROADCAST_ID:
            return list(self.ids)
        found = self._by_id.get(servo_id, [])
        if acting:
            found = found + [i for i in self._by_secondary.get(servo_id, []) if i not in found]
        return found

    def _index_ids(self) -> None:
        """Re-read every ID and Secondary ID register (after a write, a reset)."""
        self._by_id: dict[int, list[int]] = {}
        self._by_secondary: dict[int, list[int]] = {}
        for i in self.ids:
            self._by_id.setdefault(self.servos[i].servo_id, []).append(i)
            secondary = self.servos[i].get(SECONDARY_ID)
            if secondary < BROADCAST_ID:
                self._by_secondary.setdefault(secondary, []).append(i)

    def _status(self, servo_id: int, error: int, data: bytes = b"") -> bytes:
        servo = self.servos[servo_id]
        if servo.alert:
            error |= ALERT_BIT
        return encode_status(servo.servo_id, error, data)

    def _answers(self, servo_id: int, instruction: int) -> bool:
        """Whether Status Return Level lets a servo answer ``instruction``."""
        level = self.servos[servo_id].get("Status Return Level")
        return level >= 2 or instruction in _ANSWERED_AT_LEVEL[level]

    def _unicast_replies(self, packet_id: int, instruction: int, answer) -> list[tuple[int, bytes]]:
        """Run ``answer(servo id) -> (error, data)`` per servo addressed; reply unless broadcast.

        Servos acting on their Secondary ID do not reply; two servos sharing
        the id both reply at once, and their bytes collide on the wire (a
        wired AND: a 0 bit wins), so the host reads one garbled packet.
        """
        replies = []
        for servo_id in self._addressed(packet_id, acting=True):
            error, data = answer(servo_id)
            primary = self.servos[servo_id].servo_id == packet_id
            if primary and self._answers(servo_id, instruction):
                replies.append((servo_id, self._status(servo_id, error, data)))
        if len(replies) > 1:
            packets = [reply for _, reply in replies]
            collided = bytes(
                functools.reduce(operator.and_, column)
                for column in itertools.zip_longest(*packets, fillvalue=0xFF)
            )
            return [(replies[0][0], collided)]
        return replies

    # -- instructions ----------------------------------------------------------

    def _unknown(self, packet_id: int, params: bytes) -> list:
        if packet_id == BROADCAST_ID:
            return []
        return [(i, self._status(i, StatusError.INSTRUCTION)) for i in self._addressed(packet_id)]

    def _ping(self, packet_id: int, params: bytes) -> list:
        def answer(servo_id):
            servo = self.servos[servo_id]
            number = servo.get("Model Number")
            return 0, bytes([number & 0xFF, number >> 8, servo.get("Firmware Version")])

        targets = self._addressed(packet_id)
        return [(i, self._status(i, *answer(i))) for i in targets]

    def _read_one(self, servo_id: int, address: int, length: int) -> tuple[int, bytes]:
        servo = self.servos[servo_id]
        self._refresh_present(poll=self._reads_present(servo, address, length))
        return servo.read(address, length)

    def _read(self, packet_id: int, params: bytes) -> list:
        if packet_id == BROADCAST_ID:
            return []
        if len(params) != 4:
            return self._unicast_replies(
                packet_id, Instruction.READ, lambda i: (StatusError.DATA_LENGTH, b"")
            )
        address, length = word(params, 0), word(params, 2)
        return self._unicast_replies(
            packet_id, Instruction.READ, lambda i: self._read_one(i, address, length)
        )

    def _write_one(self, servo_id: int, address: int, data: bytes) -> int:
        """WRITE to one servo: its status error (0: written and passed to the plant).

        A write the plant does not simulate (it raises one of ``unsupported``)
        is undone and refused with Result Fail; ``on_refusal`` hears why.
        """
        servo = self.servos[servo_id]
        before = bytes(servo.memory)
        error, names = servo.write(address, data)
        if error:
            return error
        try:
            self._written(servo_id, names)
        except self.unsupported as e:
            servo.memory[:] = before
            if self.on_refusal is not None:
                self.on_refusal(servo_id, str(e))
            return StatusError.RESULT_FAIL
        return 0

    def _write_instruction(self, packet_id: int, params: bytes) -> list:
        if len(params) < 3:
            return self._unicast_replies(
                packet_id, Instruction.WRITE, lambda i: (StatusError.DATA_LENGTH, b"")
            )
        address = word(params, 0)
        return self._unicast_replies(
            packet_id, Instruction.WRITE, lambda i: (self._write_one(i, address, params[2:]), b"")
        )

    def _reg_write(self, packet_id: int, params: bytes) -> list:
        def answer(servo_id):
            servo = self.servos[servo_id]
            if len(params) < 3:
                return StatusError.DATA_LENGTH, b""
            error = servo.check_write(word(params, 0), params[2:])[0]
            if not error:
                servo.pending = (word(params, 0), bytes(params[2:]))
                servo.set("Registered Instruction", 1)
            return error, b""

        return self._unicast_replies(packet_id, Instruction.REG_WRITE, answer)

    def _action(self, packet_id: int, params: bytes) -> list:
        def answer(servo_id):
            servo = self.servos[servo_id]
            if servo.pending is None:
                return StatusError.INSTRUCTION, b""
            (address, data), servo.pending = servo.pending, None
            servo.set("Registered Instruction", 0)
            return self._write_one(servo_id, address, data), b""

        return self._unicast_replies(packet_id, Instruction.ACTION, answer)

    def _plant_ticks(self, servo_id: int) -> int:
        return int(rad_to_servo_ticks(self.plant.read()[0][self._joint[servo_id]]))

    def _after_reset(self, servo_id: int) -> None:
        """A servo rebooted: the plant follows its registers (torque off, goal = present)."""
        servo = self.servos[servo_id]
        j = self._joint[servo_id]
        self._index_ids()
        self.plant.set_torque_enabled(j, False)
        self.plant.set_control(j, self._control(servo))
        self._goal_ticks.pop(j, None)
        self._goal_rad[j] = self._goal_for_plant(servo)
        self._goal_written = True

    def _reboot(self, packet_id: int, params: bytes) -> list:
        replies = self._unicast_replies(packet_id, Instruction.REBOOT, lambda i: (0, b""))
        for servo_id in self._addressed(packet_id, acting=True):  # after the reply, as a servo does
            self.servos[servo_id].reboot(self._plant_ticks(servo_id))
            self._after_reset(servo_id)
        return replies

    def _factory_reset(self, packet_id: int, params: bytes) -> list:
        option = params[0] if len(params) == 1 else None
        if option == 0xFF and packet_id == BROADCAST_ID:
            return []  # firmware 42 and later ignore a broadcast reset of the ID
        if option not in FACTORY_RESET_KEEPS:
            error = StatusError.DATA_LENGTH if len(params) != 1 else StatusError.DATA_RANGE
            return self._unicast_replies(
                packet_id, Instruction.FACTORY_RESET, lambda i: (error, b"")
            )
        replies = self._unicast_replies(packet_id, Instruction.FACTORY_RESET, lambda i: (0, b""))
        for servo_id in self._addressed(packet_id):
            self.servos[servo_id].factory_reset(option, self._plant_ticks(servo_id))
            self._after_reset(servo_id)
        return replies

    def _clear(self, packet_id: int, params: bytes) -> list:
        def answer(servo_id):
            servo = self.servos[servo_id]
            if len(params) != len(_CLEAR_PARAMS):
                return StatusError.DATA_LENGTH, b""
            if bytes(params) != _CLEAR_PARAMS:
                return StatusError.DATA_RANGE, b""
            self._refresh_present(poll=False)
            if servo.get("Moving"):
                return StatusError.RESULT_FAIL, b""
            plant_goal = servo.plant_ticks(servo.get("Goal Position"))
            servo.wrap_turns(self._plant_ticks(servo_id))
            servo.set("Goal Position", servo.present_ticks(plant_goal))  # the same angle
            return 0, b""

        return self._unicast_replies(packet_id, Instruction.CLEAR, answer)

    def _sync_write(self, packet_id: int, params: bytes) -> list:
        if len(params) < 4:
            return []
        address, size = word(params, 0), word(params, 2)
        body = params[4:]
        for k in range(0, len(body) - size, size + 1):
            for servo_id in self._addressed(body[k], acting=True):
                self._write_one(servo_id, address, body[k + 1 : k + 1 + size])
        servo = self.servos[self.ids[0]]
        if (address, size) == servo.items["Goal Position"]:
            goals = [self.servos[i].get("Goal Position") for i in self.ids]
            self.goal_log.append(np.array(goals, dtype=np.int64))
            self.frames_received += 1
            if len(self.goal_log) >= 2 * self.goal_log_size:  # bounded, amortised O(1)
                del self.goal_log[: -self.goal_log_size]
        return []

    def _bulk_write(self, packet_id: int, params: bytes) -> list:
        k = 0
        while k + 5 <= len(params):
            servo_key, address, size = params[k], word(params, k + 1), word(params, k + 3)
            for servo_id in self._addressed(servo_key, acting=True):
                self._write_one(servo_id, address, params[k + 5 : k + 5 + size])
            k += 5 + size
        return []

    def _group_read(self, requests: list[tuple[int, int, int]], fast: bool) -> list:
        """Answer (servo id, address, length) requests in order: one status each, or one in all."""
        if fast and not self.fast_sync_read:
            return []
        found = [
            (servo_id, address, length)
            for servo_key, address, length in requests
            for servo_id in self._addressed(servo_key)
            if self._answers(servo_id, Instruction.READ)
        ]
        poll = any(self._reads_present(self.servos[i], a, n) for i, a, n in found)
        self._refresh_present(poll=poll)  # once: the servos sample together
        entries = [(i, *self.servos[i].read(a, n)) for i, a, n in found]
        if not fast:
            return [(i, self._status(i, e, d)) for i, e, d in entries]
        if not entries:
            return []
        packet = encode_fast_sync_status(
            [
                (e | (ALERT_BIT if self.servos[i].alert else 0), self.servos[i].servo_id, d)
                for i, e, d in entries
            ]
        )
        return [(entries[-1][0], packet, [i for i, _, _ in entries])]

    def _sync_read(self, packet_id: int, params: bytes, *, fast: bool = False) -> list:
        if len(params) < 5:
            return []
        address, length = word(params, 0), word(params, 2)
        return self._group_read([(i, address, length) for i in params[4:]], fast)

    def _bulk_read(self, packet_id: int, params: bytes, *, fast: bool = False) -> list:
        if len(params) < 5 or len(params) % 5:
            return []
        requests = [
            (params[k], word(params, k + 1), word(params, k + 3)) for k in range(0, len(params), 5)
        ]
        return self._group_read(requests, fast)

    def _fast_sync_read(self, packet_id: int, params: bytes) -> list:
        return self._sync_read(packet_id, params, fast=True)

    def _fast_bulk_read(self, packet_id: int, params: bytes) -> list:
        return self._bulk_read(packet_id, params, fast=True)

    _HANDLERS = {
        Instruction.PING: _ping,
        Instruction.READ: _read,
        Instruction.WRITE: _write_instruction,
        Instruction.REG_WRITE: _reg_write,
        Instruction.ACTION: _action,
        Instruction.FACTORY_RESET: _factory_reset,
        Instruction.REBOOT: _reboot,
        Instruction.CLEAR: _clear,
        Instruction.SYNC_READ: _sync_read,
        Instruction.SYNC_WRITE: _sync_write,
        Instruction.FAST_SYNC_READ: _fast_sync_read,
        Instruction.BULK_READ: _bulk_read,
        Instruction.BULK_WRITE: _bulk_write,
        Instruction.FAST_BULK_READ: _fast_bulk_read,
    }
