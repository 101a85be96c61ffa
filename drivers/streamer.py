"""Streaming a joint trajectory to the servos at a fixed rate.

Each frame's deadline is absolute: ``start + (frame.t - first.t)`` on the
stream's clock (``time.monotonic`` by default, or a ``SimulatedClock`` against
a lock-step virtual bus), so a frame a little late does not push the later
ones (no drift). Per frame: one Sync Write of Goal Position. Every ``telemetry_every``
frames: one group read of present current, velocity and position (Fast Sync
Read, or Sync Read where the servos do not answer it: said with a
``RuntimeWarning``), whose ERR bytes reveal a hardware error (Alert bit).
About every ``poll_s``: a group read of Torque Enable, Hardware Error Status
and Bus Watchdog (64..98): a servo whose torque went off or whose Bus Watchdog
no longer holds what it held at the start has rebooted (its RAM was reset) or
shut down, and the stream stops naming it. About every ``health_s``: a group
read of Present Input Voltage and Present Temperature (144..146), into the
telemetry, checked against the servo's own limits (``drivers.health``): a
warning near them, a stop before the servo's own shutdown.

Present Position is never trusted from one read: the stream starts from the
goal each servo held at torque on (``start_ticks``, which the first read must
agree with), or from two reads that agree; mid-stream, a read further from the
last plausible one than the servo could have moved is a glitch: counted,
warned, left out of the telemetry, and ``MAX_GLITCHES`` in a row stop the
stream.

Stalls (the host paused: GC, a busy machine, SIGSTOP): a frame more than
``stall_s`` (default half a period) past its deadline is never sent early to
catch up. The clock of the rest of the stream shifts by its lateness, so it
goes out now and every later frame keeps its planned spacing. Lateness below
``stall_s`` is jitter: that frame goes out late, the next one on time. So two
goals are never closer than ``period - stall_s``, no burst ever catches up, and
after a stall the servos follow the plan later, never faster. After a stall
long enough to have tripped a Bus Watchdog (the bus silent for half its period
or more) the watchdogs are polled at once (a stall longer than the period
stopped the servos); shorter ones wait for the next regular poll (at 1 kHz a
poll after every 0.6 ms stall would itself make the next frame late). Stalls are counted, and
the stream fails when the total shift passes ``max_delay_s``.

Any fault or stop signal stops the stream safely: the servos hold their last
goal (or, with ``on_stop="torque_off"``, are released) and the telemetry so
far stays on disk. Memory is constant in the number of frames (running
statistics; CSV telemetry is written as it goes).
"""

from __future__ import annotations

import contextlib
import math
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from itertools import chain, repeat
from pathlib import Path
from typing import Literal

import numpy as np

from trajgen.drivers.bringup import (
    HOLD_TOLERANCE_TICKS,
    MAX_APPROACH_RAD,
    POSITION_NOISE_TICKS,
    check_start,
    joint_names_for,
    restore_settings,
)
from trajgen.drivers.bus import WIRE_MARGIN_S, ServoBus
from trajgen.drivers.clock import WALL_CLOCK, SimulatedClock
from trajgen.drivers.control_table import (
    RETURN_DELAY_UNIT_S,
    VOLTAGE_UNIT_V,
    WATCHDOG_UNIT_S,
    Register,
)
from trajgen.drivers.defaults import MAX_DELAY_S
from trajgen.drivers.errors import (
    BringUpError,
    CommError,
    DriverError,
    OutsideLimits,
    ServoError,
    ServoReset,
    StreamLagging,
    WatchdogTripped,
)
from trajgen.drivers.frame_packets import sync_write_bytes
from trajgen.drivers.frame_reads import FrameReads, Read, parts
from trajgen.drivers.health import PowerLimits, health_problem
from trajgen.drivers.priority import stream_priority
from trajgen.drivers.probe import (
    BUDGET,
    MAX_READ_EVERY,
    PROBE_FRAMES,
    REPLY_WAIT_S,
    max_rate_hz,
    probe_cycle,
    read_every_for,
)
from trajgen.drivers.telemetry import TelemetryWriter
from trajgen.drivers.units import RAD_PER_TICK, JointMap
from trajgen.lead import sent_q
from trajgen.validate import check_choice, check_number

from .errors import BadArgument

_STATE = (Register.PRESENT_CURRENT, Register.PRESENT_VELOCITY, Register.PRESENT_POSITION)
_STATUS = (Register.TORQUE_ENABLE, Register.HARDWARE_ERROR_STATUS, Register.BUS_WATCHDOG)
_POWER = (Register.PRESENT_INPUT_VOLTAGE, Register.PRESENT_TEMPERATURE)
_POWER_LIMITS = (
    Register.MIN_VOLTAGE_LIMIT,
    Register.MAX_VOLTAGE_LIMIT,
    Register.TEMPERATURE_LIMIT,
)

#: A read further from the last plausible one than this factor times the
#: servo's no-load speed (at 12 V; a higher supply is faster) allows is a glitch.
GLITCH_SPEED_FACTOR = 1.5
#: This many glitched Present Position reads in a row of one servo stop the stream.
MAX_GLITCHES = 3


class RunningQuantiles:
    """Quantiles of a stream of non-negative values in constant memory.

    A histogram with ``per_decade`` logarithmic bins from ``low`` to ``high``
    (values below ``low`` count in the first bin, above ``high`` in the last);
    quantiles are bin centres, so their relative error is below
    ``10 ** (0.5 / per_decade) - 1`` (1.2 % at 100 bins a decade). The maximum
    is exact.

    Parameters
    ----------
    low, high : float
        Range resolved (same unit as the values, e.g. s).
    per_decade : int, optional
        Bins per factor of ten.
    """

    def __init__(self, low: float = 1e-7, high: float = 1e3, per_decade: int = 100) -> None:
        self._log_low = math.log10(low)
        self._per_decade = per_decade
        self._counts = np.zeros(int(round((math.log10(high) - self._log_low) * per_decade)) + 1)
        self.count = 0
        self.max = math.nan

    def add(self, value: float) -> None:
        """Count one value (>= 0)."""
        k = 0 if value <= 0 else int((math.log10(value) - self._log_low) * self._per_decade)
        self._counts[min(max(k, 0), len(self._counts) - 1)] += 1
        self.count += 1
        self.max = value if not value <= self.max else self.max

    def quantile(self, q: float) -> float:
        """The ``q`` quantile (0..1); NaN before any value."""
        if self.count == 0:
            return math.nan
        k = int(np.searchsorted(np.cumsum(self._counts), q * self.count))
        k = min(k, len(self._counts) - 1)
        return min(10 ** (self._log_low + (k + 0.5) / self._per_decade), self.max)


