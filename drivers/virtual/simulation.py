"""The virtual bus's simulated time: real time or lock-step, present values, the Bus Watchdog.

``SimulatedTime`` (a part of ``VirtualBus``) keeps the plant on the wall clock
(real time) or advances it one period per goal or poll (lock-step), fills the
present-value registers from the plant, and runs each servo's Bus Watchdog
(on simulated time in lock-step, on the wall clock in real time); see
``drivers.virtual.bus``.
"""

from __future__ import annotations

import math
import select
import time

import numpy as np

from trajgen.drivers.control_table import WATCHDOG_UNIT_S
from trajgen.drivers.units import VELOCITY_UNIT_RAD_S, rad_to_servo_ticks, servo_ticks_to_rad
from trajgen.drivers.virtual.servo import VirtualServo
from trajgen.servo_table import PWM_FULL_SCALE

# Real time: the most steps the simulation thread runs per hold of the lock
# (short holds: a packet may be waiting for it).
_MAX_STEPS_PER_HOLD = 2
# Real time: the simulation never runs faster than this many times real time. After
# the host held it back (a stall), it catches up over 1 / (rate - 1) times the
# stall's length instead of at once: the servos never seem to move faster than
# their simulation lets them (a jump would read as an encoder glitch). Below the
# driver's glitch check's factor (``GLITCH_SPEED_FACTOR``, 1.5 times the no-load
# speed), with room for the burst.
_CATCH_UP_RATE = 1.25
# Real time: while no present value was read for ``_IDLE_AFTER_S``, the simulation
# thread wakes every ``_IDLE_WAKE_S`` (and steps what is due) instead of every step:
# fewer turns taken from the other threads of the process (the GIL).
_IDLE_AFTER_S, _IDLE_WAKE_S = 0.05, 0.005
# Real time: the most simulated time (s) run at once after a pause, unless due: between
# two reads ``dt`` apart a reply shows at most this plus ``_CATCH_UP_RATE * dt`` of
# simulated motion. 10 ms (before) made a 40 ms stall read as an encoder fault at a
# third of the no-load speed (docs/realtime.md); 2 ms is within the glitch check's
# 4-tick noise allowance up to about 0.85 times the no-load speed at 1 kHz.
_CATCH_UP_BURST_S = 0.002
# Real time: a reply carries the state of the simulation's latest step; when that
# is further behind the packet's arrival than this (s), the simulation thread
# could not keep real time (a busy host): counted in ``stale_replies``.
_STALE_S = 0.005
# The first and last of the motion registers the plant fills (addresses 120..143;
# a read of them is a poll). Present Input Voltage and Temperature follow them.
_PRESENT_FIRST, _PRESENT_LAST = "Realtime Tick", "Position Trajectory"
# Real time, the plant in its own process: how long (s) after a Bus Watchdog's period
# ends the serving thread looks (the thread checked it every step, 1 ms).
_WATCH_MARGIN_S = 1e-4
# (model name, address, length) -> whether a read of them holding no Indirect Data
# byte touches the motion registers (the layout decides: worked out once).
_DIRECT_POLLS: dict[tuple[str, int, int], bool] = {}
# Real time: how far (s) simulated time may run behind the wall clock before the time
# spent so is counted (``Lag.over_s``): well above a busy host's wake-up latency.
LAG_COUNTED_S = 0.02
# Real time: the lag's distribution is kept in bins of this width (s), the last one
# holding everything beyond (``Lag``).
_LAG_BIN_S, _LAG_BINS = 2.5e-4, 2000
# Moving Status bit 0 (In-Position): the e-Manual gives no threshold; this is
# the one ROBOTIS' examples use to decide a goal is reached (pulses).
IN_POSITION_TICKS = 20


