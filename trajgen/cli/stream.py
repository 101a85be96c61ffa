"""The ``trajgen stream`` command: arguments and printing around a library session.

``plan`` (everything that can fail on bad input, before any hardware: the file,
the options, the joint stream) and :func:`run_plan` (a
``trajgen.drivers.session.Session`` with the options, on the port or a virtual
bus around the simulated gimbal; then the terminal lines, the torque report with
--virtual and --json, written on every stop). ``trajgen follow`` and ``trajgen
excite`` run the same two with their own plan and session call.

SIGINT, SIGTERM and SIGHUP are handled alike: the servos are stopped safely
(hold, or released with ``--torque-off``), the telemetry and the JSON report
are written, and the exit status is 128 + the signal number (130, 143, 129).

This module imports quickly: dynamixel-sdk, pyserial and MuJoCo load inside
``run_stream``.
"""

from __future__ import annotations

import argparse
import math
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    TELEMETRY_SUFFIXES,
    BadInput,
    Progress,
    add_bus_arguments,
    add_file_argument,
    add_ids_argument,
    add_json_argument,
    add_lead_argument,
    add_rate_argument,
    add_telemetry_argument,
    bad_input,
    check_module,
    check_output_path,
    check_plot_path,
    check_timing,
    exit_status_text,
    load_checked,
    output_path,
    positive_float,
    prefix,
    tell,
    warn,
    write_json,
)
from trajgen.errors import TrajgenError
from trajgen.gimbal import JOINT_NAMES as JOINTS

STREAM_DESCRIPTION = """\
Plan the joint stream of a keyframe file and stream it to Dynamixel X-series
servos at a fixed rate: bring-up (ping and model check; every servo checked
for a latched hardware error, its Drive Mode, position limits and present
position before any is changed; Return Delay 0, operating mode, no profile,
torque on, Bus Watchdog), a smooth move from the present position to the first
frame, then one sync write of Goal Position per frame with present position,
velocity and current read back. Prints the rate achieved, period jitter (p50,
p99, max), stalls and communication errors.

Safety: a plan that leaves a joint's installed position limits is refused
before torque on (limits are never widened; --set-limits is the only way to
write them; Drive Mode is never written); a joint farther than --max-approach
from the first frame is refused; after a host stall the rest of the stream is
shifted in time, never replayed faster, and the stream fails once it is more
than --max-delay behind its plan.

The file's [bus] table may set port, baud, ids, directions, zeros, models and
watchdog_s; flags override it. On any stop (end, fault, Ctrl-C, SIGTERM,
SIGHUP) the servos hold their last goal (--torque-off releases them); the
telemetry and --json report written so far are kept.

--virtual runs the same driver, SDK and serial layer against a virtual servo bus
on a pseudo-terminal, backed by the MuJoCo gimbal of `trajgen sim` (the file's
[gimbal] table; ideal assembly: direction +1, zero 2048), advancing one stream
period per frame received, and then prints the torque report.

Units: angles in degrees on the command line and in the file (joint degrees for
--set-limits and --max-approach), seconds for --max-delay."""

#: What gives exit status 1 (the stream and every command that streams).
STREAM_FAILED = "a stream fault, a refused bring-up, or (with --virtual) a failed torque check"