@dataclass
class StreamStats:
    """What a stream achieved (filled in as it runs; valid after a fault too).

    Attributes
    ----------
    rate_hz : float
        Planned rate (Hz).
    frames_planned, frames_sent : int
        Frames of the trajectory, and how many were sent.
    approach_frames : int
        Frames of the move from the present position to the first frame.
    lift_frames : int
        Frames of the lift sent before the first frame (``trajgen.lift``: the plan
        held at its first point while the goals bring the static gravity term in).
    lift_s : float
        How long the lift took (s), 0 without one.
    achieved_rate_hz : float
        ``rate_hz`` times planned over actual time between the first and last
        frame sent (NaN with fewer than two frames); stalls lower it.
    period_error_p50_s, period_error_p99_s, period_error_max_s : float
        Absolute error of each interval between frames sent, against its
        planned interval (s); stalls included.
    lateness_max_s : float
        Largest delay of a frame past its deadline (s), after stall shifts.
    overruns : int
        Frames sent more than one period after their deadline.
    stalls : int
        Times the stream's clock was shifted because a frame was more than
        ``stall_s`` late (approach included).
    reply_stalls : int
        Stalls (of ``stalls``) of a frame whose wait for the last frame's read
        (its reply in hand, or on the wall clock its computed wire end) ended
        later than a stall, rather than the host waking late.
    goals_behind : int
        Goals sent while the last frame's read reply was not in hand yet, its
        wire end past (wall clock; ``Streamer._loop``): that reply was checked
        right after the goal, or carried (``replies_carried``).
    replies_carried : int
        Times such a reply was still not in after its goal and was carried to
        the next frame (at most ``REPLY_WAIT_S`` past its wire end).
    reply_check_max_s : float
        Longest from the computed wire end of a reply a goal went out behind to
        its check (s; 0 if none): how late a fault in it was acted on.
    stall_max_s : float
        Longest stall (s): the largest single shift.
    delay_s : float
        Total shift (s): how far behind its plan the stream ran at the end
        (each stall's lateness plus the Bus Watchdog poll that follows it).
    reads : int
        Telemetry group reads done.
    reads_skipped : int
        State reads due that a poll part took the place of, having found no
        room beside them for ``read_every`` frames (``drivers.frame_reads``).
    reads_deferred : int
        Reads put off to the next frame: due in a frame whose goal went out
        behind the last reply, they no longer fit before the next deadline.
    position_glitches : int
        Present Position reads not trusted (a jump faster than the servo can move).
    warnings : list of str
        Power, heat and glitch warnings given during the stream (each once).
    comm_errors : int
        Transactions that failed (retried, or fatal).
    read_method : str
        "fast sync read" or "sync read".
    read_fallback : str
        Why Fast Sync Read was given up for Sync Read ("" if it was not).
    read_every : int
        Frames per telemetry read-back, as streamed (the probe may raise it
        above ``telemetry_every``: said with a warning).
    probe_write_s, probe_read_s : float
        A goal write's wire time and what a read-back took before the stream (s, median;
        NaN when not probed: on a simulated clock, or ``probe_frames=0``).
    scheduling : str
        How the stream thread was scheduled on the wall clock or a paced one
        (``drivers.priority``; "" when not raised: a simulated clock, or
        ``realtime=False``).
    fault : str
        The message of the fault or signal that stopped the stream ("" if none).
    """

    rate_hz: float
    frames_planned: int
    frames_sent: int = 0
    approach_frames: int = 0
    lift_frames: int = 0
    lift_s: float = 0.0
    achieved_rate_hz: float = math.nan
    period_error_p50_s: float = math.nan
    period_error_p99_s: float = math.nan
    period_error_max_s: float = math.nan
    lateness_max_s: float = math.nan
    overruns: int = 0
    stalls: int = 0
    reply_stalls: int = 0
    goals_behind: int = 0
    replies_carried: int = 0
    reply_check_max_s: float = 0.0
    stall_max_s: float = 0.0
    delay_s: float = 0.0
    reads: int = 0
    reads_skipped: int = 0
    reads_deferred: int = 0
    position_glitches: int = 0
    warnings: list[str] = field(default_factory=list)
    comm_errors: int = 0
    read_method: str = "fast sync read"
    read_fallback: str = ""
    read_every: int = 1
    probe_write_s: float = math.nan
    probe_read_s: float = math.nan
    scheduling: str = ""
    fault: str = ""
    _errors: RunningQuantiles = field(default_factory=RunningQuantiles, repr=False)
    _first: tuple[float, float] | None = field(default=None, repr=False)
    _last: tuple[float, float] | None = field(default=None, repr=False)

    def _sent(self, sent_s: float, planned_s: float, deadline_s: float, planned: bool) -> None:
        """Record one frame: when it went out, its unshifted and shifted deadlines;
        ``planned``: a frame of the stream (not its lift)."""
        self.frames_sent += planned
        late = sent_s - deadline_s
        self.lateness_max_s = late if not late <= self.lateness_max_s else self.lateness_max_s
        if late > 1.0 / self.rate_hz:
            self.overruns += 1
        if self._last is not None:
            self._errors.add(abs((sent_s - self._last[0]) - (planned_s - self._last[1])))
        self._first = self._first or (sent_s, planned_s)
        self._last = (sent_s, planned_s)

    def _finish(self) -> None:
        if self._errors.count == 0:
            return
        self.period_error_p50_s = self._errors.quantile(0.50)
        self.period_error_p99_s = self._errors.quantile(0.99)
        self.period_error_max_s = self._errors.max
        actual, planned = self._last[0] - self._first[0], self._last[1] - self._first[1]
        self.achieved_rate_hz = self.rate_hz * planned / actual if actual > 0 else math.nan

    def to_json_dict(self) -> dict:
        """Plain values for JSON (NaN becomes None)."""
        out = {k: v for k, v in asdict(self).items() if not k.startswith("_")}
        return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in out.items()}

    def format(self) -> str:
        """A few lines for a terminal."""

        def ms(x: float) -> str:
            return "n/a" if math.isnan(x) else f"{1e3 * x:.3f} ms"

        lines = [
            f"frames sent: {self.frames_sent}/{self.frames_planned} "
            f"(+{self.approach_frames} approach"
            + (f", +{self.lift_frames} lift, {self.lift_s:.3f} s" if self.lift_frames else "")
            + f") at {self.rate_hz:g} Hz planned, "
            + (
                "n/a achieved"
                if math.isnan(self.achieved_rate_hz)
                else f"{self.achieved_rate_hz:.2f} Hz achieved"
            ),
            f"period error: p50 {ms(self.period_error_p50_s)}, p99 {ms(self.period_error_p99_s)}, "
            f"max {ms(self.period_error_max_s)}; max lateness {ms(self.lateness_max_s)}; "
            f"overruns: {self.overruns}",
            f"stalls: {self.stalls} (longest {ms(self.stall_max_s)}; "
            f"stream ended {ms(self.delay_s)} behind its plan)"
            + (f"; {self.reply_stalls} waiting for a read's reply" if self.reply_stalls else ""),
            f"telemetry reads: {self.reads} ({self.read_method}, every {self.read_every} "
            f"frames"
            + (f"; {self.reads_skipped} given to polls" if self.reads_skipped else "")
            + (f"; {self.reads_deferred} deferred a frame" if self.reads_deferred else "")
            + (f"; {self.goals_behind} goals sent behind a reply" if self.goals_behind else "")
            + (
                f", {self.replies_carried} carried a frame; a reply checked at most "
                f"{ms(self.reply_check_max_s)} after its wire end"
                if self.goals_behind
                else ""
            )
            + f"); comm errors: {self.comm_errors}",
        ]
        if not math.isnan(self.probe_write_s):
            lines.append(
                f"probe before the stream: goal write {ms(self.probe_write_s)}, read-back "
                f"{ms(self.probe_read_s)}"
            )
        if self.scheduling:
            lines.append(f"stream thread: {self.scheduling}")
        if self.position_glitches:
            lines.append(f"position reads not trusted (glitches): {self.position_glitches}")
        if self.fault:
            lines.append(f"stopped by fault: {self.fault}")
        return "\n".join(lines)


