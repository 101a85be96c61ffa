"""A Protocol 2.0 servo bus served on a Linux pseudo-terminal.

``VirtualBus`` opens a pty, puts its slave side in raw mode, and answers
packets on the master side from a background thread, so the real driver, the
real ``dynamixel-sdk`` and the real pyserial run unchanged against
``VirtualBus.port``. Instructions: PING (also broadcast), READ, WRITE, REBOOT,
SYNC_WRITE, SYNC_READ, FAST_SYNC_READ; CRC and byte stuffing as in the
e-Manual; per-servo control tables and rules in ``drivers.virtual.servo``.

Servo motion comes from a ``Plant``. Two clocks:

- lock-step (``lockstep_dt_s`` given): the plant advances by exactly that much
  on every Sync Write of Goal Position and at no other time, so a test's result
  does not depend on the host's timing;
- real-time (``lockstep_dt_s=None``): before each packet is handled, the plant
  advances by the wall-clock time since the last packet (the plant is only
  observed through packets, so this is the same as a thread stepping it).

``WireTiming`` adds what a pty lacks: byte time at the baud rate, each servo's
Return Delay Time, its turnaround, and the USB adapter's latency. ``Fault``
injects failures for tests. The Bus Watchdog runs on the wall clock in both
modes.
"""

from __future__ import annotations

import heapq
import os
import select
import sys
import threading
import time
import tty
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from trajgen.drivers.clock import sleep_until
from trajgen.drivers.control_table import Model, Register, model_named
from trajgen.drivers.protocol import (
    ALERT_BIT,
    BROADCAST_ID,
    Instruction,
    PacketError,
    PacketReader,
    StatusError,
    decode,
    encode_fast_sync_status,
    encode_status,
)
from trajgen.drivers.units import VELOCITY_UNIT_RAD_S, rad_to_servo_ticks, servo_ticks_to_rad
from trajgen.drivers.virtual.plant import Plant
from trajgen.drivers.virtual.servo import VirtualServo

_OVERLOAD_BIT = 0x20
# Thread switch interval while serving (the default is 5 ms; see VirtualBus.start).
_SWITCH_INTERVAL_S = 1e-3


@dataclass(frozen=True)
class WireTiming:
    """Timing of a real bus, added by the emulator.

    Attributes
    ----------
    baud : int
        Bit rate (bit/s); a byte takes 10 bits.
    adapter_latency_s : float
        Delay (s) from a reply's last byte on the wire to the host reading it
        (USB adapter; a U2D2 at latency timer 1 ms is about 1e-3).
    turnaround_s : float
        Servo processing time (s) before its Return Delay Time starts.
    """

    baud: int = 1_000_000
    adapter_latency_s: float = 0.0
    turnaround_s: float = 20e-6

    @property
    def byte_time_s(self) -> float:
        """Time (s) one byte takes on the wire."""
        return 10.0 / self.baud