class Lag:
    """How far simulated time ran behind the wall clock, weighted by wall time.

    ``note`` is told the lag at each wake-up before the steps due are run
    (the age of the state replies carry then, its largest in the spell
    since the previous wake-up), and counts the spell since then at it.

    Attributes
    ----------
    max_s : float
        The largest lag noted (s).
    over_s : float
        Wall time (s) spent more than ``LAG_COUNTED_S`` behind.
    counts : list of float
        Wall time (s) spent at each lag, in bins of ``_LAG_BIN_S`` (the last
        bin: beyond).
    """

    def __init__(self) -> None:
        self.max_s = 0.0
        self.over_s = 0.0
        self.counts = [0.0] * _LAG_BINS
        self._at_s: float | None = None

    def note(self, now_s: float, lag_s: float, *, counted: bool = True) -> int:
        """Count the spell since the previous note at ``lag_s`` (s); returns its bin.

        ``counted`` False: the spell is not counted (nobody read the state then)."""
        spell = 0.0 if self._at_s is None else max(0.0, now_s - self._at_s)
        self._at_s = now_s
        if not counted:
            return 0
        self.max_s = max(self.max_s, lag_s)
        if lag_s > LAG_COUNTED_S:
            self.over_s += spell
        index = min(_LAG_BINS - 1, max(0, int(lag_s / _LAG_BIN_S)))
        self.counts[index] += spell
        return index

    @staticmethod
    def quantile(counts, q: float) -> float:
        """The lag (s, a bin's upper edge) below which a share ``q`` of the time was spent."""
        total = sum(counts)
        if total <= 0:
            return 0.0
        running = 0.0
        for index, spell in enumerate(counts):
            running += spell
            if running >= q * total:
                return (index + 1) * _LAG_BIN_S
        return _LAG_BINS * _LAG_BIN_S


class WallSteps:
    """Real time: the plant's steps due on the wall clock, and the catch-up rules.

    Simulated time is the wall clock since ``started_s`` in whole steps of
    ``step_s``. ``take`` hands out at most ``_MAX_STEPS_PER_HOLD`` steps at a
    time, and never more than ``_CATCH_UP_RATE`` times real time over more
    than ``_CATCH_UP_BURST_S``: the steps come out of a credit of simulated
    time that grows at that rate with the wall clock, capped at
    ``_CATCH_UP_BURST_S`` (so replies never show more motion than that at
    once). Used by the simulation thread and by the plant's own process
    (``drivers.virtual.process``).

    Parameters
    ----------
    step_s : float
        The plant's step (s).
    started_s : float
        ``time.monotonic()`` at simulated time 0.

    Attributes
    ----------
    done : int
        Steps handed out so far.
    lag : Lag
        How far behind the wall clock the steps ran, noted at each ``take``.
    """

    def __init__(self, step_s: float, started_s: float) -> None:
        self.step_s = step_s
        self.started_s = self._credit_at_s = started_s
        self.done = 0
        self._credit_s = 0.0  # simulated time the plant may run now (s)
        self.lag = Lag()
        self.lag_bin = 0  # the bin the latest ``take`` counted in

    def behind_s(self, now_s: float) -> float:
        """How far (s) the steps done are behind the wall clock at ``now_s``."""
        return now_s - self.started_s - self.done * self.step_s

    def take(self, now_s: float, *, unread: float = 0.0) -> int:
        """The steps to run at ``now_s`` (counted in ``done``); 0 when none is due.

        The lag before them is noted in ``lag``, unless nobody has read the
        present values for ``unread`` > ``_IDLE_AFTER_S`` (s): idle, the steps
        are run every ``_IDLE_WAKE_S`` by design (``wake_s``), all those due at
        once (nobody sees them run)."""
        read = unread <= _IDLE_AFTER_S
        self.lag_bin = self.lag.note(now_s, self.behind_s(now_s), counted=read)
        cap = max(_MAX_STEPS_PER_HOLD * self.step_s, _CATCH_UP_BURST_S)
        self._credit_s = min(cap, self._credit_s + _CATCH_UP_RATE * (now_s - self._credit_at_s))
        self._credit_at_s = now_s
        due = int((now_s - self.started_s) / self.step_s)
        if not read:
            self._credit_s = max(self._credit_s, (due - self.done) * self.step_s)
        credit = int(self._credit_s / self.step_s + 1e-9)
        steps = max(0, min(due - self.done, credit, _MAX_STEPS_PER_HOLD))
        self.done += steps
        self._credit_s -= steps * self.step_s
        return steps

    def wake_s(self, now_s: float, *, unread: float) -> float:
        """When (``time.monotonic()``) the next step is due and has credit: never a spin.

        ``unread``: how long (s) nobody has read the present values; past
        ``_IDLE_AFTER_S``, once caught up, every ``_IDLE_WAKE_S`` instead (the
        steps due meanwhile run at once).
        """
        due_s = self.started_s + (self.done + 1) * self.step_s
        if due_s > now_s and unread > _IDLE_AFTER_S:
            due_s = now_s + _IDLE_WAKE_S
        return max(due_s, self._credit_at_s + (self.step_s - self._credit_s) / _CATCH_UP_RATE)


