"""``trajgen stream`` as a library call: a keyframe file (or any path source)
planned for a bus or the virtual gimbal, run through a
``trajgen.drivers.session.Session``, and what came of it.

:class:`StreamJob` is decided before any hardware is touched (the file, the
bus configuration with the caller's overrides, the joint stream with its led
goals); :meth:`StreamJob.run` opens the port (or starts a virtual servo bus on
a pseudo-terminal around the MuJoCo gimbal of the file's ``[gimbal]`` tables),
brings the servos up, streams, stops them safely and returns a
:class:`StreamResult`: the session's ``Outcome``, the exit status the command
line gives, each servo's state, the torque report of a virtual run and the
JSON report. ``trajgen stream``, ``follow`` and ``excite`` are this, with their
options parsed and the result printed.

Units: SI (rad, s); degrees only in the file.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from trajgen.errors import BadArgument

#: Exit statuses of a run, as the command line gives them.
STATUS_OK, STATUS_FAILED, STATUS_BAD_INPUT = 0, 1, 2


class NoPort(BadArgument):
    """A job for servos with no serial port named (no ``port``, no ``[bus] port``)."""


class IdCount(BadArgument):
    """``ids`` that are not one per joint of the file's gimbal.

    Attributes
    ----------
    ids : tuple of int
    joint_names : tuple of str
    """

    def __init__(self, ids: Sequence[int], joint_names: Sequence[str]) -> None:
        self.ids, self.joint_names = tuple(ids), tuple(joint_names)
        super().__init__(
            f"expected {len(joint_names)} ids, one per joint ({', '.join(joint_names)}), "
            f"got {list(self.ids)}"
        )


class LimitsRefused(BadArgument):
    """A ``set_limits_rad`` entry the joint's registers cannot hold.

    Attributes
    ----------
    joint : int
        The joint index.
    name : str
        The joint's name (the file's ``[gimbal] joints``).
    limits_rad : tuple of float
        The refused (low, high) joint angles (rad).
    problem : str
        Why (the joint map's message).
    """

    def __init__(self, joint: int, name: str, limits_rad: tuple[float, float], problem: str):
        super().__init__(f"{name} limits: {problem}")
        self.joint, self.name, self.limits_rad, self.problem = joint, name, limits_rad, problem


@dataclass
class StreamJob:
    """Everything decided before any hardware is touched.

    Build one with :meth:`from_file` (a keyframe file) or :meth:`plan` (any
    source with ``path``, ``tables`` and ``spline()``, such as an excitation).

    Attributes
    ----------
    source : KeyframeFile or another path source
        What is streamed (``path``, ``tables``, ``spline()``).
    config : trajgen.drivers.config.BusConfig
        The file's [bus] table with the overrides applied (an ideal joint map when
        virtual).
    rate_hz : float
    trajectory : JointTrajectory
        The joint stream planned from the path's own start, its led goals attached
        (the virtual gimbal powers up at its first frame; a session plans again from
        where the servos are).
    virtual : bool
        Stream to a virtual servo bus around the simulated gimbal.
    options : dict
        ``Session`` keywords (``on_stop``, ``telemetry``, ``max_delay_s``,
        ``max_approach_rad``, ``set_limits_rad``).
    lead : str
        How goals are led ahead of the plan (``trajgen.lead.LEADS``).
    gimbal : trajgen.sim.GimbalConfig
        The simulated gimbal of the file's [gimbal] tables, whose loops set the lead.
    notes : list of str
        Why a joint got no lead (its plan fails the torque check).
    """

    source: object
    config: object
    rate_hz: float
    trajectory: object
    virtual: bool
    options: dict = field(default_factory=dict)
    lead: str = "model"
    gimbal: object = None
    notes: Sequence[str] = ()

    @classmethod
    def from_file(
        cls,
        path,
        *,
        rate_hz: float | None = None,
        say: Callable[[str], None] | None = None,
        progress: Callable | None = None,
        **overrides,
    ) -> StreamJob:
        """The job of a keyframe file, every table of it checked; no hardware.

        Parameters
        ----------
        path : str or Path
            The keyframe file.
        rate_hz : float, optional
            Stream rate (Hz); default the file's [stream] rate_hz.
        say, progress : callable, optional
            Told of a slow spline build (``trajgen.jobs.load_checked``).
        **overrides
            As for :meth:`plan` (``virtual``, ``port``, ``ids``, ``lead``, ``on_stop``,
            ``telemetry``, ...).

        Raises
        ------
        ValueError, OSError
            Bad input: the file (``KeyframeFileError``), its timing, no port
            (:class:`NoPort`), a plan the gimbal cannot follow (``KinematicsError``).
        """
        from trajgen.jobs.checked_file import check_timing, load_checked

        checked = load_checked(path, say=say, progress=progress, any_axes=True)
        kf = checked.keyframes
        rate = kf.stream_rate(rate_hz)
        check_timing(kf, rate)
        return cls.plan(kf, checked.bus, rate, **overrides)

    @classmethod
    def plan(
        cls,
        source,
        config,
        rate_hz: float,
        *,
        virtual: bool = False,
        port: str | None = None,
        baud: int | None = None,
        ids: Sequence[int] | None = None,
        lead: str | None = None,
        configure: bool = False,
        restore: bool = False,
        **session_options,
    ) -> StreamJob:
        """The job of ``source`` with the overrides applied to its [bus] ``config``;
        plans the joint stream and its led goals.

        Parameters
        ----------
        source : path source
            ``path``, ``tables`` (for [gimbal]), ``spline()``, optionally ``lead``.
        config : BusConfig
            The source's [bus] table.
        rate_hz : float
            Stream rate (Hz).
        virtual : bool
            Stream to a virtual bus around the simulated gimbal (assembled ideally:
            direction +1, zero 2048) instead of a port.
        port, baud, ids : optional
            Override the [bus] port, baud rate and servo ids (one per joint, in the
            order of the file's ``[gimbal] joints``: pan, tilt, roll by default).
        lead : {"model", "advance", "none"}, optional
            Default the source's [stream] lead, else ``trajgen.lead.DEFAULT_LEAD``.
        configure, restore : bool
            Turn on [bus] configure / restore (they stay on where the file sets them).
        **session_options
            ``Session`` keywords: ``on_stop``, ``telemetry``, ``max_delay_s``,
            ``max_approach_rad``, ``set_limits_rad`` (keyed by joint index or name).

        Raises
        ------
        NoPort
            Not virtual, and neither ``port`` nor [bus] port.
        IdCount
            ``ids`` that are not one per joint of the file's ``[gimbal] joints``.
        KinematicsError, SimError
            A plan the gimbal cannot follow; a [gimbal] table the lead cannot use.
        """
        from trajgen.drivers.units import JointMap
        from trajgen.lead import DEFAULT_LEAD
        from trajgen.sim.lead import lead_trajectory
        from trajgen.sim.model import gimbal_config_from_tables
        from trajgen.stream import plan_joint_trajectory

        joints = config.joints
        if ids and len(ids) != len(joints):
            raise IdCount(ids, config.joint_names)
        if virtual:
            joints = JointMap(joints.ids)  # the simulated gimbal is assembled ideally
        elif not (port or config.port):
            raise NoPort("no serial port: give port=, set [bus] port, or virtual=True")
        if ids:
            joints = JointMap(tuple(ids), joints.directions, joints.zeros)
        config = replace(
            config,
            port=port or config.port,
            baud=baud or config.baud,
            joints=joints,
            configure=config.configure or configure,
            restore=config.restore or restore,
        )
        lead = lead or getattr(source, "lead", None) or DEFAULT_LEAD
        gimbal = gimbal_config_from_tables(source.tables, source.path, any_axes=True)
        planned = plan_joint_trajectory(source.spline(), rate_hz, kinematics_of(source))
        # The goals a session will send (it leads them again from where the servos are).
        trajectory, _, notes = lead_trajectory(planned, gimbal, lead)
        options = dict(session_options)
        if options.get("set_limits_rad"):
            options["set_limits_rad"] = _limits_by_index(
                options["set_limits_rad"], config.joint_names
            )
        return cls(source, config, rate_hz, trajectory, bool(virtual), options, lead, gimbal, notes)

    # -- running -----------------------------------------------------------

    def session(self, stop_signals=None):
        """The library session of this job (around the simulated gimbal, powered up at
        the first frame, when virtual); returns ``(session, plant or None)``.

        Raises
        ------
        LimitsRefused
            A ``set_limits_rad`` entry outside the registers' range.
        ValueError, TypeError
            A simulated gimbal that cannot be built from the file.
        """
        from trajgen.drivers.session import Session
        from trajgen.lift import sent_goals
        from trajgen.sim.lead import Leader

        plant = registers = None
        if self.virtual:
            from trajgen.sim.plant import GimbalPlant

            # Parked at the first goal sent (the plan's first angles; the lift brings the
            # lead's static gravity term in from there), so the stream needs no approach.
            plant = GimbalPlant(self.gimbal, initial_rad=sent_goals(self.trajectory)[1][0])
            # The servos power up with the gains the file states ([gimbal.<joint>]).
            registers = plant.initial_registers()
        options = dict(self.options)
        limits = options.pop("set_limits_rad", None) or {}
        try:
            session = Session(
                self.config,
                plant=plant,
                plant_registers=registers,
                stop_signals=stop_signals,
                set_limits_rad=limits,
                leader=Leader(self.gimbal, self.lead),
                **options,
            )
        except ValueError as e:
            if not limits:
                raise
            raise _limits_refused(limits, e, self.config.joint_names) from None
        return session, plant

    def stream(self, session):
        """Stream the source's path with ``session`` (planned again from where the servos
        are); returns its ``Outcome``."""
        return session.stream_path(
            self.source.spline(), self.rate_hz, kinematics=kinematics_of(self.source)
        )

    def run(
        self,
        *,
        stream: Callable | None = None,
        stop_signals=None,
        report_to_telemetry: bool = True,
        progress: Callable[[float], None] | None = None,
    ) -> StreamResult:
        """Open, bring up, stream, stop safely; then (virtual) judge the torque.

        Parameters
        ----------
        stream : callable, optional
            ``stream(session)`` runs the session and returns its ``Outcome`` (for
            example ``session.follow(follower, lines)``); default :meth:`stream`.
        stop_signals : trajgen.drivers.signals.StopSignals, optional
            Installed by the caller around its own stages; default the session's own.
        report_to_telemetry : bool
            Add the report to an MCAP telemetry file (:meth:`StreamResult.add_to_telemetry`).
        progress : callable, optional
            ``progress(fraction)`` while the report is added (it rewrites the file).

        Returns
        -------
        StreamResult

        Raises
        ------
        ValueError, TypeError, OSError
            Bad input found at the start: a path the gimbal cannot follow from where
            the servos are, a refused ``set_limits_rad`` (:class:`LimitsRefused`).
            What happens on the bus is in the result, never raised.
        """
        session, plant = self.session(stop_signals)
        outcome = (stream or self.stream)(session)
        result = StreamResult(self, outcome)
        if result.exit_status == STATUS_OK and plant is not None:
            result.judge_torque(plant)
        if report_to_telemetry:
            result.add_to_telemetry(progress)
        return result


def _limits_refused(limits: dict, error: Exception, names: Sequence[str]) -> Exception:
    """The :class:`LimitsRefused` of the joint a Session refused (its message names it,
    one of ``names``), or ``error`` when it names none of ``limits``."""
    joint, _, problem = str(error).partition(" limits: ")
    if joint not in names or list(names).index(joint) not in limits:
        return error
    j = list(names).index(joint)
    return LimitsRefused(j, joint, tuple(limits[j]), problem)


def _limits_by_index(limits: dict, names: Sequence[str]) -> dict:
    """``set_limits_rad`` keyed by joint index, from keys that are indices or joint names.

    Raises
    ------
    BadArgument
        A name that is not one of ``names``, or an index outside them.
    """
    by_index = {}
    for key, value in limits.items():
        if isinstance(key, str):
            if key not in names:
                raise BadArgument(
                    f"limits for {key!r}: not a joint of this gimbal (one of {', '.join(names)})"
                )
            key = list(names).index(key)
        elif not 0 <= key < len(names):
            raise BadArgument(f"limits for joint {key}: out of 0..{len(names) - 1}")
        if key in by_index:
            raise BadArgument(f"limits for {names[key]}: given twice")
        by_index[key] = value
    return by_index


@dataclass
class StreamResult:
    """What a :class:`StreamJob` run did.

    Attributes
    ----------
    job : StreamJob
    outcome : trajgen.drivers.session.Outcome
        What the session did (stage, stop reason, signal, each servo's state, stats).
    exit_status : int
        0 the stream ran to its end (and, virtual, passed the torque check); 1 a
        stream fault, a refused bring-up or a failed torque check; 2 the port did not
        open; 128 + the signal number when a stop signal ended it.
    torque : trajgen.sim.TorqueReport or None
        The torque report of a virtual run that reached its end.
    simulation_error : str or None
        Why the torque report could not be made.
    extra : dict
        More entries for :meth:`to_json_dict` (``trajgen follow`` adds its summary).
    """

    job: StreamJob
    outcome: object
    exit_status: int = field(init=False)
    torque: object = None
    simulation_error: str | None = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        o = self.outcome
        if o.ok:
            self.exit_status = STATUS_OK
        elif o.signal is not None:
            self.exit_status = 128 + o.signal
        elif self.port_failed:
            self.exit_status = STATUS_BAD_INPUT
        else:
            self.exit_status = STATUS_FAILED

    @property
    def ok(self) -> bool:
        """Whether the stream ran to its end (and passed the torque check, if judged)."""
        return self.exit_status == STATUS_OK

    @property
    def port_failed(self) -> bool:
        """Whether the port did not open (nothing was touched; ``outcome.stopped_by``
        says why)."""
        return self.outcome.stage == "open" and self.outcome.signal is None

    @property
    def on_stop(self) -> str:
        """What the servos were asked to do on the stop: "hold" or "torque_off"."""
        return self.job.options.get("on_stop", "hold")

    @property
    def telemetry(self):
        """The telemetry file, if one was written."""
        path = self.job.options.get("telemetry")
        return path if path and self.outcome.stats is not None else None

    def judge_torque(self, plant) -> None:
        """Make the torque report of what was streamed to ``plant``; a failed check (or a
        simulation that fails) makes ``exit_status`` 1."""
        from trajgen.sim.errors import SimError

        try:
            self.torque = plant.report(self.outcome.trajectory, lead=self.job.lead)
        except SimError as e:
            self.simulation_error = str(e)
            self.exit_status = STATUS_FAILED
            return
        self.exit_status = STATUS_OK if self.torque.ok else STATUS_FAILED

    def servos_left(self) -> str:
        """What the servos were left doing, as a clause ("the servos hold their last goal")."""
        from trajgen.drivers.session import HOLDING, RELEASED, UNTOUCHED

        outcome = self.outcome
        states = outcome.servo_states
        asked = RELEASED if self.on_stop == "torque_off" else HOLDING
        if states and all(s == UNTOUCHED for s in states.values()):
            return "no servo was touched"
        if outcome.refused:
            return "bring-up refused before torque on: no servo was moved"
        if self.on_stop == "torque_off":
            state = "the servos were released (torque off)"
        else:
            state = "the servos hold their last goal"
        others = [f"servo {i} {s}" for i, s in states.items() if s != asked]
        if others:
            state += f" (except {', '.join(others)}: see the warnings above)"
        return state

    def ending(self) -> str:
        """How the stream ended and what the servos were left doing, one line:
        ``"servos: hold their last goal"``, ``"stream failed: ...; ..."``,
        ``"interrupted: ...; ..."``."""
        outcome = self.outcome
        if outcome.stopped_by:
            kind = "interrupted" if outcome.signal is not None else "stream failed"
            return f"{kind}: {outcome.stopped_by}; {self.servos_left()}"
        return f"servos: {self.servos_left().removeprefix('the servos ')}"

    def format(self) -> str:
        """The statistics, how the stream ended, each servo as read back after the stop,
        and the torque report: what ``trajgen stream`` prints, in lines."""
        outcome = self.outcome
        lines = [] if outcome.stats is None else [outcome.stats.format()]
        lines += [f"safe stop: {m}" for m in outcome.stop_errors]
        lines.append(self.ending())
        lines += [f"  {servo.format()}" for servo in outcome.servos]
        if self.torque is not None:
            lines.append(self.torque.format())
        if self.simulation_error is not None:
            lines.append(f"simulation failed: {self.simulation_error}")
        return "\n".join(lines)

    def to_json_dict(self) -> dict:
        """The report as plain JSON types: ``status`` (:attr:`exit_status`), ``on_stop``,
        the outcome (``Outcome.to_json_dict``), the :attr:`extra` entries, and ``torque``
        for a virtual run that was judged."""
        result = {
            "status": self.exit_status,
            "on_stop": self.on_stop,
            **self.outcome.to_json_dict(),
            **self.extra,
        }
        if self.torque is not None:
            result["torque"] = self.torque.to_json_dict()
        return result

    def add_to_telemetry(self, progress: Callable[[float], None] | None = None) -> None:
        """Add :meth:`to_json_dict` to the telemetry file where it holds one (MCAP: a
        metadata record and ``/rosout`` messages); nothing without telemetry.

        Raises
        ------
        OSError
            If the file cannot be rewritten.
        """
        if self.telemetry is None:
            return
        from trajgen.drivers.telemetry import add_report

        add_report(self.telemetry, self.to_json_dict(), progress)


def kinematics_of(source):
    """The kinematics of a source's ``[gimbal] axes`` and ``joints`` (its ``axes``); None
    for pan-tilt-roll, the default kinematics."""
    from trajgen.gimbal import GimbalKinematics
    from trajgen.keyframe_axes import is_default

    axes = getattr(source, "axes", None)
    if axes is None or is_default(axes):
        return None
    return GimbalKinematics(axes=axes.sequence, joints=axes.joints)


def run_stream_file(path, **options) -> StreamResult:
    """Plan a keyframe file and stream it: ``StreamJob.from_file(path, **options).run()``.

    Parameters
    ----------
    path : str or Path
    **options
        As for :meth:`StreamJob.from_file` (``virtual=True`` for the simulated gimbal,
        else ``port=`` or the file's [bus] port; ``rate_hz``, ``on_stop``,
        ``telemetry``, ...).

    Returns
    -------
    StreamResult
    """
    return StreamJob.from_file(path, **options).run()