def _limits(text: str) -> tuple[str, float, float]:
    """argparse type: ``JOINT=MIN:MAX`` in degrees."""
    try:
        joint, span = text.split("=")
        low, high = (float(v) for v in span.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected JOINT=MIN:MAX, got {text!r}") from None
    if joint not in JOINTS:
        raise argparse.ArgumentTypeError(f"expected a joint of {', '.join(JOINTS)}, got {joint!r}")
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise argparse.ArgumentTypeError(f"expected finite MIN < MAX, got {text!r}")
    return joint, low, high


def register(subparsers) -> None:
    """Add the ``stream`` subcommand to an argparse ``subparsers``."""
    p = subparsers.add_parser(
        "stream",
        help="stream a keyframe file to Dynamixel servos (or a virtual bus)",
        description=STREAM_DESCRIPTION,
        epilog=exit_status_text(STREAM_FAILED, signals=True),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_stream_arguments(p)
    p.set_defaults(func=run_stream)


def add_stream_arguments(p, *, telemetry_required: bool = False) -> None:
    """The file, bus, rate, output, --virtual and safety options: what every command
    that streams accepts (``stream``, ``follow``, ``excite``); see :func:`stream_options`."""
    from trajgen.drivers.defaults import MAX_DELAY_S  # constants only: no SDK, no numpy

    add_file_argument(p)
    add_bus_arguments(
        p, "stream to a virtual bus backed by the simulated gimbal (instead of --port)"
    )
    add_ids_argument(p)
    add_rate_argument(p)
    add_lead_argument(p)
    add_telemetry_argument(p, required=telemetry_required)
    add_json_argument(p, "the statistics (and with --virtual the torque report)")
    p.add_argument(
        "--torque-off", action="store_true", help="release the servos when the stream stops"
    )
    p.add_argument(
        "--max-delay",
        type=positive_float,
        default=MAX_DELAY_S,
        metavar="S",
        help="fail the stream when host stalls have put it this far behind its plan "
        f"(default {MAX_DELAY_S:g} s; stream --virtual runs on simulated time: no stalls)",
    )
    p.add_argument(
        "--plot", metavar="OUT.png", help="with --virtual: plot the torque report to OUT.png"
    )
    p.add_argument(
        "--set-limits",
        type=_limits,
        action="append",
        metavar="JOINT=MIN:MAX",
        help="write this joint's Min/Max Position Limit (joint degrees) during bring-up; "
        "without it the installed limits are only read, and a plan leaving them is refused",
    )
    p.add_argument(
        "--configure",
        action="store_true",
        help="let bring-up change EEPROM settings the stream needs (Operating Mode) or is "
        "advised (Return Delay Time 0); default [bus] configure, else off: it says what it "
        "would change and refuses where the stream needs it",
    )
    p.add_argument(
        "--restore",
        action="store_true",
        help="on exit, write back the settings bring-up changed (EEPROM ones need "
        "--torque-off); default [bus] restore, else off",
    )
    p.add_argument(
        "--max-approach",
        type=positive_float,
        default=45.0,
        metavar="DEG",
        help="refuse to start when a joint is farther than DEG (joint degrees) from the first "
        "frame (default 45)",
    )


# -- plan --------------------------------------------------------------------


@dataclass
class Plan:
    """Everything decided before any hardware is touched.

    Attributes
    ----------
    source : KeyframeFile or ExcitationFile
        What is streamed (``path``, ``tables``, ``spline()``).
    config : BusConfig
        The file's [bus] table with the flags applied (an ideal joint map with --virtual).
    rate_hz : float
    trajectory : JointTrajectory
        The joint stream planned from the path's own start (the virtual gimbal powers
        up at its first frame; a session plans again from where the servos are).
    virtual : bool
    options : dict
        ``Session`` keywords from the flags.
    lead : str
        How goals are led ahead of the plan (--lead, [stream] lead, default model).
    gimbal : GimbalConfig
        The simulated gimbal of the file's [gimbal] tables, whose loops set the lead.
    """

    source: object
    config: object
    rate_hz: float
    trajectory: object
    virtual: bool
    options: dict = field(default_factory=dict)
    lead: str = "model"
    gimbal: object = None


def check_telemetry_path(path: str | None, suffixes: tuple[str, ...], inputs=()) -> None:
    """Refuse ``--telemetry PATH`` up front: writable, a known suffix, not one of
    ``inputs``, and for ``.mcap`` the ``mcap`` extra installed."""
    check_output_path("--telemetry", path, suffixes, inputs)
    if path and path.lower().endswith(".mcap"):
        check_module("--telemetry", "mcap_ros2", "'trajgen[mcap]'")


def plan(args) -> Plan:
    """The stream command's plan; no hardware.

    Raises
    ------
    ValueError, TypeError, OSError
        Bad input (BadInput, KeyframeFileError and KinematicsError are ValueErrors).
    """
    check_stream_outputs(args)
    checked = load_checked(args.file)
    kf = checked.keyframes
    rate = kf.stream_rate(args.rate)
    check_timing(kf, rate)
    if args.virtual and args.port:
        raise BadInput("--port and --virtual exclude each other")
    if args.plot and not args.virtual:
        raise BadInput("--plot needs --virtual (it plots the simulated torque report)")
    return planned(kf, checked.bus, rate, args, stream_options(args))


def check_stream_outputs(args) -> None:
    """Refuse unusable --telemetry, --json and --plot paths before any work (an output
    that is the keyframe file among them)."""
    inputs = [args.file]
    check_telemetry_path(args.telemetry, TELEMETRY_SUFFIXES, inputs)
    check_output_path("--json", args.json, (".json",), inputs)
    check_plot_path(args.plot, inputs)


def stream_options(args) -> dict:
    """``Session`` keywords from the options of :func:`add_stream_arguments`."""
    set_limits = {
        JOINTS.index(joint): (math.radians(low), math.radians(high))
        for joint, low, high in args.set_limits or ()
    }
    return {
        "on_stop": "torque_off" if args.torque_off else "hold",
        "telemetry": args.telemetry,
        "max_delay_s": args.max_delay,
        "max_approach_rad": math.radians(args.max_approach),
        "set_limits_rad": set_limits,
    }


def planned(source, config, rate_hz: float, args, options: dict) -> Plan:
    """A :class:`Plan` of ``source`` with --port, --baud, --ids and --virtual applied to
    the file's [bus] ``config``; plans the joint stream.

    Raises
    ------
    ValueError
        No port, or a plan the gimbal cannot follow (KinematicsError).
    """
    from dataclasses import replace

    from trajgen.drivers.units import JointMap
    from trajgen.stream import plan_joint_trajectory

    joints = config.joints
    ids = getattr(args, "ids", None)
    if ids and len(ids) != len(joints):
        raise BadInput(
            f"--ids {','.join(map(str, ids))}: expected {len(joints)} ids, one per joint "
            f"({', '.join(config.joint_names)})"
        )
    if args.virtual:
        joints = JointMap(joints.ids)  # the simulated gimbal is assembled ideally
    elif not (args.port or config.port):
        raise BadInput("no serial port: give --port, set [bus] port, or use --virtual")
    if ids:
        joints = JointMap(ids, joints.directions, joints.zeros)
    config = replace(
        config,
        port=args.port or config.port,
        baud=args.baud or config.baud,
        joints=joints,
        configure=config.configure or bool(getattr(args, "configure", False)),
        restore=config.restore or bool(getattr(args, "restore", False)),
    )
    from trajgen.lead import DEFAULT_LEAD
    from trajgen.sim.lead import lead_trajectory
    from trajgen.sim.model import gimbal_config_from_tables

    lead = getattr(args, "lead", None) or getattr(source, "lead", None) or DEFAULT_LEAD
    gimbal = gimbal_config_from_tables(source.tables, source.path)
    planned_q = plan_joint_trajectory(source.spline(), rate_hz, kinematics_of(source))
    # The goals a session will send (it leads them again from where the servos are).
    trajectory, _, notes = lead_trajectory(planned_q, gimbal, lead)
    for note in notes:
        tell(f"note: {note}")
    return Plan(source, config, rate_hz, trajectory, bool(args.virtual), options, lead, gimbal)


def session_for(p: Plan, signals):
    """The library session of a plan (around the simulated gimbal of the file's
    [gimbal] table, powered up at the first frame, with --virtual); returns
    ``(session, plant or None)``.

    Raises
    ------
    ValueError, TypeError
        A bad --set-limits, or a simulated gimbal that cannot be built from the file.
    """
    from trajgen.drivers.session import Session
    from trajgen.lead import sent_q
    from trajgen.sim.lead import Leader

    plant = registers = None
    if p.virtual:
        from trajgen.sim.plant import GimbalPlant

        # Parked at the first goal (the plan's first angles; the lead's static gravity
        # term ramps in from there), so the stream needs no approach.
        plant = GimbalPlant(p.gimbal, initial_rad=sent_q(p.trajectory)[0])
        # The servos power up with the gains the file states ([gimbal.<joint>]).
        registers = plant.initial_registers()
    options = dict(p.options)
    limits = options.pop("set_limits_rad", {})
    try:
        session = Session(
            p.config,
            plant=plant,
            plant_registers=registers,
            stop_signals=signals,
            set_limits_rad=limits,
            leader=Leader(p.gimbal, p.lead),
            **options,
        )
    except ValueError as e:
        if not limits:
            raise
        raise BadInput(f"--set-limits {_set_limits_text(limits, e)}") from None
    return session, plant


def _set_limits_text(limits: dict, error: Exception) -> str:
    """``JOINT=MIN:MAX: problem`` for the joint a Session refused (its message names it)."""
    joint, _, problem = str(error).partition(" limits: ")
    if joint not in JOINTS or JOINTS.index(joint) not in limits:
        return str(error)
    low, high = (math.degrees(v) for v in limits[JOINTS.index(joint)])
    return f"{joint}={low:g}:{high:g}: {problem}"


# -- run and report ----------------------------------------------------------


@contextmanager
def _warnings_to_stderr():
    """Print the drivers' RuntimeWarnings as ``trajgen <command>: warning:`` lines when
    they happen."""

    def show(message, *args, **kwargs):
        warn(message)

    with warnings.catch_warnings():
        warnings.simplefilter("always", RuntimeWarning)
        warnings.showwarning = show
        yield


def run_stream(args) -> int:
    """Run ``trajgen stream``; returns the exit status."""
    return run_plan(args, plan, stream_source)


def stream_source(session, p: Plan):
    """Stream the plan's path with the session (planned again from where the servos are)."""
    return session.stream_path(p.source.spline(), p.rate_hz, kinematics=kinematics_of(p.source))


def kinematics_of(source):
    """The kinematics of a file's ``[gimbal] axes`` and ``joints``; None for pan-tilt-roll
    (the default kinematics)."""
    from trajgen.gimbal import GimbalKinematics
    from trajgen.keyframe_axes import is_default

    axes = getattr(source, "axes", None)
    if axes is None or is_default(axes):
        return None
    return GimbalKinematics(axes=axes.sequence, joints=axes.joints)


def run_plan(args, make_plan, go, extra=None) -> int:
    """Plan, then run the session under the stop signals and report; returns the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        With ``json`` and (optionally) ``plot``, ``torque_off``.
    make_plan : callable
        ``make_plan(args)`` returns a :class:`Plan` (or raises on bad input).
    go : callable
        ``go(session, plan)`` runs the session and returns its ``Outcome``.
    extra : callable, optional
        ``extra()`` gives entries for the JSON report.
    """
    from trajgen.drivers.signals import StopSignals

    signals = StopSignals()
    with signals.installed(), _warnings_to_stderr():
        try:
            p = make_plan(args)
            session, plant = session_for(p, signals)
            outcome = go(session, p)
        except (ValueError, TypeError, OSError) as e:  # TrajgenError: re-planning at start
            return bad_input(e)
        if outcome.virtual_error is not None:
            tell(f"virtual bus stopped: {outcome.virtual_error}")
        if outcome.stage == "open" and outcome.signal is None:
            return bad_input(outcome.stopped_by)  # the port did not open
        status = report(args, p, plant, outcome, extra=None if extra is None else extra())
    if signals.received is not None and outcome.signal is None:
        # A signal after the stream ended: everything was done and reported.
        status = 128 + signals.received
    return status


def _state(outcome, on_stop: str) -> str:
    """What the servos were left doing, as a clause for the terminal."""
    from trajgen.drivers.session import HOLDING, RELEASED, UNTOUCHED

    states = outcome.servo_states
    asked = RELEASED if on_stop == "torque_off" else HOLDING
    if states and all(s == UNTOUCHED for s in states.values()):
        return "no servo was touched"
    if outcome.refused:
        return "bring-up refused before torque on: no servo was moved"
    if on_stop == "torque_off":
        state = "the servos were released (torque off)"
    else:
        state = "the servos hold their last goal"
    others = [f"servo {i} {s}" for i, s in states.items() if s != asked]
    if others:
        state += f" (except {', '.join(others)}: see the warnings above)"
    return state


def report(args, p: Plan, plant, outcome, extra: dict | None = None) -> int:
    """Print the statistics and what the servos were left doing; write ``--json`` (with
    ``extra`` entries added); returns the exit status."""
    status = (
        EXIT_OK
        if outcome.ok
        else (128 + outcome.signal if outcome.signal is not None else EXIT_FAILED)
    )
    stats = outcome.stats
    if stats is not None:
        print(stats.format())
    for message in outcome.stop_errors:
        warn(f"safe stop: {message}")
    on_stop = p.options.get("on_stop", "hold")
    state = _state(outcome, on_stop)
    if outcome.stopped_by:
        kind = "interrupted" if outcome.signal is not None else "stream failed"
        tell(f"{kind}: {outcome.stopped_by}; {state}")
    else:
        print(f"servos: {state.removeprefix('the servos ')}")
    for servo in outcome.servos:  # each as read back after the stop
        print(f"  {servo.format()}")
    telemetry = p.options.get("telemetry")
    if telemetry and stats is not None:
        print(f"telemetry: {telemetry}")
    result = {"status": status, "on_stop": on_stop, **outcome.to_json_dict(), **(extra or {})}
    if plant is not None and status == EXIT_OK:
        status, outcome.torque_report = torque_report(
            plant, outcome.trajectory, getattr(args, "plot", None), result, lead=p.lead
        )
        result["status"] = status
    if telemetry and stats is not None:
        add_telemetry_report(telemetry, result)
    return write_report(args.json, result, status)


def add_telemetry_report(path: str, result: dict) -> None:
    """Add the report to the telemetry file where it holds one (MCAP); warn if it cannot."""
    from trajgen.drivers.telemetry import add_report

    try:
        add_report(path, result, Progress(f"{prefix()}: adding the report to {path}"))
    except OSError as e:
        warn(f"telemetry {path}: report not added: {e}")


def torque_report(plant, trajectory, plot_path, result: dict, *, lead: str = "none"):
    """Print (and plot to ``plot_path``) the torque report of ``trajectory`` as streamed
    to ``plant``; add it to ``result``; return the exit status and the report (or None)."""
    from trajgen.sim.errors import SimError

    try:
        report = plant.report(trajectory, lead=lead)
    except SimError as e:
        tell(f"simulation failed: {e}")
        return EXIT_FAILED, None
    print(report.format())
    result["torque"] = report.to_json_dict()
    status = EXIT_OK if report.ok else EXIT_FAILED
    if plot_path:
        from trajgen.sim.plot import plot_report

        try:
            with output_path("--plot", plot_path) as tmp:
                plot_report(report, tmp)
            print(f"plot: {plot_path}")
        except (OSError, ValueError) as e:
            return bad_input(e), report
    return status, report


def write_report(path, result: dict, status: int) -> int:
    """Write ``result`` to ``path`` (--json) if given; return ``status`` (or bad input)."""
    if path:
        try:
            write_json("--json", path, result)
        except TrajgenError as e:
            return bad_input(e)
        print(f"json: {path}")
    return status
