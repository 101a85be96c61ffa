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
is made holding it. The bus may carry more servos than the plant has joints
(``plant_ids`` names the plant's): the others idle behind a first-order plant
(``drivers.virtual.chain.ChainPlant``), answering and moving as servos do. A
write of registers the plant does not simulate (it raises one of
``unsupported``) is undone and answered with Result Fail. Two clocks:

- real time (``lockstep_dt_s=None``, the default): simulated time is the wall
  clock since ``start``, in whole steps of ``sim_step_s``. A simulation thread
  steps the plant once per step of wall time whether packets arrive or not,
  and publishes the present values after each step; the serving thread
  answers every read from the latest of them and never steps the plant, so a
  reply never waits for the simulation (when the simulation falls more than
  5 ms behind the wall clock, on a busy host, the reply goes out with the
  state it has, counted in ``stale_replies``). Writes still go through every
  register rule and reach the plant at once (goals, torque, gains);
- lock-step (``lockstep_dt_s`` given): simulated time advances only with the
  host's traffic, by exactly ``lockstep_dt_s`` per period, so a run does not
  depend on the host's timing and goes as fast as the plant computes. A period
  ends at each packet that writes Goal Position (by any instruction): the
  plant first runs the period that ends as the goal arrives, under the goals
  it had, then takes the new goal. A poll (a read of the present-value
  motion registers, 120..143, with no goal written since the previous poll;
  supply voltage and temperature are read without ending one) also
  ends a period, so a client that writes one goal and polls until the servo
  is there sees it move. A read that follows a goal write returns the state at
  the moment the goal was written: a telemetry row labelled with the goal's
  time holds what the servo saw at that time.

In lock-step the Bus Watchdog runs on simulated time too: a servo trips when
more than its period of simulated time passes without a packet to it (checked
at the end of each period), never because the host was slow. In real time it
runs on the wall clock. A client in the same process (``connect``) can answer
its own packets in its own thread (``PtyTransport.answer``), so that no reply
waits for the serving thread to be scheduled: a lock-step run then does not
depend on the host's load at all.

``WireTiming`` adds what a pty lacks: byte time at the baud rate, each servo's
Return Delay Time, its turnaround, and the USB adapter's latency. ``Fault``
injects failures for tests.
"""

from __future__ import annotations

import os
import sys
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from trajgen.drivers.control_table import Model, model_named
from trajgen.drivers.protocol import (
    Instruction,
    Packet,
    PacketError,
    PacketReader,
    decode,
)
from trajgen.drivers.units import rad_to_servo_ticks, servo_ticks_to_rad
from trajgen.drivers.virtual.chain import ChainPlant
from trajgen.drivers.virtual.faults import Fault, FaultInjection
from trajgen.drivers.virtual.handlers import SECONDARY_ID, InstructionHandlers
from trajgen.drivers.virtual.plant import FirstOrderPlant, Plant
from trajgen.drivers.virtual.process import PlantProcess
from trajgen.drivers.virtual.servo import VirtualServo
from trajgen.drivers.virtual.simulation import IN_POSITION_TICKS, SimulatedTime, WallSteps
from trajgen.drivers.virtual.transport import PtyTransport, WireTiming
from trajgen.servo_table import BAUD_RATES, CONTROL_REGISTERS

from ..errors import BadArgument

#: bit/s -> Baud Rate (8) register value.
_BAUD_VALUE = {rate: value for value, rate in BAUD_RATES.items()}
#: The pty's termios speed constant -> bit/s, for the rates termios names.
_TERMIOS_BAUD = {
    getattr(termios, f"B{rate}"): rate
    for rate in BAUD_RATES.values()
    if hasattr(termios, f"B{rate}")
}

if TYPE_CHECKING:
    from trajgen.drivers.bus import ServoBus

__all__ = ["IN_POSITION_TICKS", "Fault", "VirtualBus", "WireTiming"]

# Thread switch interval while serving (the default is 5 ms; see VirtualBus.start).
_SWITCH_INTERVAL_S = 1e-3
# Registers that decide how Goal Position is clamped (the limits, in Position Mode).
_GOAL_CLAMP = frozenset({"Min Position Limit", "Max Position Limit", "Operating Mode"})
# Registers whose writes the plant hears at once (``_written``), and the id registers.
_CONTROL = frozenset(CONTROL_REGISTERS)
_IDS = frozenset({"ID", SECONDARY_ID})
# How many of the latest packets decoded are kept by their bytes (decoded once).
_DECODED_KEPT = 8
# Registers whose writes may bring a Bus Watchdog's trip closer.
_WATCHDOG_ARMING = frozenset({"Bus Watchdog", "Torque Enable"})


def _chain_plant(plant: Plant | None, ids: tuple[int, ...], plant_ids) -> Plant:
    """The plant behind all of ``ids``: ``plant`` itself when it has one joint per id
    (and ``plant_ids`` is None or ``ids``), else a ``ChainPlant`` with ``plant`` behind
    ``plant_ids`` (default the first ids) and the other servos idle; every servo idle
    without a plant."""
    if plant is None:
        if plant_ids is not None:
            raise BadArgument(f"Expected a `plant` for `plant_ids` {tuple(plant_ids)}.")
        return FirstOrderPlant(len(ids))
    if not isinstance(plant, Plant):
        raise TypeError(f"Expected `plant` to be a Plant, got {type(plant).__name__}.")
    if plant_ids is None:
        if plant.n_joints > len(ids):
            raise BadArgument(
                f"Expected at least one id per plant joint ({plant.n_joints}), got `ids` {ids}."
            )
        plant_ids = ids[: plant.n_joints]
    plant_ids = tuple(plant_ids)
    if len(plant_ids) != plant.n_joints or not set(plant_ids) <= set(ids):
        raise BadArgument(
            f"Expected `plant_ids` to be {plant.n_joints} of `ids` {ids} (one per plant "
            f"joint), got {plant_ids}."
        )
    if plant_ids == ids:
        return plant
    return ChainPlant(plant, len(ids), [ids.index(i) for i in plant_ids])


class VirtualBus(PtyTransport, SimulatedTime, InstructionHandlers, FaultInjection):
    """Emulated servos on a pseudo-terminal, backed by a plant.

    Parameters
    ----------
    plant : Plant or None, optional
        What moves the servos ``plant_ids`` (its joint ``k`` is the servo
        ``plant_ids[k]``). The other servos on the chain idle as servos do: they
        answer, take goals and hold torque in any Operating Mode they accept, and
        follow their goals with a first-order response (``chain.ChainPlant``). None:
        every servo idles.
    ids : sequence of int, optional
        Servo ids at power-up, any number of them.
    plant_ids : sequence of int, optional
        The ids, among ``ids``, of the plant's joints in its joint order; default the
        first ``plant.n_joints`` of ``ids``.
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
    baud : int, optional
        The chain's baud rate (bit/s, one of the X-series rates): every servo's
        Baud Rate register is set to it, and the servos hear only a host whose
        port runs at that rate (read from the pty's settings; a rate the pty
        cannot tell, such as 4.5 Mbps, is heard). Default: any rate.

    Raises
    ------
    ValueError
        If ``plant_ids`` are not one of ``ids`` per plant joint (fewer ``ids`` than
        plant joints), a model is unknown, or a period is not positive.
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
    collisions : int
        With ``timing``: host packets that arrived while a reply was on the
        wire (both garbled: the packet dropped, the reply's CRC broken).
    wire_log : deque of (float, float)
        Per host packet answered or collided (the latest
        ``goal_log_size``), when it arrived and when the last reply before
        it left the wire (``time.monotonic``, s): arrival before that end
        is a collision.
    stale_replies, stale_max_s : int, float
        Real time: packets answered more than 5 ms before the simulation had
        caught up with their arrival (a busy host; the reply did not wait), and
        the furthest behind any reply's state was, beyond its 1 ms step (s).
    lock : threading.Lock
        Held around every plant call and while a packet is handled: hold it to
        look at ``servos`` or the plant from another thread while the bus runs.
    error : Exception or None
        What stopped the bus when the plant raised (the port then closes, so
        the driver sees it go away).
    """

    def __init__(
        self,
        plant: Plant | None = None,
        *,
        ids: Sequence[int] = (1, 2, 3),
        plant_ids: Sequence[int] | None = None,
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
        baud: int | None = None,
        plant_process: bool = False,
    ) -> None:
        ids = tuple(ids)
        plant = _chain_plant(plant, ids, plant_ids)
        names = [models] * len(ids) if isinstance(models, str) else list(models)
        if len(names) != len(ids):
            raise BadArgument(f"Expected {len(ids)} `models`, got {len(names)}.")
        resolved: list[Model] = [model_named(n) for n in names]
        if lockstep_dt_s is not None and not lockstep_dt_s > 0:
            raise BadArgument(f"Expected `lockstep_dt_s` > 0 or None, got {lockstep_dt_s}.")
        if not sim_step_s > 0:
            raise BadArgument(f"Expected `sim_step_s` > 0, got {sim_step_s}.")
        if plant_process and lockstep_dt_s is not None:
            raise BadArgument("Expected `plant_process` only in real time (`lockstep_dt_s` None).")
        registers = {i: dict(r) for i, r in (registers or {}).items()}
        if baud is not None:
            if baud not in _BAUD_VALUE:
                raise BadArgument(f"Expected `baud` one of {sorted(_BAUD_VALUE)}, got {baud}.")
            for i in ids:
                registers.setdefault(i, {})["Baud Rate"] = _BAUD_VALUE[baud]
        self.baud = baud
        self.plant = self._own_plant = plant
        self.plant_process = plant_process
        self._process: PlantProcess | None = None
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
        self._io_lock = threading.Lock()  # around reading the master and answering
        self._lock_wanted = False  # a packet waits for ``lock`` (the simulation yields)
        self._serving_idle = True  # the serving thread waits for bytes (nothing unread)
        self._read_at_s = -float("inf")  # real time: when present values were last read
        self._client_answers = False
        self._reader = PacketReader()
        self._decoded: dict[bytes, Packet] = {}  # the latest packets decoded, by their bytes
        self._goal_rad = np.asarray(plant.read()[0], dtype=float).copy()
        ticks = rad_to_servo_ticks(self._goal_rad)
        for servo_id in ids:
            servo = self.servos[servo_id]
            servo.set("Goal Position", servo.present_ticks(int(ticks[self._joint[servo_id]])))
            self.plant.set_control(self._joint[servo_id], self._control(servo))
            self.plant.set_torque_enabled(self._joint[servo_id], servo.torque_on)
        self._index_ids()
        self._goal_written = False
        self._goal_ticks: dict[int, int] = {}  # joint -> plant ticks of a goal just written
        self._trip_at_s = -float("inf")  # no Bus Watchdog trips before (real time, process)
        self._polled = False
        self._last_packet_s = dict.fromkeys(ids, 0.0)
        self._wire_free_s = 0.0
        # Wire timing, from the earliest each packet can have come in (transport._send):
        self._reply_end_s = -float("inf")  # when the last reply left the wire
        self._wire_free_min_s = self._arrived_after_s = self._read_started_s = 0.0
        self.collisions = 0
        self.wire_log: deque[tuple[float, float]] = deque(maxlen=goal_log_size)
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
        self._wall = WallSteps(sim_step_s, self._started_s)
        self._steps_done = 0
        self.stale_replies = 0
        self.stale_max_s = 0.0
        self._publish()

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
        os.set_blocking(self._master, False)  # read what is there, from either side
        self.port = os.ttyname(self._slave)
        self._stop.clear()
        self._reader = PacketReader()
        self._client_answers = False
        with self.lock:
            self._started_s = time.monotonic()
            self._wall = WallSteps(self.sim_step_s, self._started_s)
            self._steps_done = 0
            if self.plant_process:
                self._process = PlantProcess(self._own_plant, self.sim_step_s, self._started_s)
                self.plant = self._process
            self._publish()
        self._last_packet_s = dict.fromkeys(self.ids, self._now())
        simulating = self.lockstep_dt_s is None and self._process is None
        targets = [self._serve] + ([self._simulate] if simulating else [])
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
        if self._process is not None:
            self._process.stop()
            self._publish()  # its last step: sim_time_s
            self._process = None
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

    def connect(self, **kwargs) -> ServoBus:
        """A driver bus on this port (not yet open); in lock-step it answers in lock-step.

        In lock-step, the ``ServoBus`` returned has this bus as its
        ``responder``: each packet it writes is answered in its own thread
        before it waits for the reply, and a stream on it runs on a
        ``SimulatedClock`` (``ServoBus.lockstep``). In real time it is a plain
        ``ServoBus`` on the port, served by this bus's thread.

        Parameters
        ----------
        **kwargs
            Passed to ``ServoBus`` (``baud``, ``retries``, ``latency_ms``).
        """
        from trajgen.drivers.bus import ServoBus

        responder = None if self.lockstep_dt_s is None else self
        return ServoBus(self.port, responder=responder, **kwargs)

    def _now(self) -> float:
        """The time the Bus Watchdog runs on (s): simulated in lock-step, else the wall clock."""
        return time.monotonic() if self.lockstep_dt_s is None else self.sim_time_s

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

    @staticmethod
    def _control(servo: VirtualServo) -> dict[str, int]:
        return {name: servo.get(name) for name in CONTROL_REGISTERS}

    @staticmethod
    def _goal_plant_ticks(servo: VirtualServo) -> int:
        """The plant position (ticks) of a servo's Goal Position, clamped to its limits."""
        goal = servo.get("Goal Position")
        if servo.position_mode:
            goal = min(max(goal, servo.get("Min Position Limit")), servo.get("Max Position Limit"))
        return servo.plant_ticks(goal)

    def _goal_for_plant(self, servo: VirtualServo) -> float:
        """The plant angle (rad) of a servo's Goal Position, clamped to its limits."""
        return float(servo_ticks_to_rad(self._goal_plant_ticks(servo)))

    def _written(self, servo_id: int, names: set[str]) -> None:
        """Pass what a write changed to the plant (goals wait for ``_commit_goals``)."""
        j = self._joint[servo_id]
        servo = self.servos[servo_id]
        if not _CONTROL.isdisjoint(names):  # first: the plant may refuse them
            self.plant.set_control(j, self._control(servo))
        if not _IDS.isdisjoint(names):
            self._index_ids()
        if "Torque Enable" in names:
            self.plant.set_torque_enabled(j, servo.torque_on)
        if _WATCHDOG_ARMING & names:  # a Bus Watchdog may trip sooner: look again
            self._trip_at_s = -float("inf")
        if "Goal Position" in names:  # in radians once the packet is done (_commit_goals)
            self._goal_ticks[j] = self._goal_plant_ticks(servo)
            self._goal_written = True
        elif j in self._goal_ticks and names & _GOAL_CLAMP:  # a goal of this packet
            self._goal_ticks[j] = self._goal_plant_ticks(servo)  # within the new limits
        elif names & _GOAL_CLAMP:  # the goal held, clamped to the new limits or mode
            goal = self._goal_for_plant(servo)
            if goal != self._goal_rad[j]:
                self._goal_rad[j] = goal
                self.plant.set_goal(self._goal_rad.copy())

    def _host_at_baud(self) -> bool:
        """Whether the host's port runs at the chain's ``baud`` (or either is unknown)."""
        if self.baud is None or self._master < 0:
            return True
        try:
            host = _TERMIOS_BAUD.get(termios.tcgetattr(self._master)[5])
        except termios.error:
            return True
        return host is None or host == self.baud

    def _handle(self, raw: bytes, arrival_s: float) -> list[tuple] | None:
        """Answer one packet: [(servo id, reply bytes, extra delay, late on the wire)], or None
        to close."""
        if not self._host_at_baud():
            return []  # at another rate the servos read noise: they neither act nor answer
        packet = self._decoded.get(raw)
        if packet is None:  # not one of the latest (a poll repeats its request)
            try:
                packet = decode(raw)
            except PacketError:
                return []  # a real servo cannot trust the id of a corrupt packet
            if len(self._decoded) >= _DECODED_KEPT:
                self._decoded.clear()
            self._decoded[raw] = packet
        if self.lockstep_dt_s is None:
            if self._process is not None:  # the latest step's, for what follows
                self._steps_done = self._process.steps()
                self.sim_time_s = self._steps_done * self.sim_step_s
            self._note_staleness(arrival_s)
        now = self._now()
        for servo_id in self._addressed(packet.servo_id, acting=True):
            self._last_packet_s[servo_id] = now
        handler = self._HANDLERS.get(packet.instruction, InstructionHandlers._unknown)
        replies = handler(self, packet.servo_id, packet.params)
        self._commit_goals()
        if packet.instruction == Instruction.SYNC_WRITE and self._after_frame() is None:
            return None
        return self._apply_reply_faults(replies, packet)
