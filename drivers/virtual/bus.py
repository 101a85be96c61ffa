"""A Protocol 2.0 servo bus served on a Linux pseudo-terminal.

``VirtualBus`` opens a pty, puts its slave side in raw mode, and answers
packets on the master side from a background thread, so the real driver, the
real ``dynamixel-sdk`` and the real pyserial (or any other Dynamixel tool) run
unchanged against ``VirtualBus.port``. Instructions: PING (also broadcast),
READ, WRITE, REG_WRITE, ACTION, FACTORY_RESET, REBOOT, CLEAR, SYNC_READ,
SYNC_WRITE, FAST_SYNC_READ, BULK_READ, BULK_WRITE, FAST_BULK_READ; anything
else gets the Instruction Error. WRITE, REG_WRITE, ACTION, REBOOT, CLEAR and
FACTORY_RESET may be broadcast (no reply, as on a real bus); Status Return
Level decides which instructions are answered. CRC and byte stuffing as in
the e-Manual; per-servo control tables and register rules in
``drivers.virtual.servo``.

Servo motion comes from a ``Plant``: one lock guards it, and every plant call
is made holding it. A write of registers the plant does not simulate (it
raises one of ``unsupported``) is undone and answered with Result Fail. Two clocks:

- real time (``lockstep_dt_s=None``, the default): simulated time is the wall
  clock since ``start``, in whole steps of ``sim_step_s``. A simulation thread
  keeps the plant there whether packets arrive or not (it wakes every 5 ms),
  and each packet first brings the plant to its arrival time, so a reply
  shows the state at that time and never waits for more than a few steps of
  simulation, even after a long pause;
- lock-step (``lockstep_dt_s`` given): simulated time advances only with the
  host's traffic, by exactly ``lockstep_dt_s`` per period, so a run does not
  depend on the host's timing and goes as fast as the plant computes. A period
  ends at each packet that writes Goal Position (by any instruction): the
  plant first runs the period that ends as the goal arrives, under the goals
  it had, then takes the new goal. A poll (a read of the present-value
  registers, 120..147, with no goal written since the previous poll) also
  ends a period, so a client that writes one goal and polls until the servo
  is there sees it move. A read that follows a goal write returns the state at
  the moment the goal was written: a telemetry row labelled with the goal's
  time holds what the servo saw at that time.

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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from trajgen.drivers.clock import sleep_until
from trajgen.drivers.control_table import WATCHDOG_UNIT_S, Model, model_named
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
from trajgen.drivers.virtual.servo import FACTORY_RESET_KEEPS, VirtualServo
from trajgen.servo_table import CONTROL_REGISTERS, PWM_FULL_SCALE, hardware_error_mask

_OVERLOAD_BIT = hardware_error_mask("overload")
# Thread switch interval while serving (the default is 5 ms; see VirtualBus.start).
_SWITCH_INTERVAL_S = 1e-3
# Real time: how often the simulation thread wakes (s), and the most steps it
# runs per hold of the lock (short holds: a packet may be waiting for it).
_SIM_WAKE_S = 0.005
_MAX_STEPS_PER_HOLD = 2
# The first and last of the registers the plant fills (addresses 120..146).
_PRESENT_FIRST, _PRESENT_LAST = "Realtime Tick", "Present Temperature"
# Registers that decide how Goal Position is clamped (the limits, in Position Mode).
_GOAL_CLAMP = {"Min Position Limit", "Max Position Limit", "Operating Mode"}
# CLEAR's fixed parameters after the option byte 0x01 (multi-turn clear).
_CLEAR_PARAMS = bytes([0x01, 0x44, 0x58, 0x4C, 0x22])
# Moving Status bit 0 (In-Position): the e-Manual gives no threshold; this is
# the one ROBOTIS' examples use to decide a goal is reached (pulses).
IN_POSITION_TICKS = 20
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
        address are affected; None: any reply. (short and wrong_id leave fast
        bulk read replies alone.)
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
        Servo ids at power-up, one per plant joint.
    models : str or sequence of str, optional
        Model name for every servo, or one per servo.
    lockstep_dt_s : float or None, optional
        Lock-step period (s), see the module docstring. None: real time.
    timing : WireTiming or None, optional
        Wire timing to emulate; None answers as fast as possible.
    faults : sequence of Fault, optional
        Failures to inject.
    fast_sync_read : bool, optional
        Whether the servos answer Fast Sync Read and Fast Bulk Read; False
        emulates firmware that predates them (no answer), to exercise the
        driver's fallback.
    registers : mapping of int to mapping of str to int, optional
        Per servo id, register values set before power-up (as someone
        configured the servo; see ``VirtualServo``).
    goal_log_size : int, optional
        How many of the latest frames ``goal_log`` keeps (memory stays
        constant on long streams).
    sim_step_s : float, optional
        Real time: the simulation thread's step (s).
    unsupported : tuple of exception types, optional
        What ``plant.set_control`` raises for register values the plant does
        not simulate (a profile, another Operating Mode...): such a write is
        undone and answered with Result Fail instead of stopping the bus.
    on_refusal : callable (servo id, reason) -> None, optional
        Told about each write refused that way (from the serving thread).

    Raises
    ------
    ValueError
        If the ids do not match the plant's joints, a model is unknown, or a
        period is not positive.
    TypeError
        If ``plant`` is not a ``Plant``.

    Attributes
    ----------
    port : str
        Device path of the pty's slave side: open it as a serial port.
    servos : dict of int to VirtualServo
        The servos by their power-up id (a servo answers to its ID register,
        which a host may change).
    goal_log : list of ndarray, shape (n,)
        Goal ticks of the latest Goal Position sync writes received (at least
        ``goal_log_size``, at most twice that), in ``ids`` order.
    frames_received : int
        Goal Position sync writes received so far.
    bytes_received, bytes_sent : int
        Bytes read from and written to the host.
    sim_time_s : float
        Simulated time (s) the bus has advanced the plant by.
    lock : threading.Lock
        Held around every plant call and while a packet is handled: hold it to
        look at ``servos`` or the plant from another thread while the bus runs.
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
        registers: Mapping[int, Mapping[str, int]] | None = None,
        goal_log_size: int = 100_000,
        sim_step_s: float = 1e-3,
        unsupported: tuple[type[Exception], ...] = (),
        on_refusal: Callable[[int, str], None] | None = None,
    ) -> None:
        if not isinstance(plant, Plant):
            raise TypeError(f"Expected `plant` to be a Plant, got {type(plant).__name__}.")
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
        if not sim_step_s > 0:
            raise ValueError(f"Expected `sim_step_s` > 0, got {sim_step_s}.")
        registers = registers or {}
        self.plant = plant
        self.ids = ids
        self.servos = {
            i: VirtualServo(i, m, registers=registers.get(i))
            for i, m in zip(ids, resolved, strict=True)
        }
        self._joint = {i: j for j, i in enumerate(ids)}
        self.lockstep_dt_s = lockstep_dt_s
        self.sim_step_s = sim_step_s
        self.unsupported = tuple(unsupported)
        self.on_refusal = on_refusal
        self.timing = timing
        self.fast_sync_read = fast_sync_read
        self._faults = [[f, f.count] for f in faults]
        self.goal_log: list[np.ndarray] = []
        self.goal_log_size = goal_log_size
        self.frames_received = 0
        self.bytes_received = 0
        self.bytes_sent = 0
        self.sim_time_s = 0.0
        self.lock = threading.Lock()
        self._goal_rad = np.asarray(plant.read()[0], dtype=float).copy()
        ticks = rad_to_servo_ticks(self._goal_rad)
        for servo_id in ids:
            servo = self.servos[servo_id]
            servo.set("Goal Position", servo.present_ticks(int(ticks[self._joint[servo_id]])))
            self.plant.set_control(self._joint[servo_id], self._control(servo))
            self.plant.set_torque_enabled(self._joint[servo_id], servo.torque_on)
        self._index_ids()
        self._goal_written = False
        self._polled = False
        self._last_packet_s = {i: time.monotonic() for i in ids}
        self._wire_free_s = 0.0
        self._master = -1
        self._slave = -1
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self.port = ""
        self.error: Exception | None = None
        self._late: list[tuple[float, int, bytes]] = []
        self._late_count = 0
        self._switch_interval_s = sys.getswitchinterval()
        self._started_s = time.monotonic()
        self._steps_done = 0

    # -- life cycle --------------------------------------------------------

    def start(self) -> VirtualBus:
        """Open the pty and start answering (and, in real time, simulating); returns self.

        While running, the interpreter's thread switch interval is 1 ms
        (restored by ``stop``): a driver in the same process busy-waits for
        replies, and at the default 5 ms the bus thread answers late. (0.1 ms
        was worse: the threads then thrash over the GIL.)
        """
        self._switch_interval_s = sys.getswitchinterval()
        sys.setswitchinterval(_SWITCH_INTERVAL_S)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._stop.clear()
        self._started_s = time.monotonic()
        self._steps_done = 0
        self._last_packet_s = dict.fromkeys(self.ids, self._started_s)
        targets = [self._serve] + ([self._simulate] if self.lockstep_dt_s is None else [])
        self._threads = [
            threading.Thread(target=t, name=f"virtual-bus{t.__name__}", daemon=True)
            for t in targets
        ]
        for thread in self._threads:
            thread.start()
        return self

    def stop(self) -> None:
        """Stop answering and simulating, and close the pty."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._threads = []
        for fd in (self._master, self._slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass  # closed by a "close" fault or a plant failure
        self._master = self._slave = -1
        sys.setswitchinterval(self._switch_interval_s)

    def __enter__(self) -> VirtualBus:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def wall_time_s(self) -> float:
        """Wall-clock time (s) since ``start``."""
        return time.monotonic() - self._started_s

    def _fail(self, error: Exception) -> None:
        """The plant failed: remember why and close the port (the host sees it go)."""
        self.error = error
        self._stop.set()
        if self._master >= 0:
            try:
                os.close(self._master)
            except OSError:
                pass
            self._master = -1

    # -- the plant -----------------------------------------------------------

    def _advance(self, dt_s: float) -> None:
        """Advance the plant by ``dt_s`` (lock held)."""
        self.plant.advance(dt_s)
        self.sim_time_s += dt_s

    def _catch_up(self, now_s: float, max_steps: int | None = None) -> None:
        """Real time: advance the plant by whole steps to ``now_s`` (lock held)."""
        due = int((now_s - self._started_s) / self.sim_step_s)
        steps = due - self._steps_done
        if max_steps is not None:
            steps = min(steps, max_steps)
        if steps > 0:
            self._advance(steps * self.sim_step_s)
            self._steps_done += steps

    def _simulate(self) -> None:
        """Real time: keep the plant on the wall clock, whatever the traffic.

        Wakes every ``_SIM_WAKE_S``; a packet brings the plant to its arrival
        time itself, so a reply waits for at most that much simulation. Steps
        in short holds of the lock, and not while a packet is waiting.
        """
        while not self._stop.is_set():
            try:
                waiting = select.select([self._master], [], [], 0)[0]
            except (OSError, ValueError):
                return  # the port is gone
            if waiting:  # a packet first: the serving thread needs the lock now
                time.sleep(0.0002)
                continue
            try:
                with self.lock:
                    now = time.monotonic()
                    self._catch_up(now, _MAX_STEPS_PER_HOLD)
                    self._check_watchdogs(now)
                    behind = int((now - self._started_s) / self.sim_step_s) > self._steps_done
            except Exception as e:  # the plant failed: the port goes away
                self._fail(e)
                return
            time.sleep(0 if behind else _SIM_WAKE_S)

    @staticmethod
    def _control(servo: VirtualServo) -> dict[str, int]:
        return {name: servo.get(name) for name in CONTROL_REGISTERS}

    def _goal_for_plant(self, servo: VirtualServo) -> float:
        """The plant angle (rad) of a servo's Goal Position, clamped to its limits."""
        goal = servo.get("Goal Position")
        if servo.position_mode:
            goal = min(max(goal, servo.get("Min Position Limit")), servo.get("Max Position Limit"))
        return float(servo_ticks_to_rad(servo.plant_ticks(goal)))

    def _written(self, servo_id: int, names: set[str]) -> None:
        """Pass what a write changed to the plant (goals wait for ``_commit_goals``)."""
        j = self._joint[servo_id]
        servo = self.servos[servo_id]
        if names & set(CONTROL_REGISTERS):  # first: the plant may refuse them
            self.plant.set_control(j, self._control(servo))
        if "ID" in names:
            self._index_ids()
        if "Torque Enable" in names:
            self.plant.set_torque_enabled(j, servo.torque_on)
        if "Goal Position" in names:
            self._goal_rad[j] = self._goal_for_plant(servo)
            self._goal_written = True
        elif names & _GOAL_CLAMP:  # the goal held, clamped to the new limits or mode
            goal = self._goal_for_plant(servo)
            if goal != self._goal_rad[j]:
                self._goal_rad[j] = goal
                self.plant.set_goal(self._goal_rad.copy())

    def _commit_goals(self) -> None:
        """After a packet: hand new goals to the plant (lock-step: a period ends first)."""
        if not self._goal_written:
            return
        self._goal_written = False
        if self.lockstep_dt_s is not None:
            self._advance(self.lockstep_dt_s)
            self._polled = False
        self.plant.set_goal(self._goal_rad.copy())

    def _refresh_present(self, *, poll: bool) -> None:
        """Fill every servo's present-value registers from the plant.

        In lock-step, a poll with no goal written since the previous poll ends
        a period first.
        """
        if poll and self.lockstep_dt_s is not None:
            if self._polled:
                self._advance(self.lockstep_dt_s)
            self._polled = True
        position, velocity, current = self.plant.read()
        pwm = self.plant.present_pwm()
        ticks = rad_to_servo_ticks(position)
        tick_ms = round(self.sim_time_s * 1000) % 32_768
        for j, servo_id in enumerate(self.ids):
            servo = self.servos[servo_id]
            present = servo.present_ticks(int(ticks[j]))
            speed = round(velocity[j] / VELOCITY_UNIT_RAD_S)
            goal = servo.get("Goal Position")
            servo.set("Realtime Tick", tick_ms)
            servo.set("Present Position", present)
            servo.set("Present Velocity", speed)
            servo.set("Present Current", servo.model.current_raw(current[j]))
            servo.set("Present PWM", round(pwm[j] * PWM_FULL_SCALE))
            servo.set("Position Trajectory", goal)
            servo.set("Velocity Trajectory", 0)
            servo.set("Moving", abs(speed) > servo.get("Moving Threshold"))
            servo.set("Moving Status", self._moving_status(servo, goal - present))

    @staticmethod
    def _moving_status(servo: VirtualServo, error_ticks: int) -> int:
        """Moving Status (123): bit 0 in position, bits 4-5 the profile's shape.

        The goal is a step (no profile generator is emulated), so Profile
        Ongoing (bit 1) and Following Error (bit 3) stay 0; bits 4-5 say
        which profile the registers ask for: 00 step, 01 rectangular
        (velocity only), 11 trapezoidal.
        """
        status = int(abs(error_ticks) <= IN_POSITION_TICKS)
        if servo.get("Profile Velocity"):
            status |= 0x30 if servo.get("Profile Acceleration") else 0x10
        return status

    def _reads_present(self, servo: VirtualServo, address: int, length: int) -> bool:
        """Whether a read of ``address``.. touches the registers the plant fills."""
        low = servo.items[_PRESENT_FIRST][0]
        high = sum(servo.items[_PRESENT_LAST])
        return any(low <= servo.target(a) < high for a in range(address, address + length))

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
            except (OSError, ValueError):
                return  # master closed
            arrival_s = time.monotonic()
            self.bytes_received += len(data)
            reader.feed(data)
            for raw in reader.packets():
                try:
                    with self.lock:
                        replies = self._handle(raw, arrival_s)
                except Exception as e:  # the plant failed: the port goes away
                    self._fail(e)
                    return
                if replies is None:  # "close" fault
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
                delay = 2e-6 * servo.get("Return Delay Time") if servo else 0.0
                t += self.timing.turnaround_s + delay + len(reply) * self.timing.byte_time_s
                sleep_until(t + self.timing.adapter_latency_s)
            if extra_s:
                self._late_count += 1
                heapq.heappush(self._late, (time.monotonic() + extra_s, self._late_count, reply))
            else:
                self._write(reply)
        self._wire_free_s = t

    def _addressed(self, servo_id: int) -> list[int]:
        """The servos (by power-up id) whose ID register is ``servo_id``, or all on broadcast."""
        if servo_id == BROADCAST_ID:
            return list(self.ids)
        return self._by_id.get(servo_id, [])

    def _index_ids(self) -> None:
        """Re-read every ID register (after a write of ID or a factory reset)."""
        self._by_id: dict[int, list[int]] = {}
        for i in self.ids:
            self._by_id.setdefault(self.servos[i].servo_id, []).append(i)

    def _handle(self, raw: bytes, arrival_s: float) -> list[tuple[int, bytes, float]] | None:
        """Answer one packet: [(servo id, reply bytes, extra delay)], or None to close."""
        try:
            packet = decode(raw)
        except PacketError:
            return []  # a real servo cannot trust the id of a corrupt packet
        if self.lockstep_dt_s is None:
            self._catch_up(arrival_s)  # at most _SIM_WAKE_S behind: the thread keeps up
        else:
            self._check_watchdogs(arrival_s)
        for servo_id in self._addressed(packet.servo_id):
            self._last_packet_s[servo_id] = arrival_s
        handler = self._HANDLERS.get(packet.instruction, VirtualBus._unknown)
        replies = handler(self, packet.servo_id, packet.params)
        self._commit_goals()
        if packet.instruction == Instruction.SYNC_WRITE and self._after_frame() is None:
            return None
        return self._apply_reply_faults(replies, packet)

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
        """Run ``answer(servo id) -> (error, data)`` per servo addressed; reply unless broadcast."""
        replies = []
        for servo_id in self._addressed(packet_id):
            error, data = answer(servo_id)
            if packet_id != BROADCAST_ID and self._answers(servo_id, instruction):
                replies.append((servo_id, self._status(servo_id, error, data)))
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
        address, length = _word(params, 0), _word(params, 2)
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
        address = _word(params, 0)
        return self._unicast_replies(
            packet_id, Instruction.WRITE, lambda i: (self._write_one(i, address, params[2:]), b"")
        )

    def _reg_write(self, packet_id: int, params: bytes) -> list:
        def answer(servo_id):
            servo = self.servos[servo_id]
            if len(params) < 3:
                return StatusError.DATA_LENGTH, b""
            error = servo.check_write(_word(params, 0), params[2:])[0]
            if not error:
                servo.pending = (_word(params, 0), bytes(params[2:]))
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
        self._goal_rad[j] = self._goal_for_plant(servo)
        self._goal_written = True

    def _reboot(self, packet_id: int, params: bytes) -> list:
        replies = self._unicast_replies(packet_id, Instruction.REBOOT, lambda i: (0, b""))
        for servo_id in self._addressed(packet_id):  # after the reply, as a servo does
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
        address, size = _word(params, 0), _word(params, 2)
        body = params[4:]
        for k in range(0, len(body) - size, size + 1):
            for servo_id in self._addressed(body[k]):
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
            servo_key, address, size = params[k], _word(params, k + 1), _word(params, k + 3)
            for servo_id in self._addressed(servo_key):
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
        address, length = _word(params, 0), _word(params, 2)
        return self._group_read([(i, address, length) for i in params[4:]], fast)

    def _bulk_read(self, packet_id: int, params: bytes, *, fast: bool = False) -> list:
        if len(params) < 5 or len(params) % 5:
            return []
        requests = [
            (params[k], _word(params, k + 1), _word(params, k + 3))
            for k in range(0, len(params), 5)
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

    # -- the Bus Watchdog ----------------------------------------------------------

    def _check_watchdogs(self, now_s: float) -> None:
        for servo_id in self.ids:
            servo = self.servos[servo_id]
            period_s = WATCHDOG_UNIT_S * servo.get("Bus Watchdog")
            if (
                servo.torque_on
                and period_s > 0
                and now_s - self._last_packet_s[servo_id] > period_s
            ):
                self._trip_watchdog(servo_id)

    def _trip_watchdog(self, servo_id: int) -> None:
        """Bus Watchdog -1, and the servo stops where it is (its registers keep their goal)."""
        self.servos[servo_id].set("Bus Watchdog", -1)
        j = self._joint[servo_id]
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
                j = self._joint[fault.servo_id]
                self.servos[fault.servo_id].raise_hardware_error(_OVERLOAD_BIT)
                self.plant.set_torque_enabled(j, self.servos[fault.servo_id].torque_on)
            else:
                self._trip_watchdog(fault.servo_id)
        return []

    def _apply_reply_faults(self, replies: list, request) -> list[tuple[int, bytes, float]]:
        inst = request.instruction
        reads = (Instruction.READ, Instruction.SYNC_READ, Instruction.FAST_SYNC_READ)
        address = _word(request.params, 0) if inst in reads and len(request.params) >= 2 else None
        reshapable = inst != Instruction.FAST_BULK_READ
        out = []
        for reply in replies:
            servo_id, data = reply[0], reply[1]
            # A fast read reply carries every servo in it.
            members = reply[2] if len(reply) == 3 else [servo_id]
            extra_s = 0.0
            dropped = False
            for entry in self._active(_REPLY_FAULTS):
                fault, remaining = entry
                if fault.servo_id is not None and fault.servo_id not in members:
                    continue
                if fault.address is not None and fault.address != address:
                    continue
                if fault.kind in ("short", "wrong_id") and not reshapable:
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
    ``ERR ID DATA CRC2`` for ``members`` in order, all of one data size.
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


def _word(params: bytes, k: int) -> int:
    """The little-endian 16-bit word at ``params[k]``."""
    return params[k] | params[k + 1] << 8