def min_jerk_ramp(q_from: np.ndarray, q_to: np.ndarray, rate_hz: float, speed_rad_s: float):
    """Frames (t, q) of a minimum-jerk move, peak joint speed ``speed_rad_s``.

    Parameters
    ----------
    q_from, q_to : ndarray, shape (n,)
        Start and end angles (rad).
    rate_hz : float
        Frame rate (Hz).
    speed_rad_s : float
        Peak speed of the joint that moves furthest (rad/s).

    Returns
    -------
    t : ndarray, shape (M,)
        Times (s) from 0, the last at the end of the move.
    q : ndarray, shape (M, n)
        Angles (rad); ``q[-1] == q_to``. ``M == 0`` when there is nothing to move.
    """
    distance = float(np.max(np.abs(q_to - q_from)))
    if distance == 0:
        return np.zeros(0), np.zeros((0, len(q_from)))
    # Minimum jerk 10 s^3 - 15 s^4 + 6 s^5 peaks at 1.875 times the mean speed.
    duration = max(1.875 * distance / speed_rad_s, 2.0 / rate_hz)
    n = math.ceil(duration * rate_hz)
    t = np.arange(1, n + 1) / rate_hz
    s = np.minimum(t / duration, 1.0)
    h = s**3 * (10 - 15 * s + 6 * s**2)
    return t, q_from + h[:, None] * (q_to - q_from)