class SimulatedTime:
    """The plant's time and present values for a ``VirtualBus``."""

    def _advance(self, dt_s: float) -> None:
        """Advance the plant by ``dt_s`` (lock held); in lock-step, then the Bus Watchdogs."""
        self.plant.advance(dt_s)
        self.sim_time_s += dt_s
        if self.lockstep_dt_s is not None:
            self._check_watchdogs(self.sim_time_s)

    def _catch_up(self, now_s: float) -> None:
        """Real time: advance the plant by the steps due at ``now_s`` (``WallSteps.take``;
        lock held)."""
        steps = self._wall.take(now_s, unread=now_s - self._read_at_s)
        if steps > 0:
            self._advance(steps * self.sim_step_s)
            self._steps_done = self._wall.done

    def _publish(self) -> None:
        """Real time: read the plant's latest step for replies (lock held; never steps it).

        One tuple, swapped in whole: (simulated time (s), position (ticks),
        velocity (rad/s), current (A), drive output), the arrays as lists. Done
        once per step at most, by the first reply that needs present values
        after it (``_refresh_present``): the simulation thread only steps.
        """
        if self._process is not None:  # the plant steps in its own process
            steps, ticks, velocity, current, pwm = self._process.latest()
            self._steps_done = steps
            self.sim_time_s = steps * self.sim_step_s
            self._snapshot = (self.sim_time_s, ticks, velocity, current, pwm)
            return
        position, velocity, current = self.plant.read()
        self._snapshot = (
            self._steps_done * self.sim_step_s,
            rad_to_servo_ticks(position).tolist(),
            np.asarray(velocity, dtype=float).tolist(),
            np.asarray(current, dtype=float).tolist(),
            np.asarray(self.plant.present_pwm(), dtype=float).tolist(),
        )

    def lag(self) -> tuple[float, float, float]:
        """Real time: how far simulated time ran behind the wall clock so far: (max (s),
        99th percentile over wall time (s), wall time spent more than
        ``LAG_COUNTED_S`` behind (s)); from the plant's process when it has one (also
        once stopped)."""
        if self.plant is not self._own_plant:  # a PlantProcess
            lag_max, over, _, counts = self.plant.figures()
        else:
            lag = self._wall.lag
            lag_max, over, counts = lag.max_s, lag.over_s, lag.counts
        return lag_max, Lag.quantile(counts, 0.99), over

    def _note_staleness(self, arrival_s: float) -> None:
        """Real time: count a reply whose state is more than ``_STALE_S`` behind its arrival.

        The reply never waits for the simulation: it carries the latest step's
        state. ``stale_replies`` counts those further behind and ``stale_max_s``
        keeps how far behind any reply's state was beyond its step (s; the first
        read after an idle spell may be up to ``_IDLE_WAKE_S`` behind).
        """
        behind = (arrival_s - self._started_s) - self._steps_done * self.sim_step_s
        if behind > self.sim_step_s:
            self.stale_max_s = max(self.stale_max_s, behind)
        if behind > _STALE_S + self.sim_step_s:
            self.stale_replies += 1

    def _simulate(self) -> None:
        """Real time: keep the plant on the wall clock, whatever the traffic.

        Steps once per ``sim_step_s`` of wall time, sleeping until the next step
        is due; the serving thread answers from the latest step (``_publish``)
        and never steps the plant itself. It
        holds the lock for at most ``_MAX_STEPS_PER_HOLD`` steps at a time, lets
        a packet that is waiting go first, and after a stall catches up at
        ``_CATCH_UP_RATE`` times real time (``_catch_up``).
        """
        while not self._stop.is_set():
            try:
                waiting = select.select([self._master], [], [], 0)[0]
            except (OSError, ValueError):
                return  # the port is gone
            if waiting or self._lock_wanted:  # a packet first: it needs the lock now
                time.sleep(0.0002)
                continue
            try:
                with self.lock:
                    now = time.monotonic()
                    self._catch_up(now)
                    if self._serving_idle:  # else a packet may be on its way in: not silent
                        self._check_watchdogs(now)
            except Exception as e:  # the plant failed: the port goes away
                self._fail(e)
                return
            now = time.monotonic()
            time.sleep(max(0.0, self._wall.wake_s(now, unread=now - self._read_at_s) - now))

    def _commit_goals(self) -> None:
        """After a packet: hand new goals to the plant (lock-step: a period ends first)."""
        if not self._goal_written:
            return
        self._goal_written = False
        if self._goal_ticks:  # Goal Position writes: one conversion for all
            joints = list(self._goal_ticks)
            self._goal_rad[joints] = servo_ticks_to_rad(np.array(list(self._goal_ticks.values())))
            self._goal_ticks.clear()
        if self.lockstep_dt_s is not None:
            self._advance(self.lockstep_dt_s)
            self._polled = False
        self.plant.set_goal(self._goal_rad.copy())

    def _refresh_present(self, *, poll: bool) -> None:
        """Fill every servo's present-value registers (120..143).

        Real time: from the simulation's latest step (``_publish``); the plant
        is read, never stepped. Lock-step: from the plant, and a poll with no goal
        written since the previous poll ends a period first.
        """
        if self.lockstep_dt_s is None:
            self._read_at_s = time.monotonic()
            if self._snapshot[0] != self._steps_done * self.sim_step_s:  # a step since
                self._publish()
            sim_s, ticks, velocity, current, pwm = self._snapshot
        else:
            if poll:
                if self._polled:
                    self._advance(self.lockstep_dt_s)
                self._polled = True
            position, velocity, current = self.plant.read()
            sim_s, ticks = self.sim_time_s, rad_to_servo_ticks(position).tolist()
            velocity, current = np.asarray(velocity).tolist(), np.asarray(current).tolist()
            pwm = np.asarray(self.plant.present_pwm()).tolist()
        tick_ms = round(sim_s * 1000) % 32_768
        for j, servo_id in enumerate(self.ids):
            servo = self.servos[servo_id]
            present = servo.present_ticks(ticks[j])
            speed = round(velocity[j] / VELOCITY_UNIT_RAD_S)
            goal = servo.get("Goal Position")
            servo.store_present(
                (
                    tick_ms,  # Realtime Tick
                    abs(speed) > servo.get("Moving Threshold"),  # Moving
                    self._moving_status(servo, goal - present),
                    round(pwm[j] * PWM_FULL_SCALE),  # Present PWM
                    servo.model.current_raw(current[j]),  # Present Current
                    speed,  # Present Velocity
                    present,  # Present Position
                    0,  # Velocity Trajectory
                    goal,  # Position Trajectory
                )
            )

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
        """Whether a read of ``address``.. touches the motion registers (a poll)."""
        key = (servo.model.name, address, length)
        polls = _DIRECT_POLLS.get(key)
        if polls is not None:
            return polls
        low = servo.items[_PRESENT_FIRST][0]
        high = sum(servo.items[_PRESENT_LAST])
        if servo.direct(address, length):  # no Indirect Data byte: one overlap test, kept
            polls = _DIRECT_POLLS[key] = address < high and low < address + length
            return polls
        return any(low <= servo.target(a) < high for a in range(address, address + length))

    def _next_trip_s(self) -> float:
        """The time (s, ``_now``) after which the first armed Bus Watchdog trips (inf if none)."""
        trips = [
            self._last_packet_s[i] + WATCHDOG_UNIT_S * servo.get("Bus Watchdog")
            for i, servo in self.servos.items()
            if i in self._last_packet_s and servo.torque_on and servo.get("Bus Watchdog") > 0
        ]
        return min(trips, default=math.inf)

    def _watch_watchdogs(self) -> float:
        """Real time, the plant in its own process: the serving thread trips the Bus
        Watchdogs that are due; returns how long (s) it may wait before the next."""
        now = time.monotonic()
        if now > self._trip_at_s:  # looked for again only then, or after a write arming one
            with self.lock:
                self._check_watchdogs(now)
                self._trip_at_s = self._next_trip_s()
        return max(0.0, self._trip_at_s - now) + _WATCH_MARGIN_S

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
