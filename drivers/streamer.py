"""Streaming a joint trajectory to the servos at a fixed rate.

Each frame's deadline is absolute: ``start + (frame.t - first.t)`` on the
stream's clock (``time.monotonic`` by default), so a late frame does not push
the later ones (no drift).
Per frame: one Sync Write of Goal Position. Every ``telemetry_every`` frames:
one group read of present current, velocity and position (Fast Sync Read, or
Sync Read where the servos do not answer it), whose ERR bytes reveal a
hardware error (Alert bit). About every ``poll_s``: a group read of the Bus
Watchdog. Any fault stops the stream safely: the servos hold their last goal
(or, with ``on_stop="torque_off"``, are released) and the telemetry so far
stays on disk.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field
from itertools import chain
from pathlib import Path
from typing import Literal

import numpy as np

from trajgen.drivers.bus import ServoBus
from trajgen.drivers.clock import WALL_CLOCK
from trajgen.drivers.control_table import Register
from trajgen.drivers.errors import CommError, DriverError, WatchdogTripped
from trajgen.drivers.telemetry import TelemetryWriter
from trajgen.drivers.units import JointMap
from trajgen.gimbal import JOINT_NAMES
from trajgen.validate import check_choice, check_number

_STATE = (Register.PRESENT_CURRENT, Register.PRESENT_VELOCITY, Register.PRESENT_POSITION)


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
    achieved_rate_hz : float
        ``rate_hz`` times planned over actual time between the first and last
        frame sent (NaN with fewer than two frames).
    period_error_p50_s, period_error_p99_s, period_error_max_s : float
        Absolute error of each interval between frames sent, against its
        planned interval (s).
    lateness_max_s : float
        Largest delay of a frame past its deadline (s).
    overruns : int
        Frames sent more than one period after their deadline.
    reads : int
        Telemetry group reads done.
    comm_errors : int
        Transactions that failed (retried, or fatal).
    read_method : str
        "fast sync read" or "sync read".
    fault : str
        The message of the fault that stopped the stream ("" if none).
    """

    rate_hz: float
    frames_planned: int
    frames_sent: int = 0
    approach_frames: int = 0
    achieved_rate_hz: float = math.nan
    period_error_p50_s: float = math.nan
    period_error_p99_s: float = math.nan
    period_error_max_s: float = math.nan
    lateness_max_s: float = math.nan
    overruns: int = 0
    reads: int = 0
    comm_errors: int = 0
    read_method: str = "fast sync read"
    fault: str = ""
    _sent_s: list[float] = field(default_factory=list, repr=False)
    _deadline_s: list[float] = field(default_factory=list, repr=False)

    def _finish(self) -> None:
        sent, deadline = np.asarray(self._sent_s), np.asarray(self._deadline_s)
        self.frames_sent = len(sent)
        if len(sent) == 0:
            return
        self.lateness_max_s = float(np.max(sent - deadline))
        if len(sent) >= 2:
            error = np.abs(np.diff(sent) - np.diff(deadline))
            self.period_error_p50_s = float(np.percentile(error, 50))
            self.period_error_p99_s = float(np.percentile(error, 99))
            self.period_error_max_s = float(np.max(error))
            planned, actual = deadline[-1] - deadline[0], sent[-1] - sent[0]
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
            f"(+{self.approach_frames} approach) at {self.rate_hz:g} Hz planned, "
            + (
                "n/a achieved"
                if math.isnan(self.achieved_rate_hz)
                else f"{self.achieved_rate_hz:.2f} Hz achieved"
            ),
            f"period error: p50 {ms(self.period_error_p50_s)}, p99 {ms(self.period_error_p99_s)}, "
            f"max {ms(self.period_error_max_s)}; max lateness {ms(self.lateness_max_s)}; "
            f"overruns: {self.overruns}",
            f"telemetry reads: {self.reads} ({self.read_method}); comm errors: {self.comm_errors}",
        ]
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
        ``.csv`` or ``.npz`` file for per-frame telemetry.
    joint_names : sequence of str, optional
        Column names of the joints in the telemetry.
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
        Try Fast Sync Read first (falls back to Sync Read if it gets no answer).
    clock : object with ``now()`` and ``sleep_until(deadline_s)``, optional
        What the deadlines run on: the host's monotonic clock, or a
        ``drivers.clock.SimulatedClock`` against a lock-step virtual bus (the
        stream then runs as fast as the simulation allows).

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
        joint_names: Iterable[str] = JOINT_NAMES,
        telemetry_every: int = 1,
        poll_s: float = 0.05,
        on_stop: Literal["hold", "torque_off"] = "hold",
        approach_speed_rad_s: float = 0.5,
        fast_read: bool = True,
        clock=WALL_CLOCK,
    ) -> None:
        telemetry_every = check_number("telemetry_every", telemetry_every, integer=True, low=1)
        check_choice("on_stop", on_stop, ("hold", "torque_off"))
        poll_s = check_number("poll_s", poll_s, low=0.0, low_open=True)
        approach_speed_rad_s = check_number(
            "approach_speed_rad_s", approach_speed_rad_s, low=0.0, low_open=True
        )
        self.bus = bus
        self.joints = joints
        self.telemetry_path = telemetry
        self.joint_names = tuple(joint_names)
        self.telemetry_every = telemetry_every
        self.poll_s = poll_s
        self.on_stop = on_stop
        self.approach_speed_rad_s = approach_speed_rad_s
        self.fast_read = fast_read
        self.clock = clock
        self.stats: StreamStats | None = None
        self.stop_errors: list[str] = []

    def run(self, stream, *, rate_hz: float | None = None) -> StreamStats:
        """Move to the first frame smoothly, then stream every frame.

        Parameters
        ----------
        stream : JointTrajectory or iterable of JointFrame
            Frames with ``t`` (s) and ``q`` (rad, shape (n,)).
        rate_hz : float, optional
            Stream rate (Hz); default ``stream.rate_hz``.

        Returns
        -------
        StreamStats

        Raises
        ------
        ValueError
            If no rate is known or the stream is empty.
        CommError, ServoError, WatchdogTripped
            On a fault, after the safe stop; ``self.stats`` holds the statistics
            and ``self.stop_errors`` anything the safe stop could not do.
        KeyboardInterrupt
            On Ctrl-C, after the safe stop.
        """
        rate_hz = getattr(stream, "rate_hz", None) if rate_hz is None else rate_hz
        if rate_hz is None or not rate_hz > 0:
            raise ValueError(f"Expected a positive `rate_hz` (or stream.rate_hz), got {rate_hz}.")
        frames: Iterator = iter(stream)
        try:
            first = next(frames)
        except StopIteration:
            raise ValueError("Expected a non-empty stream, got no frames.") from None
        planned = len(stream) if hasattr(stream, "__len__") else 0
        self.stats = stats = StreamStats(rate_hz=float(rate_hz), frames_planned=planned)
        self.stop_errors = []
        writer = None
        if self.telemetry_path is not None:
            writer = TelemetryWriter(self.telemetry_path, self.joint_names)
        self._writer = writer
        self._frame_no = 0
        failed_before = self.bus.failed_tries
        try:
            self._choose_read_method()
            present = self._read_state()[0]
            t_ramp, q_ramp = min_jerk_ramp(
                present, np.asarray(first.q, float), rate_hz, self.approach_speed_rad_s
            )
            stats.approach_frames = len(t_ramp)
            self._loop(zip(t_ramp, q_ramp, strict=True), "approach", None)
            self._loop(((f.t, f.q) for f in chain([first], frames)), "stream", stats)
        except (DriverError, KeyboardInterrupt) as e:
            stats.fault = str(e) or type(e).__name__
            self._safe_stop()
            raise
        finally:
            stats.comm_errors = self.bus.failed_tries - failed_before
            stats._finish()
            if writer is not None:
                writer.close()
        if planned == 0:
            stats.frames_planned = stats.frames_sent
        self._safe_stop()
        return stats

    # -- reading -----------------------------------------------------------

    def _choose_read_method(self) -> None:
        if self.fast_read:
            try:
                self.bus.read_block(self.joints.ids, _STATE, fast=True)
                return
            except CommError:
                pass  # counted by the bus; try Sync Read
        self.bus.read_block(self.joints.ids, _STATE, fast=False)
        self.stats.read_method = "sync read"

    @property
    def _use_fast(self) -> bool:
        return self.stats.read_method == "fast sync read"

    def _read_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present joint position (rad), velocity (rad/s), current (A), each (n,)."""
        block = self.bus.read_block(self.joints.ids, _STATE, fast=self._use_fast)
        self.bus.check_block(block, "streaming")
        self.stats.reads += 1
        ids = self.joints.ids
        raw = np.array([[block.values[i][r] for r in _STATE] for i in ids], dtype=float)
        current = np.array([self.bus.models[i].current_a(block.values[i][_STATE[0]]) for i in ids])
        return (
            self.joints.to_rad(raw[:, 2]),
            self.joints.velocity_to_rad_s(raw[:, 1]),
            self.joints.signed_joint(current),
        )

    def _poll_watchdog(self) -> None:
        block = self.bus.read_block(self.joints.ids, (Register.BUS_WATCHDOG,), fast=self._use_fast)
        self.bus.check_block(block, "streaming")
        for servo_id, values in block.values.items():
            if values[Register.BUS_WATCHDOG] == -1:
                raise WatchdogTripped(
                    f"servo {servo_id}: Bus Watchdog tripped (register 98 = -1) before frame "
                    f"{self._frame_no}: it stopped and refuses goals until the watchdog is "
                    "cleared (the bus was silent longer than its watchdog period)"
                )

    # -- the loop ----------------------------------------------------------

    def _loop(self, frames, phase: str, stats: StreamStats | None) -> None:
        ids = self.joints.ids
        period = 1.0 / self.stats.rate_hz
        poll_every = max(1, round(self.poll_s * self.stats.rate_hz))
        start = self.clock.now() + period
        t_first = None
        nan = np.full(len(ids), math.nan)
        for k, (t, q) in enumerate(frames):
            t_first = t if t_first is None else t_first
            deadline = start + (t - t_first)
            self.clock.sleep_until(deadline)
            sent = self.clock.now()
            ticks = self.joints.to_ticks(q)
            self.bus.sync_write(Register.GOAL_POSITION, dict(zip(ids, ticks.tolist(), strict=True)))
            self._frame_no += 1
            if stats is not None:
                stats._sent_s.append(sent)
                stats._deadline_s.append(deadline)
                if sent - deadline > period:
                    stats.overruns += 1
            state = (nan, nan, nan)
            try:
                if k % self.telemetry_every == 0:
                    state = self._read_state()
                if k % poll_every == poll_every - 1:
                    self._poll_watchdog()
            finally:  # the goal went out: its row is written even if the read failed
                if self._writer is not None:
                    self._writer.write(
                        [self._frame_no - 1, phase, t, sent - start, sent - deadline]
                        + list(q)
                        + ticks.tolist()
                        + [*state[0], *state[1], *state[2]]
                    )

    def _safe_stop(self) -> None:
        """Hold the last goal (clear the Bus Watchdog) or release the servos.

        Best effort, one try per servo: what fails is kept in ``stop_errors``.
        """
        retries, self.bus.retries = self.bus.retries, 0
        try:
            for servo_id in self.joints.ids:
                try:
                    if self.on_stop == "torque_off":
                        self.bus.write(servo_id, Register.TORQUE_ENABLE, 0)
                    else:
                        self.bus.write(servo_id, Register.BUS_WATCHDOG, 0)
                except DriverError as e:
                    self.stop_errors.append(str(e))
        finally:
            self.bus.retries = retries
