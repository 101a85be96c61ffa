"""A streaming session: a plan in; the port (or a virtual bus) opened, the servos
brought up, the stream sent, the servos stopped safely; an outcome out.

:class:`Session` is what ``trajgen stream``, ``trajgen excite`` and ``trajgen
follow`` run, for a Python program to run without the command line::

    from trajgen.drivers.config import BusConfig
    from trajgen.drivers.session import Session

    outcome = Session(BusConfig(port="/dev/ttyUSB0")).stream_path(spline, rate_hz=200)
    print(outcome.stats.format(), outcome.servo_states)

Stages, in order: open the port (or start a virtual bus on a pseudo-terminal,
in lock-step with the stream, around a plant); bring up (``bringup.bring_up``:
every check before any servo is changed; the plan made from where the servos
are); stream (``streamer.Streamer``: the approach, then one frame per period);
on every stop (the end, a fault, a stop signal) the servos hold their last goal
or are released, per servo, and the port closes. SIGINT, SIGTERM and SIGHUP
stop the stream while the servos are being touched (``signals.StopSignals``);
their number is in the outcome.

Nothing here reads a file or prints: the command line does both.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from trajgen.gimbal import JOINT_NAMES
from trajgen.stream import plan_joint_trajectory

from . import bringup
from .bringup import MAX_APPROACH_RAD, BringUp, JointRange
from .clock import WALL_CLOCK, PacedClock
from .config import BusConfig
from .defaults import MAX_DELAY_S
from .errors import BadArgument, BringUpError, DriverError, Interrupted
from .signals import StopSignals
from .streamer import Streamer, safe_stop

#: What a servo was left doing, per ``Outcome.servo_states``.
UNTOUCHED = "untouched"  # nothing was written to it
NOT_MOVED = "not moved"  # bring-up refused before torque on
HOLDING = "holding"  # reads torque on after the safe stop: it holds its last goal
RELEASED = "released"  # reads torque off after the safe stop
UNKNOWN = "unknown"  # did not answer after the safe stop: see ``stop_errors``
OFF_BY_ITSELF = "off by itself"  # torque off although it was driven: rebooted, shut down


@dataclass
class Outcome:
    """What a session did, filled in as its stages run.

    Attributes
    ----------
    stopped_by : str
        Why the stream ended early ("" if it ran to its end).
    signal : int or None
        The stop signal that ended it (the command line exits ``128 + signal``).
    stage : str
        Where it stopped early: "open" (the port did not open), "bring-up",
        "stream"; "" if it did not.
    bring_up : BringUp or None
        What bring-up found and set (None if it did not finish).
    stats : StreamStats or None
        The streamer's statistics (also after a fault).
    stop_errors : list of str
        What the safe stop could not do.
    servo_states : dict of int to str
        Per servo id: ``UNTOUCHED``, ``NOT_MOVED``, or after a safe stop its
        state as read back, ``HOLDING``, ``RELEASED``, ``OFF_BY_ITSELF``
        (``UNKNOWN`` if it did not answer soundly).
    servos : tuple of drivers.outcome.ServoOutcome
        The same after a safe stop, with the goal held and the likely cause of a
        silence (``format()`` gives one line per servo); empty when not read back.
    trajectory : JointTrajectory or JointRange or None
        The plan bring-up checked (for a stream, what was streamed).
    virtual_error : Exception or None
        What stopped the virtual bus, if it failed.
    joint_names : tuple of str
        The joints' names, in the order of the session's ids (``BusConfig.joint_names``).
    clock : object or None
        What the stream ran on when the session chose it (``Session.follow``: a
        ``drivers.clock.PacedClock`` on a virtual bus, whose ``format()`` says how far
        simulated time fell behind the wall clock); None otherwise.
    """

    stopped_by: str = ""
    signal: int | None = None
    stage: str = ""
    bring_up: BringUp | None = None
    stats: object = None
    stop_errors: list[str] = field(default_factory=list)
    servo_states: dict[int, str] = field(default_factory=dict)
    servos: tuple = ()
    trajectory: object = None
    virtual_error: Exception | None = None
    joint_names: tuple[str, ...] = JOINT_NAMES
    clock: object = None

    @property
    def ok(self) -> bool:
        """Whether the stream ran to its end."""
        return not self.stopped_by

    @property
    def refused(self) -> bool:
        """Whether bring-up refused the plan before any servo moved."""
        return (
            self.stage == "bring-up"
            and bool(self.servo_states)
            and all(s in (NOT_MOVED, UNTOUCHED) for s in self.servo_states.values())
        )

    def to_json_dict(self, joint_names=None) -> dict:
        """What happened, as plain JSON types: ``stopped_by``, ``signal``, ``stage``,
        ``stop_errors``, ``servos`` (state per servo id), ``servo_outcomes`` (per joint, as
        read back), ``changes`` (what bring-up wrote), ``bring_up`` and ``stream``."""
        return {
            "stopped_by": self.stopped_by,
            "signal": self.signal,
            "stage": self.stage,
            "stop_errors": self.stop_errors,
            "servos": {str(i): s for i, s in self.servo_states.items()},
            "servo_outcomes": {o.joint: o.to_json_dict() for o in self.servos},
            "changes": []
            if self.bring_up is None
            else [c.describe() for c in self.bring_up.changes],
            "bring_up": self.bring_up_summary(joint_names or self.joint_names),
            "stream": None if self.stats is None else self.stats.to_json_dict(),
        }

    def bring_up_summary(self, joint_names=None) -> dict | None:
        """Per joint (default :attr:`joint_names`): servo id, Drive Mode, Operating Mode,
        position limits and start tick."""
        setup = self.bring_up
        if setup is None:
            return None
        return {
            joint: {
                "servo": s.servo_id,
                "drive_mode": s.drive_mode,
                "operating_mode": mode,
                "position_limits": [int(low), int(high)],
                "start_tick": int(tick),
            }
            for joint, s, mode, (low, high), tick in zip(
                joint_names or self.joint_names,
                setup.installed,
                setup.operating_modes,
                setup.limits_ticks,
                setup.present_ticks,
                strict=True,
            )
        }


class Session:
    """Stream joint frames to the servos of one bus, from bring-up to a safe stop.

    Parameters
    ----------
    config : BusConfig, optional
        Port, baud rate, joint map (ids, directions, zeros), models and Bus
        Watchdog period; default ``BusConfig()`` (ids 1, 2, 3, no port).
    on_stop : {"hold", "torque_off"}, optional
        What the servos do when the stream stops, however it stops.
    telemetry : str or Path, optional
        Per-frame telemetry file (``.csv``, ``.npz`` or ``.mcap``).
    max_delay_s : float or None, optional
        Fail the stream once host stalls put it this far (s) behind its plan.
    max_approach_rad : float, optional
        Refuse to start when a joint is farther (rad) than this from the first frame.
    set_limits_rad : mapping of int to (float, float), optional
        Joint index -> (low, high) joint angles (rad) to write as that servo's
        Min / Max Position Limit during bring-up; the user's explicit choice.
        Without it the installed limits are only read.
    plant : drivers.virtual.plant.Plant, optional
        Stream to a virtual bus around this plant (e.g. ``sim.plant.GimbalPlant``)
        instead of ``config.port``; the bus advances one period per frame.
    plant_registers : sequence or mapping of dict, optional
        With ``plant``: register values at power-up, per joint (as
        ``GimbalPlant.initial_registers()`` gives them) or per servo id.
    stop_signals : StopSignals, optional
        Stop signals the caller has installed (and may act on around the
        session); default a new one, installed for each run (on the main thread).
    leader : optional
        Leads the goals ahead of the plan by the servos' lag (``trajgen.sim.lead.Leader``:
        ``trajectory(planned)`` attaches the goals to a planned stream,
        ``frames(frames, rate_hz, bounds_rad)`` leads a live one); None sends the
        plan as it is. Bring-up checks, and the streamer sends, the goals.

    Raises
    ------
    ValueError
        If a ``set_limits_rad`` entry falls outside the registers' range 0..4095
        (the message names the joint).
    """

    def __init__(
        self,
        config: BusConfig | None = None,
        *,
        on_stop: Literal["hold", "torque_off"] = "hold",
        telemetry: str | Path | None = None,
        max_delay_s: float | None = MAX_DELAY_S,
        max_approach_rad: float = MAX_APPROACH_RAD,
        set_limits_rad: Mapping[int, tuple[float, float]] | None = None,
        plant=None,
        plant_registers=None,
        stop_signals: StopSignals | None = None,
        leader=None,
    ) -> None:
        self.config = BusConfig() if config is None else config
        self.leader = leader
        self.on_stop = on_stop
        self.telemetry = telemetry
        self.max_delay_s = max_delay_s
        self.max_approach_rad = float(max_approach_rad)
        self.plant = plant
        if plant_registers is not None and not isinstance(plant_registers, Mapping):
            plant_registers = dict(zip(self.config.joints.ids, plant_registers, strict=True))
        self.plant_registers = plant_registers
        self.stop_signals = stop_signals
        joints = self.config.joints
        self.set_limits: dict[int, tuple[int, int]] = {}
        for j, (low, high) in (set_limits_rad or {}).items():
            try:
                self.set_limits[joints.ids[j]] = joints.limit_ticks(j, low, high)
            except ValueError as e:
                name = self.config.joint_names[j]
                raise BadArgument(f"{name} limits: {e}") from None

    # -- the two kinds of stream -------------------------------------------

    def stream_path(self, path, rate_hz: float, *, kinematics=None, clock=None) -> Outcome:
        """Stream an orientation path, planned from where the servos are.

        Parameters
        ----------
        path : spline-like
            ``t_start``, ``t_end`` (s), ``evaluate(t, max_order=2)`` (a ``BlendingSpline``).
        rate_hz : float
            Stream rate (Hz).
        kinematics : GimbalKinematics, optional
            Joint limits and the gimbal-lock margin.
        clock : optional
            Default simulated time with a virtual bus (lock-step, as fast as the
            simulation runs), else the wall clock.

        Returns
        -------
        Outcome

        Raises
        ------
        KinematicsError
            If the path, planned from the present position, leaves the joint
            limits or nears gimbal lock (nothing was changed on any servo).
        """

        def plan(present):
            # From where the servos are: pan and roll take the nearest 2 pi branch,
            # so the move to the first frame never unwinds a turn.
            planned = plan_joint_trajectory(path, rate_hz, kinematics, start=present)
            # Led goals attached (bring-up checks and the streamer sends them).
            return planned if self.leader is None else self.leader.trajectory(planned)

        return self.run(plan, rate_hz, clock=clock)

    def run(
        self,
        plan,
        rate_hz: float,
        *,
        frames: Callable[[BringUp], Iterable] | None = None,
        clock=None,
    ) -> Outcome:
        """Open, bring up, stream, stop safely; returns what happened.

        Parameters
        ----------
        plan : JointTrajectory or JointRange, or callable
            What bring-up checks, or a function of the present joint angles
            (rad, shape (n,)) returning it (see ``bringup.bring_up``).
        rate_hz : float
            Stream rate (Hz).
        frames : callable, optional
            ``frames(setup)`` returns the joint frames to stream (anything with
            ``t`` and ``q`` per frame, at ``rate_hz``); default the checked
            trajectory itself. This is the one place frames enter the stream.
        clock : optional
            As for :meth:`stream_path`.

        Returns
        -------
        Outcome
            ``stage`` "open" when the port did not open (nothing touched).

        Raises
        ------
        TrajgenError
            If ``plan`` refuses the present position (nothing changed).
        ValueError, TypeError
            If the virtual bus cannot be built around ``plant``.
        """
        outcome = Outcome(joint_names=self.config.joint_names)
        signals = self.stop_signals
        if signals is None:
            signals = StopSignals()
            with signals.installed():
                self._run(plan, rate_hz, frames, clock, signals, outcome)
        else:
            self._run(plan, rate_hz, frames, clock, signals, outcome)
        if signals.received is not None and outcome.signal is None and outcome.stopped_by:
            outcome.signal = signals.received
        return outcome

    def follow(self, follower, lines, *, clock=None, process: bool = True) -> Outcome:
        """Stream a follower's plan while keyframe lines change it.

        Bring-up checks where the stream starts and the whole range the
        follower's joint limits allow against the servos' installed limits
        (the frames are not known in advance). The stream ends at the end of
        ``lines``, once the last keyframe is reached.

        Parameters
        ----------
        follower : trajgen.follower.Follower
            The plan, its rate and its kinematics.
        lines : iterable of str or bytes, or callable
            The keyframe lines (see ``Follower.read``), or a function of the
            follower returning them (to time them against the stream; with
            ``process``, the planner's copy of the follower).
        clock : optional
            Default: on a virtual bus (``plant``), a ``drivers.clock.PacedClock``
            (``outcome.clock``): simulated time, one period per frame, paced by the
            wall clock, so the stream runs in real time beside the lines where the
            host keeps up and falls behind the wall clock, never late, where it
            does not (a line's time counts from the last frame planned when it
            arrives, ``Follower``); else the wall clock.
        process : bool
            Plan in a process of its own (``drivers.follow_process``, where the OS
            forks): it reads the lines, builds the changes and makes the frames (and
            their led goals), this process only streams them. Else the lines are read
            on a thread and the changes built in steps between frames, here.

        Returns
        -------
        Outcome
            ``trajectory`` is what was streamed. A planner that fails or dies ends
            the stream in the safe stop (``stopped_by`` says so).
        """
        if clock is None:
            clock = WALL_CLOCK if self.plant is None else PacedClock()
        limits = np.asarray(follower.kinematics.limits_rad, float)
        process = process and hasattr(os, "fork")
        planner = []

        def plan(present):
            return JointRange(np.asarray(present, float), limits)

        def lead(frames):
            # Goals led from the live plan's own frames, inside the range bring-up checked.
            return self.leader.frames(frames, follower.rate_hz, limits)

        def frames(setup):
            start = self.config.joints.to_rad(setup.present_ticks)
            led = None if self.leader is None else lead
            if process:
                from .follow_process import PlannedFrames

                planner.append(PlannedFrames(follower, lines, start, lead=led))
                return planner[0]
            source = lines(follower) if callable(lines) else lines
            threading.Thread(target=follower.read, args=(source,), daemon=True).start()
            frames = follower.frames(start=start)
            return frames if led is None else led(frames)

        try:
            outcome = self.run(plan, follower.rate_hz, frames=frames, clock=clock)
        finally:
            for p in planner:
                p.close()
        outcome.clock = clock if isinstance(clock, PacedClock) else None
        outcome.trajectory = follower.trajectory()
        if follower.fault and outcome.ok:
            outcome.stopped_by = f"a frame the gimbal cannot take: {follower.fault}"
            outcome.stage = "stream"
        return outcome

    # -- stages ------------------------------------------------------------

    def _open_virtual(self, rate_hz: float):
        from .virtual.bus import VirtualBus

        return VirtualBus(
            self.plant,
            ids=self.config.joints.ids,
            models=self.config.models,
            lockstep_dt_s=1.0 / rate_hz,
            registers=self.plant_registers,
        ).start()

    def _run(self, plan, rate_hz, frames, clock, signals, outcome: Outcome) -> None:
        from .bus import ServoBus

        virtual = None if self.plant is None else self._open_virtual(rate_hz)
        port = self.config.port if virtual is None else virtual.port
        ids = self.config.joints.ids
        bus = None
        log = bringup.BringUpLog()
        try:
            with signals.armed():
                outcome.stage = "open"
                if virtual is None:
                    bus = ServoBus(port, baud=self.config.baud).open()
                else:  # answered in this thread, in lock-step
                    bus = virtual.connect(baud=self.config.baud).open()
                outcome.stage = "bring-up"
                setup = bringup.bring_up(
                    bus,
                    self.config.joints,
                    self.config.models,
                    plan,
                    watchdog_s=self.config.watchdog_s,
                    joint_names=self.config.joint_names,
                    set_limits=self.set_limits,
                    max_approach_rad=self.max_approach_rad,
                    configure=self.config.configure,
                    log=log,
                )
                outcome.bring_up, outcome.trajectory = setup, setup.trajectory
                outcome.stage = "stream"
                source = setup.trajectory if frames is None else frames(setup)
                self._stream(bus, setup, source, rate_hz, clock, outcome)
            outcome.stage = ""
            self._states(bus, ids, outcome)
        except (DriverError, Interrupted) as e:
            outcome.stopped_by = str(e)
            if isinstance(e, Interrupted):
                outcome.signal = e.signum
            if bus is None:
                outcome.servo_states = dict.fromkeys(ids, UNTOUCHED)
            elif (
                outcome.stats is None
                and isinstance(e, BringUpError)
                and not (log.changes or bus.torque_written or bus.driven)
            ):
                # Refused before any change: bring-up changes nothing before its checks pass.
                outcome.servo_states = dict.fromkeys(ids, NOT_MOVED)
            else:
                if outcome.stats is None:
                    # Stopped during bring-up, possibly after it changed something.
                    restore = log.changes if self.config.restore else ()
                    outcome.stop_errors += safe_stop(bus, ids, self.on_stop, restore)
                self._states(bus, ids, outcome)
        finally:
            if bus is not None:
                bus.close()
            if virtual is not None:
                virtual.stop()
                outcome.virtual_error = virtual.error

    def _stream(self, bus, setup: BringUp, source, rate_hz, clock, outcome: Outcome) -> None:
        # clock None: simulated in lock-step (time moves with the frames: no waiting
        # for them), else the wall clock (``Streamer``).
        streamer = Streamer(
            bus,
            self.config.joints,
            telemetry=self.telemetry,
            joint_names=self.config.joint_names,
            on_stop=self.on_stop,
            max_approach_rad=self.max_approach_rad,
            goal_bounds_ticks=setup.goal_bounds_ticks,
            max_delay_s=self.max_delay_s,
            start_ticks=setup.present_ticks,
            power_limits=setup.power_limits,
            restore=setup.changes if self.config.restore else (),
            clock=clock,
        )
        try:
            outcome.stats = streamer.run(source, rate_hz=rate_hz)
        finally:
            outcome.stats = streamer.stats
            outcome.stop_errors += streamer.stop_errors

    def _states(self, bus, ids, outcome: Outcome) -> None:
        """Each servo's state after the safe stop, as it reads back
        (``outcome.servo_outcomes``): holding, released, off by itself (torque off
        although it was driven), not moved (never torqued), untouched; a servo that does
        not answer soundly is unknown, its likely cause in ``stop_errors``."""
        from .outcome import servo_outcomes

        outcome.servos = servo_outcomes(bus, self.config.joints, self.config.joint_names)
        named = {"never torqued": NOT_MOVED}
        outcome.servo_states = {o.servo_id: named.get(o.state, o.state) for o in outcome.servos}
        for o in outcome.servos:
            if o.state == UNKNOWN:
                outcome.stop_errors.append(f"state unknown: {o.detail}")