@dataclass(frozen=True)
class Fault:
    """A failure injected into the virtual bus.

    Attributes
    ----------
    kind : {"drop", "corrupt", "delay", "short", "wrong_id", "close", "overload", "watchdog"}
        drop: replies are not sent. corrupt: replies get a wrong CRC. delay:
        replies come ``delay_s`` late. short: servo ``servo_id``'s reply
        loses ``n_bytes`` data bytes but stays well formed (valid CRC; in a
        fast sync read, its part of the one packet). wrong_id: servo
        ``servo_id``'s reply carries id ``reply_id`` (valid CRC). close: the
        pty master closes (the port goes away). overload: servo ``servo_id``
        latches hardware error bit 5 (torque off, since the default Shutdown
        covers it). watchdog: servo ``servo_id``'s Bus Watchdog trips.
    at_frame : int
        Number of Goal Position sync writes received before the fault starts.
    servo_id : int or None
        The servo affected (required for short, wrong_id, overload and
        watchdog); None means every servo's replies.
    count : int or None
        How many replies drop / corrupt / delay / short / wrong_id affect;
        None: all from then on.
    delay_s : float
        Extra delay (s) for ``kind="delay"``.
    n_bytes : int or None
        Data bytes a short reply loses; None: all of them (an empty reply).
    reply_id : int or None
        The id a wrong_id reply carries; None: ``servo_id + 1``.
    address : int or None
        Only replies to reads (READ, SYNC_READ, FAST_SYNC_READ) of this start
        address are affected; None: any reply.
    """

    kind: Literal["drop", "corrupt", "delay", "short", "wrong_id", "close", "overload", "watchdog"]
    at_frame: int = 0
    servo_id: int | None = None
    count: int | None = None
    delay_s: float = 0.0
    n_bytes: int | None = None
    reply_id: int | None = None
    address: int | None = None

    def __post_init__(self) -> None:
        kinds = ("drop", "corrupt", "delay", "short", "wrong_id", "close", "overload", "watchdog")
        if self.kind not in kinds:
            raise ValueError(f"Expected `kind` in {kinds}, got {self.kind!r}.")
        if self.kind in ("short", "wrong_id", "overload", "watchdog") and self.servo_id is None:
            raise ValueError(f"Expected a `servo_id` for a {self.kind} fault, got None.")