class Streamer:
    """Sends a joint stream to the servos of a configured bus.

    Parameters
    ----------
    bus : ServoBus
        Open bus, servos brought up (``drivers.bringup.bring_up``).
    joints : JointMap
        Joint-to-servo mapping.
    telemetry : str or Path or None, optional
        ``.csv``, ``.npz`` or ``.mcap`` file for per-frame telemetry.
    joint_names : sequence of str, optional
        Names of the joints (telemetry columns, messages); default pan, tilt,
        roll for three joints.
    telemetry_every : int, optional
        Read present state every this many frames (>= 1).
    poll_s : float, optional
        Poll the Bus Watchdog about this often (s).
    on_stop : {"hold", "torque_off"}, optional
        What the servos do when the stream ends or faults: hold the last goal
        (Bus Watchdog cleared), or torque off.
    approach_speed_rad_s : float, optional
        Peak joint speed of the move from the present position to the first
        frame (rad/s).
    fast_read : bool, optional
        Try Fast Sync Read first (falls back to Sync Read, with a
        ``RuntimeWarning``, if it gets no sound answer).
    max_approach_rad : float, optional
        Refuse to start when a joint reads farther than this from the first
        frame (rad): the plausibility check of the read-back position that
        starts the approach.
    goal_bounds_ticks : array_like, shape (n, 2), optional
        Lowest and highest goal (ticks) per servo, e.g. ``BringUp.goal_bounds_ticks``
        (the installed position limits); a frame outside is a fault, never sent.
    stall_s : float, optional
        Lateness (s) past which a frame counts as a stall and the stream's
        clock shifts; default half a period.
    max_delay_s : float or None, optional
        Fail the stream (``StreamLagging``) when the total shift passes this
        (s); None: no bound (stalls are still counted).
    start_ticks : array_like of int, shape (n,), optional
        The Goal Position each servo holds at the start (``BringUp.present_ticks``):
        the stream starts from it, and the first position read must agree with
        it. None: two position reads that agree.
    health_s : float, optional
        Read supply voltage and temperature about this often (s).
    power_limits : sequence of PowerLimits, optional
        Each servo's voltage and temperature limits (``BringUp.power_limits``);
        None: read from the servos at the start.
    restore : sequence of Change, optional
        Settings bring-up changed (``BringUp.changes``), written back by the
        safe stop (``restore_settings``); empty: nothing is restored.
    clock : object with ``now()`` and ``sleep_until(deadline_s)``, optional
        What the deadlines run on. Default: a ``drivers.clock.SimulatedClock``
        when the bus answers in lock-step (``bus.lockstep``: the stream then
        runs as fast as the simulation allows, never stalls and never waits on
        the wall clock), else the host's monotonic clock.
    probe_frames : int, optional
        On a real-time clock, before the approach: time this many read-backs
        (nothing is written; a goal write counts its wire time) and refuse
        a rate the host and bus cannot keep (``StreamLagging``, nothing
        moved), or read back less often than ``telemetry_every`` where that
        is what does not fit (a ``RuntimeWarning``; ``stats.read_every``); see
        ``drivers.probe``. 0: no probe.
    realtime : bool, optional
        On the wall clock (or a clock it paces, ``clock.paced``: a
        ``drivers.clock.PacedClock``), stream from a thread raised to ``SCHED_FIFO`` with
        a short GIL switch interval (``drivers.priority``; said in
        ``stats.scheduling``, also where the system does not permit it).

    Attributes
    ----------
    stats : StreamStats or None
        Statistics of the last ``run`` (also after a fault).
    stop_errors : list of str
        What the last safe stop could not do (e.g. a servo that no longer answers).

    Raises
    ------
    TypeError, ValueError
        If an option has the wrong type or range.
    """

    def __init__(
        self,
        bus: ServoBus,
        joints: JointMap,
        *,
        telemetry: str | Path | None = None,
        joint_names: Sequence[str] | None = None,
        telemetry_every: int = 1,
        poll_s: float = 0.05,
        on_stop: Literal["hold", "torque_off"] = "hold",
        approach_speed_rad_s: float = 0.5,
        fast_read: bool = True,
        max_approach_rad: float = MAX_APPROACH_RAD,
        goal_bounds_ticks: np.ndarray | None = None,
        stall_s: float | None = None,
        max_delay_s: float | None = MAX_DELAY_S,
        start_ticks: np.ndarray | None = None,
        health_s: float = 0.5,
        power_limits: Sequence[PowerLimits] | None = None,
        restore: Sequence = (),
        clock=None,
        probe_frames: int = PROBE_FRAMES,
        realtime: bool = True,
    ) -> None:
        positive = {"low": 0.0, "low_open": True}
        telemetry_every = check_number("telemetry_every", telemetry_every, low=1, integer=True)
        probe_frames = check_number("probe_frames", probe_frames, low=0, integer=True)
        check_choice("on_stop", on_stop, ("hold", "torque_off"))
        poll_s = check_number("poll_s", poll_s, **positive)
        health_s = check_number("health_s", health_s, **positive)
        if start_ticks is not None:
            start_ticks = np.asarray(start_ticks, dtype=np.int64)
            if start_ticks.shape != (len(joints),):
                raise BadArgument(
                    f"Expected `start_ticks` of shape ({len(joints)},), got {start_ticks.shape}."
                )
        approach_speed_rad_s = check_number(
            "approach_speed_rad_s", approach_speed_rad_s, **positive
        )
        max_approach_rad = check_number("max_approach_rad", max_approach_rad, **positive)
        if stall_s is not None:
            stall_s = check_number("stall_s", stall_s, **positive)
        if max_delay_s is not None:
            max_delay_s = check_number("max_delay_s", max_delay_s, **positive)
        if goal_bounds_ticks is not None:
            goal_bounds_ticks = np.asarray(goal_bounds_ticks)
            if goal_bounds_ticks.shape != (len(joints), 2):
                raise BadArgument(
                    f"Expected `goal_bounds_ticks` of shape ({len(joints)}, 2), "
                    f"got {goal_bounds_ticks.shape}."
                )
        self.bus = bus
        self.joints = joints
        self.telemetry_path = telemetry
        self.joint_names = joint_names_for(joints, joint_names)
        self.telemetry_every = telemetry_every
        self.poll_s = poll_s
        self.on_stop = on_stop
        self.approach_speed_rad_s = approach_speed_rad_s
        self.fast_read = fast_read
        self.max_approach_rad = max_approach_rad
        self.goal_bounds_ticks = goal_bounds_ticks
        self.stall_s = stall_s
        self.max_delay_s = max_delay_s
        self.start_ticks = start_ticks
        self.health_s = health_s
        self.power_limits = None if power_limits is None else tuple(power_limits)
        self.restore = tuple(restore)
        if clock is None:
            clock = SimulatedClock() if bus.lockstep else WALL_CLOCK
        self.clock = clock
        self.probe_frames = probe_frames
        self.realtime = bool(realtime)
        self.stats: StreamStats | None = None
        self._behind_goal = None  # the last PendingRead a goal went out behind (``_loop``)
        self.stop_errors: list[str] = []

    def run(self, stream, *, rate_hz: float | None = None) -> StreamStats:
        """Move to the first frame smoothly, then stream every frame.

        Parameters
        ----------
        stream : JointTrajectory or iterable of JointFrame
            Frames with ``t`` (s) and ``q`` (rad, shape (n,)); each frame's
            ``goal`` (``trajgen.lead``) is sent when it has one, else its ``q``.
        rate_hz : float, optional
            Stream rate (Hz); default ``stream.rate_hz``.

        Returns
        -------
        StreamStats

        Raises
        ------
        ValueError
            If no rate is known or the stream is empty.
        BringUpError
            If a joint reads farther than ``max_approach_rad`` from the first
            frame, or its position reads do not agree with ``start_ticks`` (or
            with each other) (nothing is sent; the servos hold or are released).
        CommError, ServoError, WatchdogTripped, StreamLagging, OutsideLimits
            On a fault, after the safe stop; ``self.stats`` holds the statistics
            and ``self.stop_errors`` anything the safe stop could not do.
            ``ServoReset`` (a ``ServoError``): a servo rebooted or lost power;
            ``ServoError`` also for supply or temperature at the stop margins,
            and for ``MAX_GLITCHES`` implausible position reads in a row.
        KeyboardInterrupt
            On Ctrl-C (or ``errors.Interrupted``: a stop signal), after the safe stop.
        """
        rate_hz = getattr(stream, "rate_hz", None) if rate_hz is None else rate_hz
        if rate_hz is None or not rate_hz > 0:
            raise BadArgument(f"Expected a positive `rate_hz` (or stream.rate_hz), got {rate_hz}.")
        frames: Iterator = iter(stream)
        try:
            first = next(frames)
        except StopIteration:
            raise BadArgument("Expected a non-empty stream, got no frames.") from None
        planned = len(stream) if hasattr(stream, "__len__") else 0
        self.stats = stats = StreamStats(rate_hz=float(rate_hz), frames_planned=planned)
        self.stop_errors = []
        self._writer = writer = None
        self._frame_no = 0
        self._last_position: tuple[np.ndarray, np.ndarray] | None = None
        self._max_speed = GLITCH_SPEED_FACTOR * np.array(
            [self.bus.models[i].no_load_speed_rad_s for i in self.joints.ids]
        )
        self._glitches = np.zeros(len(self.joints), dtype=int)
        failed_before = self.bus.failed_tries
        priority = contextlib.nullcontext("")
        if self.realtime and getattr(self.clock, "paced", self.clock.real_time):
            priority = stream_priority()  # a clock the wall clock paces (PacedClock too)
        try:
            if self.telemetry_path is not None:
                models = [self.bus.models[i] for i in self.joints.ids]
                self._writer = writer = TelemetryWriter(
                    self.telemetry_path, self.joint_names, models
                )
            self._choose_read_method()
            if self.clock.real_time:  # for a reply's wire end (ServoBus.reply_s)
                delays = [self.bus.read(i, Register.RETURN_DELAY_TIME) for i in self.joints.ids]
                self.bus.return_delay_s = max(delays) * RETURN_DELAY_UNIT_S
            self._status_at_start = self._read_status()
            periods = [v[Register.BUS_WATCHDOG] for v in self._status_at_start.values()]
            # A silence this long (s) may have tripped a Bus Watchdog (inf: none is on).
            self._watchdog_risk_s = (
                0.5 * WATCHDOG_UNIT_S * min((p for p in periods if p > 0), default=math.inf)
            )
            if self.power_limits is None:
                self.power_limits = self._read_power_limits()
            present = self._start_position()
            # The lift (trajgen.lift) comes first: the first frame drawn has set it.
            lift = getattr(stream, "lift", None)
            first_goal = np.asarray(sent_q(first) if lift is None else lift.goal[0], float)
            check_start(present, first_goal, self.max_approach_rad, self.joint_names)
            stats.read_every = self.telemetry_every
            t_ramp, q_ramp = min_jerk_ramp(present, first_goal, rate_hz, self.approach_speed_rad_s)
            stats.approach_frames = len(t_ramp)
            if lift is not None:
                stats.lift_frames, stats.lift_s = len(lift), lift.duration_s
            lifting = [] if lift is None else zip(lift.t, lift.goal, repeat(lift.q), repeat("lift"))
            with priority as stats.scheduling:
                if self.clock.real_time and self.probe_frames:
                    self._probe()
                approach = zip(t_ramp, q_ramp, q_ramp, repeat("approach"))
                self._loop(approach, timed=False)
                # A frame's goal (led ahead of the plan, trajgen.lead) is sent; its plan is
                # logged (during the lift, the plan's first point, which it holds).
                streamed = ((f.t, sent_q(f), f.q, "stream") for f in chain([first], frames))
                self._loop(chain(lifting, streamed), timed=True)
        except (DriverError, KeyboardInterrupt) as e:
            stats.fault = str(e) or type(e).__name__
            self.stop_errors = safe_stop(self.bus, self.joints.ids, self.on_stop, self.restore)
            raise
        finally:
            stats.comm_errors = self.bus.failed_tries - failed_before
            stats._finish()
            if writer is not None:
                writer.close()
        if planned == 0:
            stats.frames_planned = stats.frames_sent
        self.stop_errors = safe_stop(self.bus, self.joints.ids, self.on_stop, self.restore)
        return stats

    # -- reading -----------------------------------------------------------

    def _probe(self) -> None:
        """Time the stream's traffic before its first goal; refuse a rate it cannot carry.

        Raises
        ------
        StreamLagging
            If no read-back interval lets this host and bus keep the rate.
        """
        stats, ids = self.stats, self.joints.ids
        period_s = 1.0 / stats.rate_hz
        write_s = self.bus.wire_s(sync_write_bytes(len(ids), 4))  # Goal Position: 4 bytes

        def read():
            block = self.bus.read_block(ids, _STATE, fast=self._use_fast)
            self.bus.check_block(block, "probing the bus")

        read_bytes = self.bus.read_bytes(ids, _STATE, fast=self._use_fast)
        read_wire_s = self.bus.reply_s(read_bytes) + WIRE_MARGIN_S
        cost = probe_cycle(read, write_s, self.probe_frames).with_read_wire(read_wire_s)
        stats.probe_write_s, stats.probe_read_s = cost.write_s, cost.read_s
        every = read_every_for(cost, period_s, self.telemetry_every)
        n_late = cost.late(period_s)[0]
        late = ""  # said where the reads too late for the next goal are what decided
        by_median = read_every_for(cost.median_only(), period_s, self.telemetry_every)
        if n_late and by_median is not None and (every is None or every > by_median):
            late = (
                f"; {n_late} of {cost.frames} probe reads took more than "
                f"{1e3 * (cost.stall_bound_s(period_s) - cost.write_s):.2f} ms, past the "
                "stall bound of the goal that waits for the reply (those before it go out behind "
                "it)"
            )
        if every is None:
            most = (
                f"even reading back every {MAX_READ_EVERY}. frame"
                if late
                else f"about {max_rate_hz(cost, self.telemetry_every):.0f} Hz at most, reading "
                f"back every {self.telemetry_every}. frame"
            )
            raise StreamLagging(
                f"before the first goal: {cost.describe()}, and {stats.rate_hz:g} Hz leaves "
                f"{1e3 * period_s:.2f} ms a frame{late}: this host and bus cannot keep it "
                f"({most}); nothing was moved{self.bus.latency_advice()}"
            )
        if every > self.telemetry_every:
            self._warn(
                f"reading the servos back every {every} frames instead of every "
                f"{self.telemetry_every}: {cost.describe()}, and {stats.rate_hz:g} Hz leaves "
                f"{1e3 * period_s:.2f} ms a frame{late}{self.bus.latency_advice()}"
            )
            stats.read_every = every

    def _choose_read_method(self) -> None:
        if self.fast_read:
            try:
                self.bus.read_block(self.joints.ids, _STATE, fast=True)
                return
            except CommError as e:  # counted by the bus; try Sync Read
                reason = str(e)
            self.bus.read_block(self.joints.ids, _STATE, fast=False)
            self.stats.read_fallback = reason
            warnings.warn(
                f"fast sync read failed ({reason}); reading back by sync read for this stream "
                "(one status packet per servo: slower)",
                RuntimeWarning,
                stacklevel=3,
            )
        else:
            self.bus.read_block(self.joints.ids, _STATE, fast=False)
        self.stats.read_method = "sync read"

    @property
    def _use_fast(self) -> bool:
        return self.stats.read_method == "fast sync read"

    def _state_of(self, block, read_at: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present joint position (rad), velocity (rad/s), current (A), each (n,), of a
        state read (ERR bytes checked) asked at ``read_at`` (the stream's clock, s)."""
        self.stats.reads += 1
        raw = np.array(block.table, dtype=float)
        models = [self.bus.models[i] for i in self.joints.ids]
        rows = zip(models, block.table, strict=True)
        current = np.array([m.current_a(row[0]) for m, row in rows])
        return (
            self._plausible(raw[:, 2], read_at),
            self.joints.velocity_to_rad_s(raw[:, 1]),
            self.joints.signed_joint(current),
        )

    def _plausible(self, ticks: np.ndarray, now: float) -> np.ndarray:
        """Joint angles (rad) of a position read asked at ``now`` (s), NaN where it jumped
        implausibly far.

        A read is compared with the last plausible one: a servo cannot move
        faster than ``GLITCH_SPEED_FACTOR`` times its no-load speed.

        Raises
        ------
        ServoError
            After ``MAX_GLITCHES`` implausible reads in a row of one servo.
        """
        position = self.joints.to_rad(ticks)
        if self._last_position is None:
            self._last_position = (np.full(position.shape, now), position)
            return position
        then, last = self._last_position  # per joint: when and where it last read plausibly
        allowed = self._max_speed * np.maximum(now - then, 0.0)
        allowed += POSITION_NOISE_TICKS * RAD_PER_TICK
        jumped = np.abs(position - last) > allowed
        self._glitches = np.where(jumped, self._glitches + 1, 0)
        for j in np.flatnonzero(jumped):
            self.stats.position_glitches += 1
            who = f"servo {self.joints.ids[j]} ({self.joint_names[j]})"
            jump = math.degrees(position[j] - last[j])
            if self._glitches[j] >= MAX_GLITCHES:
                raise ServoError(
                    f"{who}: Present Position implausible {MAX_GLITCHES} reads in a row (the "
                    f"last {jump:+.1f} deg from the last plausible read, faster than it can "
                    f"move) at frame {self._frame_no}: encoder fault, or it was moved by force"
                )
            self._warn(
                f"{who}: Present Position jumped {jump:+.1f} deg in one read at frame "
                f"{self._frame_no}, faster than it can move: not trusted (left out of the "
                "telemetry)"
            )
        keep = ~jumped
        self._last_position = (np.where(keep, now, then), np.where(keep, position, last))
        return np.where(keep, position, math.nan)

    def _warn(self, message: str) -> None:
        """A ``RuntimeWarning`` during the stream, kept in ``stats.warnings`` (each once)."""
        key = message.split(" at frame ")[0]
        if any(w.split(" at frame ")[0] == key for w in self.stats.warnings):
            return
        self.stats.warnings.append(message)
        warnings.warn(message, RuntimeWarning, stacklevel=4)

    def _start_position(self) -> np.ndarray:
        """Joint angles (rad) the stream starts from; never one unchecked read.

        With ``start_ticks``: those goals, once a position read agrees with
        them (up to 3 reads). Without: the second of two reads that agree.

        Raises
        ------
        BringUpError
            If no read agrees.
        """
        reads = []
        for _ in range(3):
            ticks = self._raw_positions()
            reads.append(ticks)
            if self.start_ticks is not None:
                if np.all(np.abs(ticks - self.start_ticks) <= HOLD_TOLERANCE_TICKS):
                    return self.joints.to_rad(self.start_ticks)
            elif len(reads) >= 2 and np.all(np.abs(ticks - reads[-2]) <= POSITION_NOISE_TICKS):
                return self.joints.to_rad(ticks)
        reference = self.start_ticks if self.start_ticks is not None else reads[0]
        j = int(np.argmax(np.max(np.abs(np.array(reads) - reference), axis=0)))
        values = ", ".join(str(int(r[j])) for r in reads)
        against = (
            f"the Goal Position {int(self.start_ticks[j])} it held at torque on"
            if self.start_ticks is not None
            else "each other"
        )
        raise BringUpError(
            f"servo {self.joints.ids[j]} ({self.joint_names[j]}): Present Position reads "
            f"{values}, which do not agree with {against}; refusing to start from it"
        )

    def _raw_positions(self) -> np.ndarray:
        block = self.bus.read_block(self.joints.ids, _STATE, fast=self._use_fast)
        self.bus.check_block(block, "streaming")
        return np.array([block.values[i][Register.PRESENT_POSITION] for i in self.joints.ids])

    def _read_status(self) -> dict[int, dict[Register, int]]:
        block = self.bus.read_block(self.joints.ids, _STATUS, fast=self._use_fast)
        self.bus.check_block(block, "streaming")
        return block.values

    def _read_power_limits(self) -> tuple[PowerLimits, ...]:
        return tuple(
            PowerLimits.from_registers(*(self.bus.read(i, r) for r in _POWER_LIMITS))
            for i in self.joints.ids
        )

    def _health_of(self, block, power: tuple[np.ndarray, np.ndarray]) -> None:
        """Supply voltage (V) and temperature (deg C) of the servos of a health read (ERR
        bytes checked), checked against their limits and put into ``power`` (volts, temps).

        Raises
        ------
        ServoError
            If a servo is at its voltage or temperature stop margin.
        """
        ids = self.joints.ids
        for servo_id, values in block.values.items():
            j = ids.index(servo_id)
            volts = power[0][j] = values[_POWER[0]] * VOLTAGE_UNIT_V
            temps = power[1][j] = float(values[_POWER[1]])
            who = f"servo {servo_id} ({self.joint_names[j]})"
            problem = health_problem(who, self.power_limits[j], volts, temps)
            if problem is not None and problem[0] == "stop":
                raise ServoError(f"{problem[1]} (frame {self._frame_no})")
            if problem is not None:
                self._warn(f"{problem[1]} at frame {self._frame_no}")

    def _poll_watchdog(self, when: str) -> None:
        """Torque, hardware error and Bus Watchdog of every servo, against the start
        (``_status_of``)."""
        self._status_of(self._read_status(), when)

    def _status_of(self, status: dict[int, dict[Register, int]], when: str) -> None:
        """The registers of a status read (ERR bytes checked) against the start.

        Raises
        ------
        WatchdogTripped
            If a Bus Watchdog reads -1.
        ServoReset
            If a servo's torque went off or its Bus Watchdog changed: it
            rebooted (RAM reset) or shut down.
        ServoError
            If a servo reports a hardware error (Alert bit).
        """
        for servo_id, read in status.items():
            j = self.joints.ids.index(servo_id)
            start = self._status_at_start[servo_id]
            values = {**start, **read}  # a part of the poll: what it did not read is as it was
            who = f"servo {servo_id} ({self.joint_names[j]})"
            watchdog = values[Register.BUS_WATCHDOG]
            if watchdog == -1:
                raise WatchdogTripped(
                    f"servo {servo_id}: Bus Watchdog tripped (register 98 = -1) {when} "
                    f"frame {self._frame_no}: it stopped and refuses goals until the watchdog is "
                    "cleared (the bus was silent longer than its watchdog period)"
                )
            torque, torque_was = values[Register.TORQUE_ENABLE], start[Register.TORQUE_ENABLE]
            if watchdog != start[Register.BUS_WATCHDOG] or torque != torque_was:
                raise ServoReset(
                    f"{who} reset itself {when} frame {self._frame_no}: Torque Enable "
                    f"{torque} (was {torque_was}), Bus Watchdog {watchdog} (was "
                    f"{start[Register.BUS_WATCHDOG]}): it rebooted or lost power (its RAM "
                    "is back to the defaults) and does not hold its goal"
                )

    # -- the loop ----------------------------------------------------------

    def _check_bounds(self, ticks: np.ndarray, t: float) -> None:
        bounds = self.goal_bounds_ticks
        if bounds is None:
            return
        outside = (ticks < bounds[:, 0]) | (ticks > bounds[:, 1])
        if outside.any():
            j = int(np.flatnonzero(outside)[0])
            raise OutsideLimits(
                f"{self.joint_names[j]}: goal tick {ticks[j]} at t = {t:.3f} s is outside "
                f"{bounds[j, 0]}..{bounds[j, 1]} (servo {self.joints.ids[j]}'s position limits); "
                "not sent"
            )

    def _frame_reads(self, period_s: float) -> FrameReads:
        """What each frame of a phase reads (``drivers.frame_reads``).

        On the wall clock a frame's goal write and reads fit ``BUDGET`` of its
        period: each read costs its wire time and what the probe found the
        host and adapter add to a read (``stats.probe_read_s`` less the state
        read's wire time); the polls go in parts where needed. A part fits
        where its bytes do: where goals go out behind a reply (a wire, not
        lock-step: ``_loop``), the bytes whose reply leaves the wire, with
        ``WIRE_MARGIN_S``, before the next deadline (the host's time for a
        read then delays the reply's check, not the next goal); otherwise those
        of the budget less that time. On a simulated clock time is not short:
        every read due goes in its frame.
        """
        ids, bus, fast, stats = self.joints.ids, self.bus, self._use_fast, self.stats
        room_s = part_s = math.inf  # a frame's time for reads, and for one read's bytes (s)
        extra_s = 0.0  # what a read costs besides its wire time (s)
        if self.clock.real_time:
            goal_s = bus.wire_s(sync_write_bytes(len(ids), 4))
            room_s = BUDGET * period_s - goal_s
            if not math.isnan(stats.probe_read_s):
                wire_s = bus.wire_s(bus.read_bytes(ids, _STATE, fast=fast))
                extra_s = max(0.0, stats.probe_read_s - wire_s)
            part_s = room_s - extra_s
            if not bus.lockstep:
                part_s = max(part_s, period_s - goal_s - bus.reply_s(0) - WIRE_MARGIN_S)

        def size(part_ids, registers):
            return bus.read_bytes(part_ids, registers, fast=fast)

        def cost(read):
            return bus.wire_s(read.n_bytes) + extra_s

        room_b = part_s * bus.baud / 10  # bytes of one read that fit
        return FrameReads(
            Read("state", ids, _STATE, size(ids, _STATE)),  # never split: the probe's part
            parts("status", ids, _STATUS, size, room_b),
            parts("health", ids, _POWER, size, room_b, by_register=False),
            cost,
            room_s,
            stats.read_every,
            max(1, round(self.poll_s * stats.rate_hz)),
            max(1, round(self.health_s * stats.rate_hz)),
        )

    def _loop(self, frames, *, timed: bool) -> None:
        """Send ``frames``, ``(t, goal, plan, phase)`` each, one per period.

        A frame: collect the reply of the last frame's split-phase read as soon
        as it is in (``ServoBus.await_reply``, then ``_take``); wait for the
        frame's deadline; shift the clock after a stall; send the goal; write
        the last frame's telemetry row; then this frame's reads
        (``_frame_reads``), all but the last at once, the last split-phase.

        On the wall clock a goal waits for the wire, not for the reply: a reply
        not in hand at the deadline whose computed wire end has passed (with
        ``bus.WIRE_MARGIN_S``; if not, the goal waits for it) is left
        outstanding, the goal goes out behind it (``ServoBus.sync_write(behind=)``),
        and the reply is collected and checked right after it, exactly as
        before and before anything else is sent, if it is in by then. If it is
        not (the adapter or the pty still holds it), it is carried to the next
        frame: checked there as soon as it is in, before that frame's goal or
        right after it, until ``REPLY_WAIT_S`` past its wire end; the goal after
        that waits for it (or its timeout: a failed try). The trade: a fault in
        that reply is acted on up to ``REPLY_WAIT_S`` and a period later, and a
        servo answering later than computed collides with the goal on a
        half-duplex bus (both garbled: the servos drop the goal by its CRC and
        hold the previous one a period; the reply is a failed try, retried as
        any other). While a reply is carried, the frames defer their reads
        (``FrameReads.defer``), and a frame whose goal went out behind a reply
        defers those that no longer fit before the next deadline: never two
        requests in flight. A stall first collects an outstanding reply. On a
        simulated clock every reply is collected before the next goal.
        """
        stats = self.stats
        ids = self.joints.ids
        n = len(ids)
        period = 1.0 / stats.rate_hz
        stall_s = 0.5 * period if self.stall_s is None else self.stall_s
        schedule = self._frame_reads(period)
        clock = self.clock
        start = clock.now() + period
        shift = 0.0  # this phase's clock shift (s), from stalls
        t_first = None
        pending = None  # (PendingRead, Read, its frame's row, asked at): the read outstanding
        rows = []  # telemetry rows not written yet (the last frame's waits for its read)
        # A goal may go out behind a reply (the bus's own clock, a wire: not lock-step).
        wire = clock.real_time and not self.bus.lockstep
        try:
            for k, (t, q, plan, phase) in enumerate(frames):
                t_first = t if t_first is None else t_first
                planned = start + (t - t_first)
                due = planned + shift
                replied = -math.inf  # how late (s) the goal could go for the wire, if it waited
                behind = None  # the last frame's read, its reply outstanding behind this goal
                if pending is not None:
                    pending, (waiting, read, row, asked) = None, pending
                    # Taken as soon as it is in, the core free meanwhile (wall clock).
                    if clock.real_time and not self.bus.await_reply(waiting, due) and wire:
                        behind = (waiting, read, row, asked)
                        wire_left = self.bus.reply_wire_end(waiting) - time.monotonic()
                        replied = clock.now() + wire_left - due
                    else:
                        self._take(*self._collected((waiting, read, row, asked)))
                        replied = clock.now() - due
                clock.sleep_until(due if behind is None else max(due, due + replied))
                late = clock.now() - due
                if late > stall_s:  # never catch up: shift the rest of the stream instead
                    if behind is not None:  # in by now (or timed out): the stall's poll may send
                        self._take(*self._collected(behind))
                        behind = None
                    stats.reply_stalls += int(replied > stall_s)  # an int for JSON, not np.int64
                    self._stall(late)
                    stats.delay_s += clock.now() - planned - shift
                    shift = clock.now() - planned
                sent = clock.now()
                ticks = self.joints.to_ticks(q)
                self._check_bounds(ticks, t)
                self.bus.sync_write(
                    Register.GOAL_POSITION,
                    dict(zip(ids, ticks.tolist(), strict=True)),
                    behind=None if behind is None else behind[0],
                )
                self._frame_no += 1
                if timed:
                    stats._sent(sent, planned, planned + shift, phase == "stream")
                # The goal went out: its row is written even if a read fails.
                row = None  # (frame columns, state (3, n), power (2, n)), with a telemetry file
                if self._writer is not None:
                    head = [self._frame_no - 1, phase, t, sent - start, sent - planned - shift]
                    row = (head + [sent, *plan, *q, *ticks.tolist()], _nans(3, n), _nans(2, n))
                    rows.append(row)
                if behind is not None:  # its reply, before anything else is sent, if it is in
                    stats.goals_behind += 1
                    self._behind_goal = behind[0]
                    if self._carried(behind[0]):
                        pending, behind = behind, None
                        stats.replies_carried += 1
                    else:
                        self._take(*self._collected(behind))
                self._write_rows(
                    rows, keep=_waiting_rows(rows, row if pending is None else pending[2])
                )
                reads = schedule.for_frame(k)
                if reads and (
                    pending is not None
                    or (behind is not None and not self._fits(schedule, reads, due + period))
                ):
                    schedule.defer(reads)
                    reads = []
                for j, read in enumerate(reads):
                    asked = clock.now()
                    if j < len(reads) - 1:
                        block = self.bus.read_block(read.ids, read.registers, fast=self._use_fast)
                        self._take(read, block, row, asked)
                    else:
                        waiting = self.bus.request_block(
                            read.ids, read.registers, fast=self._use_fast
                        )
                        pending = (waiting, read, row, asked)
            if pending is not None:
                pending, outstanding = None, pending
                self._take(*self._collected(outstanding))
        finally:
            stats.reads_skipped += schedule.skipped
            stats.reads_deferred += schedule.deferred
            self._write_rows(rows)

    def _collected(self, outstanding: tuple) -> tuple:
        """``_take``'s arguments for an outstanding read ``(pending, read, row, asked)``:
        its reply collected (``ServoBus.collect``: checked, retried)."""
        waiting, read, row, asked = outstanding
        block = self.bus.collect(waiting)
        if waiting is self._behind_goal:  # a goal went out behind it: how late it is checked
            late_s = time.monotonic() - waiting.wire_end_s
            self.stats.reply_check_max_s = max(self.stats.reply_check_max_s, late_s)
        return read, block, row, asked

    def _carried(self, waiting) -> bool:
        """Whether the outstanding ``waiting`` (``PendingRead``) is carried to the next
        frame: its reply not in yet, ``REPLY_WAIT_S`` past its wire end not reached (nor
        its timeout)."""
        until_s = min(waiting.wire_end_s + REPLY_WAIT_S, waiting.deadline_s)
        return time.monotonic() < until_s and not self.bus.await_reply(waiting, -math.inf)

    def _fits(self, schedule: FrameReads, reads: Sequence[Read], until_s: float) -> bool:
        """Whether ``reads``, sent now, leave the bus free by ``until_s`` (the clock's s):
        all but the last read at once (``schedule.cost``), the last one's reply off the
        wire (with margin)."""
        bus = self.bus
        at_once = sum(schedule.cost(r) for r in reads[:-1])
        last = bus.reply_s(reads[-1].n_bytes) + WIRE_MARGIN_S
        return self.clock.now() + at_once + last <= until_s

    def _take(self, read, block, row, asked: float) -> None:
        """A frame's read, in: ERR bytes checked, then what it is for (into ``row``, if any)."""
        self.bus.check_block(block, "streaming")
        if read.kind == "state":
            state = self._state_of(block, asked)
            if row is not None:
                row[1][:] = state
        elif read.kind == "status":
            self._status_of(block.values, "before")
        else:
            self._health_of(block, _nans(2, len(self.joints)) if row is None else row[2])

    def _write_rows(self, rows: list, keep: int = 0) -> None:
        """Write the telemetry rows (frame columns, state (3, n), power (2, n)) but the last
        ``keep``, and forget them."""
        done = len(rows) - keep
        if self._writer is not None:
            for head, state, power in rows[:done]:
                self._writer.write(head + state.ravel().tolist() + power.ravel().tolist())
        del rows[:done]

    def _stall(self, late_s: float) -> None:
        """A frame is ``late_s`` past its deadline: count it, check the servos, bound the delay."""
        stats = self.stats
        stats.stalls += 1
        stats.stall_max_s = max(stats.stall_max_s, late_s)
        if self.max_delay_s is not None and stats.delay_s + late_s > self.max_delay_s:
            stats.delay_s += late_s
            raise StreamLagging(
                f"the stream fell {stats.delay_s:.3f} s behind its plan (bound "
                f"{self.max_delay_s:g} s) after {stats.stalls} stalls, the last "
                f"{1e3 * late_s:.1f} ms before frame {self._frame_no}: the host or the bus cannot "
                f"keep {stats.rate_hz:g} Hz"
            )
        if late_s + 1.0 / stats.rate_hz >= self._watchdog_risk_s:  # the bus was that silent
            self._poll_watchdog(f"after a {1e3 * late_s:.1f} ms stall, before")


def _waiting_rows(rows: list, first) -> int:
    """How many of the telemetry ``rows`` (the last ones) wait for a read: those from
    ``first`` (a row, by identity; None: none wait) on."""
    for i, row in enumerate(rows):
        if row is first:
            return len(rows) - i
    return 0


def _nans(rows: int, n: int) -> np.ndarray:
    return np.full((rows, n), math.nan)


def safe_stop(bus: ServoBus, ids: Sequence[int], on_stop: str, restore: Sequence = ()) -> list[str]:
    """Hold the last goal (clear the Bus Watchdog) or release the servos (torque off).

    Best effort, one try per servo. Then, if ``restore`` lists changes, write
    back what bring-up changed (``drivers.bringup.restore_settings``).

    Parameters
    ----------
    bus : ServoBus
    ids : sequence of int
    on_stop : {"hold", "torque_off"}
    restore : sequence of Change, optional

    Returns
    -------
    list of str
        What could not be done (e.g. a servo that no longer answers, a
        setting left changed).
    """
    errors = []
    retries, bus.retries = bus.retries, 0
    try:
        for servo_id in ids:
            try:
                if on_stop == "torque_off":
                    bus.write(servo_id, Register.TORQUE_ENABLE, 0)
                else:
                    bus.write(servo_id, Register.BUS_WATCHDOG, 0)
            except DriverError as e:
                errors.append(str(e))
    finally:
        bus.retries = retries
    if restore:
        errors += restore_settings(bus, restore)
    return errors
