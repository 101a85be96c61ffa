"""The ``trajgen stream`` command.

One function per stage, so each can be read (and tested) on its own:
``plan`` (everything that can fail on bad input, before any hardware),
``open_port`` (the serial port, or a virtual bus), ``bring_up_servos`` (the
same ``drivers.bringup.bring_up`` the tests exercise), ``stream_plan`` and
``report`` (terminal lines and ``--json``, written on every stop).

SIGINT, SIGTERM and SIGHUP are handled alike: the servos are stopped safely
(hold, or released with ``--torque-off``), the telemetry and the JSON report
are written, and the exit status is 128 + the signal number (130, 143, 129).

This module imports quickly: dynamixel-sdk, pyserial and MuJoCo load inside
``run_stream``.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    add_file_argument,
    add_lead_argument,
    bad_input,
    baud_rate,
    check_output_path,
    check_plot_path,
    check_timing,
    load_checked,
    open_bus,
    positive_float,
    servo_ids,
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

exit status: 0 ok, 1 stream fault, refused bring-up or torque check failed,
2 bad input, 128 + signal number when stopped by a signal (130 SIGINT,
143 SIGTERM, 129 SIGHUP)."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


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
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_stream_arguments(p)
    p.set_defaults(func=run_stream)


def add_stream_arguments(p) -> None:
    """The file, bus, rate, output, --virtual and safety options (shared with
    ``trajgen follow``)."""
    from trajgen.drivers.defaults import MAX_DELAY_S  # constants only: no SDK, no numpy

    add_file_argument(p)
    p.add_argument("--port", help="serial device, e.g. /dev/ttyUSB0; default [bus] port")
    p.add_argument(
        "--baud", type=baud_rate, help="baud rate (up to 4500000); default [bus] baud, else 1000000"
    )
    p.add_argument(
        "--ids", type=servo_ids, metavar="P,T,R", help="servo ids of pan, tilt, roll; default 1,2,3"
    )
    p.add_argument(
        "--rate",
        type=positive_float,
        metavar="HZ",
        help="stream rate (Hz); default the file's [stream] rate_hz, else 200",
    )
    add_lead_argument(p)
    p.add_argument(
        "--telemetry", metavar="OUT", help="write per-frame telemetry to OUT (.csv or .npz)"
    )
    p.add_argument("--json", metavar="OUT.json", help="write the statistics (and report) as JSON")
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
        "--virtual",
        action="store_true",
        help="stream to a virtual bus backed by the simulated gimbal (no --port needed)",
    )
    p.add_argument("--plot", metavar="OUT.png", help="with --virtual: plot the torque report")
    p.add_argument(
        "--set-limits",
        type=_limits,
        action="append",
        metavar="JOINT=MIN:MAX",
        help="write this joint's Min/Max Position Limit (joint degrees) during bring-up; "
        "without it the installed limits are only read, and a plan leaving them is refused",
    )
    p.add_argument(
        "--max-approach",
        type=positive_float,
        default=45.0,
        metavar="DEG",
        help="refuse to start when a joint is farther than this from the first frame (default 45)",
    )


# -- signals -----------------------------------------------------------------


class _StopSignals:
    """SIGINT, SIGTERM and SIGHUP as ``Interrupted``, raised only while ``armed``.

    Outside the armed stretch (planning, reporting), a signal is remembered and
    acted on at the next ``arm`` or in the exit status; while the safe stop
    runs, a second signal is ignored so that the stop completes.
    """

    def __init__(self) -> None:
        self.received: int | None = None
        self._armed = False

    def _handle(self, signum, frame) -> None:
        from trajgen.drivers.errors import Interrupted

        first = self.received is None
        self.received = signum if first else self.received
        if self._armed and first:
            self._armed = False
            raise Interrupted(signum)

    @contextmanager
    def installed(self):
        previous = {s: signal.signal(s, self._handle) for s in STOP_SIGNALS}
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)

    @contextmanager
    def armed(self):
        from trajgen.drivers.errors import Interrupted

        if self.received is not None:
            raise Interrupted(self.received)
        self._armed = True
        try:
            yield
        finally:
            self._armed = False


@contextmanager
def _warnings_to_stderr():
    """Print the drivers' RuntimeWarnings as ``trajgen: warning:`` lines when they happen."""

    def show(message, *args, **kwargs):
        print(f"trajgen: warning: {message}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.simplefilter("always", RuntimeWarning)
        warnings.showwarning = show
        yield


# -- stages ------------------------------------------------------------------


@dataclass
class Plan:
    """Everything decided before any hardware is touched."""

    kf: object
    config: object
    joints: object
    rate_hz: float
    trajectory: object
    set_limits: dict[int, tuple[int, int]]
    #: How goals are led ahead of the plan (``trajgen.lead``), and the simulated
    #: gimbal of the file's [gimbal] tables whose loop parameters set the lead.
    lead: str = "model"
    gimbal: object = None


@dataclass
class Outcome:
    """What happened, for the report: filled in as the stages run."""

    status: int = EXIT_OK
    stopped_by: str = ""
    untouched: bool = False
    refused: bool = False
    bring_up: dict | None = None
    streamer: object = None
    stop_errors: list[str] = field(default_factory=list)
    torque_report: object = None


def _plan(args):
    """Everything that can fail on bad input, before any hardware is touched.

    Shared with ``trajgen follow``. Returns ``(kf, config, joints, rate, trajectory)``.

    Raises
    ------
    ValueError, TypeError, OSError
        Bad input (BadInput, KeyframeFileError and KinematicsError are ValueErrors).
    """
    from trajgen.drivers.config import bus_config_from_tables
    from trajgen.drivers.units import JointMap
    from trajgen.keyframes import DEFAULT_RATE_HZ
    from trajgen.stream import plan_joint_trajectory

    check_output_path("--telemetry", args.telemetry, (".csv", ".npz"))
    check_output_path("--json", args.json, (".json",))
    check_plot_path(args.plot)
    if hasattr(args.file, "spline"):
        # ``trajgen excite`` passes an already planned source (``cli.excite.ExcitationFile``).
        kf = args.file
        config = bus_config_from_tables(kf.tables, kf.path)
        rate = args.rate or kf.rate_hz or DEFAULT_RATE_HZ
    else:
        checked = load_checked(args.file)
        kf, config = checked.keyframes, checked.bus
        rate = kf.stream_rate(args.rate)
        check_timing(kf, rate)
    joints = config.joints
    if args.virtual:
        if args.port:
            raise ValueError("--port and --virtual exclude each other")
        joints = JointMap(joints.ids)  # the simulated gimbal is assembled ideally
    elif args.plot:
        raise ValueError("--plot needs --virtual (it plots the simulated torque report)")
    elif not (args.port or config.port):
        raise ValueError("no serial port: give --port, set [bus] port, or use --virtual")
    if args.ids:
        joints = JointMap(args.ids, joints.directions, joints.zeros)
    trajectory = plan_joint_trajectory(kf.spline(), rate)
    return kf, config, joints, rate, trajectory


def _set_limits(args, joints) -> dict[int, tuple[int, int]]:
    """``--set-limits`` as servo id -> (min, max) ticks, through each joint's mapping.

    Raises
    ------
    ValueError
        If a limit falls outside the registers' range 0..4095.
    """
    import numpy as np

    from trajgen.drivers.units import TICKS_PER_REV

    limits = {}
    for joint, low_deg, high_deg in args.set_limits or ():
        j = JOINTS.index(joint)
        angles = np.zeros((2, len(JOINTS)))
        angles[:, j] = np.radians([low_deg, high_deg])
        ticks = sorted(int(v) for v in joints.to_ticks(angles)[:, j])
        if not 0 <= ticks[0] < ticks[1] <= TICKS_PER_REV - 1:
            raise ValueError(
                f"--set-limits {joint}={low_deg:g}:{high_deg:g}: ticks {ticks[0]}..{ticks[1]} "
                f"fall outside the registers' range 0..{TICKS_PER_REV - 1}"
            )
        limits[joints.ids[j]] = (ticks[0], ticks[1])
    return limits


def plan(args) -> Plan:
    """The stream command's plan (``_plan``) and its ``--set-limits``; no hardware.

    Raises
    ------
    ValueError, TypeError, OSError
        Bad input.
    """
    from trajgen.lead import DEFAULT_LEAD
    from trajgen.sim.model import gimbal_config_from_tables

    kf, config, joints, rate, trajectory = _plan(args)
    lead = getattr(args, "lead", None) or getattr(kf, "lead", None) or DEFAULT_LEAD
    gimbal = gimbal_config_from_tables(kf.tables, kf.path)
    p = Plan(kf, config, joints, rate, trajectory, _set_limits(args, joints), lead, gimbal)
    p.trajectory = lead_plan(p, trajectory)
    return p


def lead_plan(p: Plan, trajectory, *, quiet: bool = False):
    """``trajectory`` with the goals to send (``sim.lead.lead_trajectory``: the same goals
    ``trajgen sim`` simulates), led by ``p.lead`` with the loop parameters of the file's
    [gimbal] tables; notes why a joint gets no lead."""
    from trajgen.sim.lead import lead_trajectory

    led, _, notes = lead_trajectory(trajectory, p.gimbal, p.lead)
    for note in () if quiet else notes:
        print(f"trajgen: note: {note}", file=sys.stderr)
    return led


def open_port(args, p: Plan):
    """Start the virtual bus (with ``--virtual``); returns (port, virtual bus, plant).

    Raises
    ------
    ValueError, TypeError
        If the simulated gimbal cannot be built from the file.
    """
    if not args.virtual:
        return args.port or p.config.port, None, None
    from trajgen.lead import sent_q

    # Parked at the first goal (the plan's first angles plus the lead's static gravity
    # term), so the stream needs no approach.
    virtual, plant = start_virtual(p.kf, p.config, p.joints, p.rate_hz, sent_q(p.trajectory)[0])
    return virtual.port, virtual, plant


def start_virtual(kf, config, joints, rate, first_q):
    """The simulated gimbal of the file's [gimbal] table, powered up at ``first_q``
    (rad, as a gimbal parked at the first frame would be), behind a virtual bus in
    lock-step with the stream; returns ``(virtual_bus, plant)``."""
    from trajgen.drivers.virtual.bus import VirtualBus
    from trajgen.sim.model import gimbal_config_from_tables
    from trajgen.sim.plant import GimbalPlant

    plant = GimbalPlant(gimbal_config_from_tables(kf.tables, kf.path), initial_rad=first_q)
    virtual = VirtualBus(
        plant,
        ids=joints.ids,
        models=config.models,
        lockstep_dt_s=1.0 / rate,
        # The servos power up with the gains the file states ([gimbal.<joint>]).
        registers=dict(zip(joints.ids, plant.initial_registers(), strict=True)),
    )
    return virtual.start(), plant


def bring_up_servos(bus, args, p: Plan, *, plan_from=None):
    """``drivers.bringup.bring_up``, planning from where the servos are.

    Planning with ``start`` = the present joint angles puts pan and roll on the
    2 pi branch nearest to where the servos are, so the move to the first
    frame never unwinds a turn. ``plan_from(present)`` replaces that plan (what
    bring-up checks against the servos), e.g. the range an online plan may use.
    The default plans from the present position and leads the goals
    (:func:`lead_plan`): bring-up checks the goals that will be sent.
    """
    from trajgen.drivers.bringup import bring_up
    from trajgen.stream import plan_joint_trajectory

    if plan_from is None:

        def plan_from(present):
            # Bring-up checks the goals that will be sent (led), not only the plan.
            planned = plan_joint_trajectory(p.kf.spline(), p.rate_hz, start=present)
            return lead_plan(p, planned, quiet=True)

    setup = bring_up(
        bus,
        p.joints,
        p.config.models,
        plan_from,
        watchdog_s=p.config.watchdog_s,
        joint_names=JOINTS,
        set_limits=p.set_limits,
        max_approach_rad=math.radians(args.max_approach),
    )
    p.trajectory = setup.trajectory
    return setup


def stream_plan(bus, args, p: Plan, setup, outcome: Outcome, *, frames=None, clock=None) -> None:
    """Stream the brought-up plan (the streamer's statistics go in ``outcome``).

    ``frames`` (default ``p.trajectory``) is any iterable of joint frames at
    ``p.rate_hz``; ``clock`` defaults to simulated time with --virtual (lock-step,
    as fast as the simulation runs), else the wall clock.
    """
    from trajgen.drivers.clock import WALL_CLOCK, SimulatedClock
    from trajgen.drivers.streamer import Streamer

    if clock is None:
        # Lock-step: simulated time moves with the frames, so do not wait for them.
        clock = SimulatedClock() if args.virtual else WALL_CLOCK

    outcome.streamer = Streamer(
        bus,
        p.joints,
        telemetry=args.telemetry,
        joint_names=JOINTS,
        on_stop="torque_off" if args.torque_off else "hold",
        max_approach_rad=math.radians(args.max_approach),
        goal_bounds_ticks=setup.goal_bounds_ticks,
        max_delay_s=args.max_delay,
        clock=clock,
    )
    try:
        outcome.streamer.run(p.trajectory if frames is None else frames, rate_hz=p.rate_hz)
    finally:
        outcome.stop_errors += outcome.streamer.stop_errors


def _bring_up_summary(setup) -> dict:
    return {
        joint: {
            "servo": s.servo_id,
            "drive_mode": s.drive_mode,
            "operating_mode": mode,
            "position_limits": [int(low), int(high)],
            "start_tick": int(tick),
        }
        for joint, s, mode, (low, high), tick in zip(
            JOINTS,
            setup.installed,
            setup.operating_modes,
            setup.limits_ticks,
            setup.present_ticks,
            strict=True,
        )
    }


def _run(args, signals: _StopSignals, outcome: Outcome, stages=None):
    """Open, bring up, stream; returns (plan, plant) for the report, or an int on bad input.

    ``stages`` is ``(plan, bring_up_servos, stream_plan)`` or replacements with
    the same arguments (``trajgen follow`` streams an online plan).
    """
    from trajgen.drivers.errors import BringUpError, DriverError, Interrupted
    from trajgen.drivers.streamer import safe_stop

    make_plan, bring_up, stream = stages or (plan, bring_up_servos, stream_plan)
    try:
        p = make_plan(args)
        port, virtual, plant = open_port(args, p)
    except (ValueError, TypeError, OSError) as e:
        return bad_input(e)
    on_stop = "torque_off" if args.torque_off else "hold"
    bus = None
    try:
        with signals.armed():
            bus = open_bus(port, args.baud or p.config.baud)
            setup = bring_up(bus, args, p)
            outcome.bring_up = _bring_up_summary(setup)
            stream(bus, args, p, setup, outcome)
    except (DriverError, Interrupted) as e:
        if bus is None and not isinstance(e, Interrupted):
            return bad_input(e)  # the port did not open
        outcome.stopped_by = str(e)
        outcome.status = 128 + e.signum if isinstance(e, Interrupted) else EXIT_FAILED
        streamed = outcome.streamer is not None and outcome.streamer.stats is not None
        outcome.untouched = bus is None
        outcome.refused = isinstance(e, BringUpError) and not streamed
        if bus is not None and not streamed and not outcome.refused:
            # Stopped during bring-up, possibly after it changed something: stop safely.
            outcome.stop_errors += safe_stop(bus, p.joints.ids, on_stop)
    except TrajgenError as e:  # re-planning from the present position (KinematicsError)
        return bad_input(e)
    finally:
        if bus is not None:
            bus.close()
        if virtual is not None:
            virtual.stop()
            if virtual.error is not None:
                print(f"trajgen: virtual bus stopped: {virtual.error}", file=sys.stderr)
    return p, plant


def report(args, p: Plan, plant, outcome: Outcome, extra: dict | None = None) -> int:
    """Print the statistics and what the servos were left doing; write ``--json`` (with
    ``extra`` entries added)."""
    stats = None if outcome.streamer is None else outcome.streamer.stats
    if stats is not None:
        print(stats.format())
    for message in outcome.stop_errors:
        print(f"trajgen: warning: safe stop: {message}", file=sys.stderr)
    if outcome.untouched:
        state = "no servo was touched"
    elif outcome.refused:
        state = "bring-up refused before torque on: no servo was moved"
    elif args.torque_off:
        state = "the servos were released (torque off)"
    else:
        state = "the servos hold their last goal"
    if outcome.stop_errors:
        state += " (except where the safe stop failed: see the warnings above)"
    if outcome.stopped_by:
        kind = "interrupted" if outcome.status > EXIT_FAILED else "stream failed"
        print(f"trajgen: {kind}: {outcome.stopped_by}; {state}", file=sys.stderr)
    else:
        print(f"servos: {state.removeprefix('the servos ')}")
    if args.telemetry and stats is not None:
        print(f"telemetry: {args.telemetry}")
    result = {
        "status": outcome.status,
        "stopped_by": outcome.stopped_by,
        "on_stop": "torque_off" if args.torque_off else "hold",
        "stop_errors": outcome.stop_errors,
        "bring_up": outcome.bring_up,
        "stream": None if stats is None else stats.to_json_dict(),
        **(extra or {}),
    }
    if plant is not None and outcome.status == EXIT_OK:
        outcome.status, outcome.torque_report = torque_report(
            plant, p.trajectory, args, result, lead=p.lead
        )
        result["status"] = outcome.status
    return write_json(args, result, outcome.status)


def torque_report(plant, trajectory, args, result: dict, *, lead: str = "none"):
    """Print (and plot with --plot) the torque report of ``trajectory`` as streamed to
    ``plant``; add it to ``result``; return the exit status and the report (or None)."""
    from trajgen.sim.errors import SimError

    try:
        report = plant.report(trajectory, lead=lead)
    except SimError as e:
        print(f"trajgen: simulation failed: {e}", file=sys.stderr)
        return EXIT_FAILED, None
    print(report.format())
    result["torque"] = report.to_json_dict()
    status = EXIT_OK if report.ok else EXIT_FAILED
    if args.plot:
        from trajgen.sim.plot import plot_report

        try:
            print(f"plot: {plot_report(report, args.plot)}")
        except (OSError, ValueError) as e:
            return bad_input(e), report
    return status, report


def write_json(args, result: dict, status: int) -> int:
    """Write ``result`` to --json if given; return ``status`` (or bad input)."""
    if args.json:
        try:
            with open(args.json, "w", encoding="utf-8") as f:
                json.dump(result, f, indent=2)
        except OSError as e:
            return bad_input(e)
        print(f"json: {args.json}")
    return status


def run_stream(args) -> int:
    """Run ``trajgen stream``; returns the exit status."""
    return run_stages(args, Outcome())


def run_stages(args, outcome: Outcome, stages=None, extra=None) -> int:
    """Plan, open, bring up, stream and report under the stop signals; returns the exit
    status. ``stages`` as for ``_run``; ``extra()`` gives entries for the JSON report."""
    signals = _StopSignals()
    with signals.installed(), _warnings_to_stderr():
        ran = _run(args, signals, outcome, stages)
        if isinstance(ran, int):
            return ran
        status = report(args, *ran, outcome, extra=None if extra is None else extra())
    if signals.received is not None and not outcome.stopped_by:
        # A signal after the stream ended: everything was done and reported.
        status = 128 + signals.received
    return status