class VirtualBus:
    """Emulated servos on a pseudo-terminal, backed by a plant.

    Parameters
    ----------
    plant : Plant
        Joint ``j`` is the servo ``ids[j]``.
    ids : sequence of int, optional
        Servo ids, one per plant joint.
    models : str or sequence of str, optional
        Model name for every servo, or one per servo.
    lockstep_dt_s : float or None, optional
        Lock-step period (s): the plant advances this much per Goal Position
        sync write. None: real-time.
    timing : WireTiming or None, optional
        Wire timing to emulate; None answers as fast as possible.
    faults : sequence of Fault, optional
        Failures to inject.
    fast_sync_read : bool, optional
        Whether the servos answer Fast Sync Read; False emulates firmware that
        predates it (no answer), to exercise the driver's fallback.
    registers : mapping of int to mapping of Register to int, optional
        Initial register values per servo id, over the factory defaults: what
        whoever assembled the robot installed (position limits, Drive Mode...),
        or a latched Hardware Error Status.
    goal_log_size : int, optional
        How many of the latest frames ``goal_log`` keeps (memory stays
        constant on long streams).

    Raises
    ------
    ValueError
        If the ids do not match the plant's joints or a model is unknown.

    Attributes
    ----------
    port : str
        Device path of the pty's slave side: open it as a serial port.
    servos : dict of int to VirtualServo
        The servos by id.
    goal_log : deque of ndarray, shape (n,)
        Goal ticks of the latest ``goal_log_size`` Goal Position sync writes
        received, in ``ids`` order.
    frames_received : int
        Goal Position sync writes received so far.
    bytes_received, bytes_sent : int
        Bytes read from and written to the host.
    lock : threading.Lock
        Held while a packet is handled: hold it to look at ``servos`` or the
        plant from another thread while the bus runs.
    error : Exception or None
        What stopped the bus when the plant raised (the port then closes, so
        the driver sees it go away).
    """

    def __init__(
        self,
        plant: Plant,
        *,
        ids: Sequence[int] = (1, 2, 3),
        models: str | Sequence[str] = "XM430-W350",
        lockstep_dt_s: float | None = None,
        timing: WireTiming | None = None,
        faults: Sequence[Fault] = (),
        fast_sync_read: bool = True,
        registers: Mapping[int, Mapping[Register, int]] | None = None,
        goal_log_size: int = 100_000,
    ) -> None:
        ids = tuple(ids)
        if len(ids) != plant.n_joints:
            raise ValueError(
                f"Expected one id per plant joint ({plant.n_joints}), got `ids` {ids}."
            )
        names = [models] * len(ids) if isinstance(models, str) else list(models)
        if len(names) != len(ids):
            raise ValueError(f"Expected {len(ids)} `models`, got {len(names)}.")
        resolved: list[Model] = [model_named(n) for n in names]
        if lockstep_dt_s is not None and not lockstep_dt_s > 0:
            raise ValueError(f"Expected `lockstep_dt_s` > 0 or None, got {lockstep_dt_s}.")
        self.plant = plant
        self.ids = ids
        self.servos = {i: VirtualServo(i, m) for i, m in zip(ids, resolved, strict=True)}
        for servo_id, values in (registers or {}).items():
            for register, value in values.items():
                self.servos[servo_id].set(register, value)
        self.lockstep_dt_s = lockstep_dt_s
        self.timing = timing
        self.fast_sync_read = fast_sync_read
        self._faults = [[f, f.count] for f in faults]
        self.goal_log: deque[np.ndarray] = deque(maxlen=goal_log_size)
        self.frames_received = 0
        self.bytes_received = 0
        self.bytes_sent = 0
        self._goal_rad = np.asarray(plant.read()[0], dtype=float).copy()
        for servo_id, ticks in zip(ids, rad_to_servo_ticks(self._goal_rad), strict=True):
            self.servos[servo_id].set(Register.GOAL_POSITION, int(ticks))
        self._last_packet_s = {i: time.monotonic() for i in ids}
        self._last_advance_s = time.monotonic()
        self._wire_free_s = 0.0
        self._master = -1
        self._slave = -1
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.lock = threading.Lock()
        self.port = ""
        self.error: Exception | None = None
        self._late: list[tuple[float, int, bytes]] = []
        self._late_count = 0
        self._switch_interval_s = sys.getswitchinterval()

    # -- life cycle --------------------------------------------------------

    def start(self) -> VirtualBus:
        """Open the pty and start answering; returns self.

        While running, the interpreter's thread switch interval is 1 ms
        (restored by ``stop``): the driver busy-waits for replies in the same
        process, and at the default 5 ms the bus thread answers late. (0.1 ms
        was worse: the two threads then thrash over the GIL.)
        """
        self._switch_interval_s = sys.getswitchinterval()
        sys.setswitchinterval(_SWITCH_INTERVAL_S)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._stop.clear()
        self._last_advance_s = time.monotonic()
        self._thread = threading.Thread(target=self._serve, name="virtual-bus", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop answering and close the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master, self._slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass  # closed by a "close" fault
        self._master = self._slave = -1
        sys.setswitchinterval(self._switch_interval_s)

    def __enter__(self) -> VirtualBus:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- serving -----------------------------------------------------------

    def _serve(self) -> None:
        reader = PacketReader()
        while not self._stop.is_set():
            self._flush_late_replies()
            wait_s = 0.05
            if self._late:
                wait_s = min(wait_s, max(0.0, self._late[0][0] - time.monotonic()))
            try:
                ready, _, _ = select.select([self._master], [], [], wait_s)
                if not ready:
                    continue
                data = os.read(self._master, 4096)
            except OSError:
                return  # master closed
            arrival_s = time.monotonic()
            self.bytes_received += len(data)
            reader.feed(data)
            for raw in reader.packets():
                try:
                    with self.lock:
                        replies = self._handle(raw, arrival_s)
                except Exception as e:  # the plant failed: the port goes away
                    self.error = e
                    replies = None
                if replies is None:  # "close" fault, or the plant failed
                    os.close(self._master)
                    self._master = -1
                    return
                self._send(raw, replies, arrival_s)

    def _write(self, reply: bytes) -> None:
        try:
            os.write(self._master, reply)
            self.bytes_sent += len(reply)
        except OSError:
            pass  # the host closed the port

    def _flush_late_replies(self) -> None:
        """Write the replies a "delay" fault held back, once they are due."""
        while self._late and self._late[0][0] <= time.monotonic():
            self._write(heapq.heappop(self._late)[2])

    def _send(self, request: bytes, replies: list[tuple[int, bytes, float]], arrival_s: float):
        """Write replies [(servo id, bytes, extra delay)] with wire timing.

        Wire time is slept (the bus is busy); a fault's extra delay is not (the
        servo has acted on the packet, only its reply is late).
        """
        t = arrival_s
        if self.timing is not None:
            t = max(arrival_s, self._wire_free_s) + len(request) * self.timing.byte_time_s
        for servo_id, reply, extra_s in replies:
            if self.timing is not None:
                servo = self.servos.get(servo_id)
                delay = 2e-6 * servo.get(Register.RETURN_DELAY_TIME) if servo else 0.0
                t += self.timing.turnaround_s + delay + len(reply) * self.timing.byte_time_s
                sleep_until(t + self.timing.adapter_latency_s)
            if extra_s:
                self._late_count += 1
                heapq.heappush(self._late, (time.monotonic() + extra_s, self._late_count, reply))
            else:
                self._write(reply)
        self._wire_free_s = t

    def _handle(self, raw: bytes, arrival_s: float) -> list[tuple[int, bytes, float]] | None:
        """Answer one packet: [(servo id, reply bytes, extra delay)], or None to close."""
        try:
            packet = decode(raw)
        except PacketError:
            return []  # a real servo cannot trust the id of a corrupt packet
        self._advance_real_time(arrival_s)
        targets = self.ids if packet.servo_id == BROADCAST_ID else (packet.servo_id,)
        for servo_id in targets:
            if servo_id in self.servos:
                self._check_watchdog(servo_id, arrival_s)
                self._last_packet_s[servo_id] = arrival_s
        inst, params = packet.instruction, packet.params
        if inst == Instruction.SYNC_WRITE:
            self._sync_write(params)
            return self._after_frame()
        if inst == Instruction.FAST_SYNC_READ and not self.fast_sync_read:
            replies = []
        elif inst in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ):
            replies = self._sync_read(params, fast=inst == Instruction.FAST_SYNC_READ)
        elif packet.servo_id == BROADCAST_ID and inst == Instruction.PING:
            replies = [(i, self._status(i, 0, self._ping_data(i))) for i in self.ids]
        elif packet.servo_id in self.servos:
            replies = [(packet.servo_id, self._unicast(packet.servo_id, inst, params))]
        else:
            replies = []
        return self._apply_reply_faults(replies, packet)

    def _status(self, servo_id: int, error: int, data: bytes = b"") -> bytes:
        if self.servos[servo_id].alert:
            error |= ALERT_BIT
        return encode_status(servo_id, error, data)

    def _ping_data(self, servo_id: int) -> bytes:
        servo = self.servos[servo_id]
        number = servo.get(Register.MODEL_NUMBER)
        return bytes([number & 0xFF, number >> 8, servo.get(Register.FIRMWARE_VERSION)])

    def _unicast(self, servo_id: int, inst: int, params: bytes) -> bytes:
        servo = self.servos[servo_id]
        if inst == Instruction.PING:
            return self._status(servo_id, 0, self._ping_data(servo_id))
        if inst == Instruction.READ and len(params) == 4:
            self._refresh_present()
            address, length = params[0] | params[1] << 8, params[2] | params[3] << 8
            error, data = servo.read(address, length)
            return self._status(servo_id, error, data)
        if inst == Instruction.WRITE and len(params) >= 3:
            address = params[0] | params[1] << 8
            error = servo.write(address, params[2:])
            if error == 0 and self._apply_write(servo_id, address, len(params) - 2):
                self.plant.set_goal(self._goal_rad.copy())
            return self._status(servo_id, error)
        if inst == Instruction.REBOOT:
            servo.reboot()
            self.plant.set_torque_enabled(self.ids.index(servo_id), False)
            return self._status(servo_id, 0)
        if inst in (Instruction.READ, Instruction.WRITE):
            return self._status(servo_id, StatusError.DATA_LENGTH)
        return self._status(servo_id, StatusError.INSTRUCTION)

    def _apply_write(self, servo_id: int, address: int, length: int) -> bool:
        """Pass a torque change to the plant; True if Goal Position was written."""
        j = self.ids.index(servo_id)
        servo = self.servos[servo_id]
        if address <= servo.layout[Register.TORQUE_ENABLE][0] < address + length:
            self.plant.set_torque_enabled(j, servo.torque_on)
        goal_address = servo.layout[Register.GOAL_POSITION][0]
        if address <= goal_address < address + length:
            self._goal_rad[j] = servo_ticks_to_rad(servo.get(Register.GOAL_POSITION))
            return True
        return False

    def _sync_write(self, params: bytes) -> None:
        if len(params) < 4:
            return
        address, size = params[0] | params[1] << 8, params[2] | params[3] << 8
        body = params[4:]
        goal_changed = False
        for k in range(0, len(body) - size, size + 1):
            servo_id, data = body[k], body[k + 1 : k + 1 + size]
            if servo_id in self.servos and self.servos[servo_id].write(address, data) == 0:
                goal_changed |= self._apply_write(servo_id, address, size)
        if goal_changed:  # once per packet: the plant sees one set of goals per frame
            self.plant.set_goal(self._goal_rad.copy())
        goal_address, goal_size = self.servos[self.ids[0]].layout[Register.GOAL_POSITION]
        if (address, size) == (goal_address, goal_size):
            goals = [self.servos[i].get(Register.GOAL_POSITION) for i in self.ids]
            self.goal_log.append(np.array(goals, dtype=np.int64))
            self.frames_received += 1
            if self.lockstep_dt_s is not None:
                self.plant.advance(self.lockstep_dt_s)

    def _sync_read(self, params: bytes, *, fast: bool) -> list[tuple[int, bytes]]:
        if len(params) < 5:
            return []
        address, length = params[0] | params[1] << 8, params[2] | params[3] << 8
        self._refresh_present()
        entries = []
        for servo_id in params[4:]:
            if servo_id in self.servos:
                error, data = self.servos[servo_id].read(address, length)
                entries.append((servo_id, error, data))
        if fast:
            return [
                (
                    entries[-1][0] if entries else BROADCAST_ID,
                    encode_fast_sync_status(
                        [
                            (e | (ALERT_BIT if self.servos[i].alert else 0), i, d)
                            for i, e, d in entries
                        ]
                    ),
                    [i for i, _, _ in entries],
                )
            ]
        return [(i, self._status(i, e, d)) for i, e, d in entries]

    def _refresh_present(self) -> None:
        position, velocity, current = self.plant.read()
        ticks = rad_to_servo_ticks(position)
        for j, servo_id in enumerate(self.ids):
            servo = self.servos[servo_id]
            servo.set(Register.PRESENT_POSITION, int(ticks[j]))
            servo.set(Register.PRESENT_VELOCITY, round(velocity[j] / VELOCITY_UNIT_RAD_S))
            servo.set(Register.PRESENT_CURRENT, servo.model.current_raw(current[j]))

    def _advance_real_time(self, now_s: float) -> None:
        if self.lockstep_dt_s is None:
            self.plant.advance(now_s - self._last_advance_s)
            self._last_advance_s = now_s

    def _check_watchdog(self, servo_id: int, now_s: float) -> None:
        servo = self.servos[servo_id]
        period_s = 0.020 * servo.get(Register.BUS_WATCHDOG)
        if servo.torque_on and period_s > 0 and now_s - self._last_packet_s[servo_id] > period_s:
            self._trip_watchdog(servo_id)

    def _trip_watchdog(self, servo_id: int) -> None:
        """Bus Watchdog -1, and the servo stops where it is."""
        servo = self.servos[servo_id]
        servo.set(Register.BUS_WATCHDOG, -1)
        j = self.ids.index(servo_id)
        self._goal_rad[j] = self.plant.read()[0][j]
        self.plant.set_goal(self._goal_rad.copy())

    # -- faults ------------------------------------------------------------

    def _active(self, kinds: tuple[str, ...]):
        for entry in self._faults:
            fault, remaining = entry
            if fault.kind in kinds and self.frames_received >= fault.at_frame:
                yield entry

    def _after_frame(self) -> list | None:
        """Apply faults that start at this frame; None to close the port."""
        for entry in list(self._active(("close", "overload", "watchdog"))):
            fault = entry[0]
            self._faults.remove(entry)
            if fault.kind == "close":
                return None
            if fault.kind == "overload":
                j = self.ids.index(fault.servo_id)
                self.servos[fault.servo_id].raise_hardware_error(_OVERLOAD_BIT)
                self.plant.set_torque_enabled(j, self.servos[fault.servo_id].torque_on)
            else:
                self._trip_watchdog(fault.servo_id)
        return []

    def _apply_reply_faults(self, replies: list, request) -> list[tuple[int, bytes, float]]:
        read = request.instruction in (
            Instruction.READ,
            Instruction.SYNC_READ,
            Instruction.FAST_SYNC_READ,
        )
        address = request.params[0] | request.params[1] << 8 if read else None
        out = []
        for reply in replies:
            servo_id, data = reply[0], reply[1]
            # A fast sync read reply carries every servo in it.
            members = reply[2] if len(reply) == 3 else [servo_id]
            extra_s = 0.0
            dropped = False
            for entry in self._active(_REPLY_FAULTS):
                fault, remaining = entry
                if fault.servo_id is not None and fault.servo_id not in members:
                    continue
                if fault.address is not None and fault.address != address:
                    continue
                if remaining is not None:
                    if remaining <= 0:
                        continue
                    entry[1] = remaining - 1
                if fault.kind == "drop":
                    dropped = True
                elif fault.kind == "corrupt":
                    data = data[:-1] + bytes([data[-1] ^ 0xFF])
                elif fault.kind in ("short", "wrong_id"):
                    data = _reshape_reply(data, members, fault)
                else:
                    extra_s += fault.delay_s
            if not dropped:
                out.append((servo_id, data, extra_s))
        return out


_REPLY_FAULTS = ("drop", "corrupt", "delay", "short", "wrong_id")


def _reshape_reply(reply: bytes, members: Sequence[int], fault: Fault) -> bytes:
    """A well-formed reply (valid CRC) with ``fault.servo_id``'s part short or re-addressed.

    ``reply`` is a status packet, or a fast sync read reply whose parts are
    ``ERR ID DATA CRC2`` for ``members`` in order.
    """
    packet = decode(reply)
    reply_id = fault.servo_id + 1 if fault.reply_id is None else fault.reply_id

    def reshaped(servo_id: int, error: int, data: bytes) -> tuple[int, int, bytes]:
        if fault.kind == "wrong_id":
            return reply_id, error, data
        keep = 0 if fault.n_bytes is None else max(0, len(data) - fault.n_bytes)
        return servo_id, error, data[:keep]

    if packet.servo_id != BROADCAST_ID:  # one servo's status packet
        servo_id, error, data = reshaped(packet.servo_id, packet.params[0], packet.params[1:])
        return encode_status(servo_id, error, data)
    # Fast sync read: the packet's params are every part except the last CRC2.
    body = reply[8:]
    size = len(body) // len(members) - 4
    entries = []
    for k, servo_id in enumerate(members):
        part = body[k * (size + 4) : (k + 1) * (size + 4)]
        error, data = part[0], part[2 : 2 + size]
        if servo_id == fault.servo_id:
            servo_id, error, data = reshaped(servo_id, error, data)
        entries.append((error, servo_id, data))
    return encode_fast_sync_status(entries)
