"""The ``trajgen stream`` command: arguments and printing around ``trajgen.jobs.StreamJob``.

:func:`plan` turns the options into a ``StreamJob`` (everything that can fail on
bad input, before any hardware); :func:`run_plan` runs it under the stop signals
and prints its ``StreamResult`` (the statistics, each servo's state, the torque
report with --virtual; --plot and --json, written on every stop). ``trajgen
follow`` and ``trajgen excite`` run the same two with their own job and stream.

SIGINT, SIGTERM and SIGHUP are handled alike: the servos are stopped safely
(hold, or released with ``--torque-off``), the telemetry and the JSON report
are written, and the exit status is 128 + the signal number (130, 143, 129).

This module imports quickly: dynamixel-sdk, pyserial and MuJoCo load when the
job is planned and run.
"""

from __future__ import annotations

import argparse
import math
import warnings
from contextlib import contextmanager
from pathlib import Path

from trajgen.cli.common import (
    TELEMETRY_SUFFIXES,
    BadInput,
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
    exit_status_text,
    output_path,
    positive_float,
    progress_line,
    tell,
    warn,
    write_json,
)
from trajgen.errors import TrajgenError
from trajgen.jobs import IdCount, LimitsRefused, NoPort, StreamJob

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
    if not joint.isidentifier():
        raise argparse.ArgumentTypeError(f"expected a joint name, got {joint!r}")
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
        "JOINT is a name of the file's [gimbal] joints (pan, tilt, roll by default); "
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


def check_telemetry_path(path: str | None, suffixes: tuple[str, ...], inputs=()) -> None:
    """Refuse ``--telemetry PATH`` up front: writable, a known suffix, not one of
    ``inputs``, and for ``.mcap`` the ``mcap`` extra installed."""
    check_output_path("--telemetry", path, suffixes, inputs)
    suffix = Path(path or "").suffix
    if suffix not in suffixes and suffix.lower() in suffixes:
        # The writers and `trajgen identify` tell the formats apart by the suffix as written.
        raise BadInput(f"--telemetry {path!r}: write the suffix in lower case ({suffix.lower()})")
    if path and path.lower().endswith(".mcap"):
        check_module("--telemetry", "mcap_ros2", "'trajgen[mcap]'")


def check_stream_outputs(args) -> None:
    """Refuse unusable --telemetry, --json and --plot paths before any work (an output
    that is the keyframe file among them)."""
    inputs = [args.file]
    check_telemetry_path(args.telemetry, TELEMETRY_SUFFIXES, inputs)
    check_output_path("--json", args.json, (".json",), inputs)
    check_plot_path(args.plot, inputs)


def plan(args) -> StreamJob:
    """The stream command's job; no hardware.

    Raises
    ------
    ValueError, TypeError, OSError
        Bad input (BadInput, KeyframeFileError and KinematicsError are ValueErrors).
    """
    check_stream_outputs(args)
    if args.virtual and args.port:
        raise BadInput("--port and --virtual exclude each other")
    if args.plot and not args.virtual:
        raise BadInput("--plot needs --virtual (it plots the simulated torque report)")
    return planned(
        lambda **options: StreamJob.from_file(
            args.file, rate_hz=args.rate, say=tell, progress=progress_line, **options
        ),
        args,
    )


def job_options(args) -> dict:
    """``StreamJob.plan`` keywords from the options of :func:`add_stream_arguments`."""
    set_limits = {}
    for joint, low, high in args.set_limits or ():
        if joint in set_limits:
            raise BadInput(f"--set-limits {joint}: given twice; give each joint once")
        set_limits[joint] = (math.radians(low), math.radians(high))
    return {
        "virtual": bool(args.virtual),
        "port": args.port,
        "baud": args.baud,
        "ids": getattr(args, "ids", None),
        "lead": getattr(args, "lead", None),
        "configure": bool(getattr(args, "configure", False)),
        "restore": bool(getattr(args, "restore", False)),
        "on_stop": "torque_off" if args.torque_off else "hold",
        "telemetry": args.telemetry,
        "max_delay_s": args.max_delay,
        "max_approach_rad": math.radians(args.max_approach),
        "set_limits_rad": set_limits,
    }


def planned(make, args) -> StreamJob:
    """``make(**job_options(args))``, its lead notes printed; the job's errors said
    with the options' names."""
    try:
        job = make(**job_options(args))
    except NoPort:
        raise BadInput("no serial port: give --port, set [bus] port, or use --virtual") from None
    except IdCount as e:
        ids = ",".join(map(str, e.ids))
        raise BadInput(
            f"--ids {ids}: expected {len(e.joint_names)} ids, one per joint "
            f"({', '.join(e.joint_names)})"
        ) from None
    for note in job.notes:
        tell(f"note: {note}")
    return job


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
    return run_plan(args, plan)


def run_plan(args, make_job, stream=None, extra=None) -> int:
    """Plan, then run the job under the stop signals and report; returns the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        With ``json`` and (optionally) ``plot``.
    make_job : callable
        ``make_job(args)`` returns a ``StreamJob`` (or raises on bad input).
    stream : callable, optional
        ``stream(session, job)`` runs the session and returns its ``Outcome``; default
        ``job.stream(session)``.
    extra : callable, optional
        ``extra()`` gives entries for the JSON report.
    """
    from trajgen.drivers.signals import StopSignals

    signals = StopSignals()
    with signals.installed(), _warnings_to_stderr():
        try:
            job = make_job(args)
            go = None if stream is None else (lambda session: stream(session, job))
            result = job.run(stream=go, stop_signals=signals, report_to_telemetry=False)
        except LimitsRefused as e:
            low, high = (math.degrees(v) for v in e.limits_rad)
            return bad_input(f"--set-limits {e.name}={low:g}:{high:g}: {e.problem}")
        except (ValueError, TypeError, OSError) as e:  # TrajgenError: re-planning at start
            return bad_input(e)
        if result.outcome.virtual_error is not None:
            tell(f"virtual bus stopped: {result.outcome.virtual_error}")
        if result.port_failed:
            return bad_input(result.outcome.stopped_by)
        if extra is not None:
            result.extra.update(extra())
        status = report(args, result)
    if signals.received is not None and result.outcome.signal is None:
        # A signal after the stream ended: everything was done and reported.
        status = 128 + signals.received
    return status


def report(args, result) -> int:
    """Print a ``StreamResult`` (statistics, what the servos were left doing, the torque
    report), plot it (--plot) and write --json; returns the exit status."""
    outcome = result.outcome
    if outcome.stats is not None:
        print(outcome.stats.format())
    for message in outcome.stop_errors:
        warn(f"safe stop: {message}")
    if outcome.stopped_by:
        tell(result.ending())
    else:
        print(result.ending())
    for servo in outcome.servos:  # each as read back after the stop
        print(f"  {servo.format()}")
    if result.telemetry:
        print(f"telemetry: {result.telemetry}")
    if result.simulation_error is not None:
        tell(f"simulation failed: {result.simulation_error}")
    if result.torque is not None:
        print(result.torque.format())
        plot = getattr(args, "plot", None)
        if plot:
            try:
                plot_torque(result.torque, plot)
            except (OSError, ValueError) as e:
                result.exit_status = bad_input(e)
    if result.telemetry:
        try:
            result.add_to_telemetry(progress_line(f"adding the report to {result.telemetry}"))
        except OSError as e:
            warn(f"telemetry {result.telemetry}: report not added: {e}")
    return write_report(args.json, result.to_json_dict(), result.exit_status)


def plot_torque(torque, path: str) -> None:
    """Plot a torque report to ``path`` (written whole or not at all)."""
    from trajgen.sim.plot import plot_report

    with output_path("--plot", path) as tmp:
        plot_report(torque, tmp)
    print(f"plot: {path}")


def write_report(path, result: dict, status: int) -> int:
    """Write ``result`` to ``path`` (--json) if given; return ``status`` (or bad input)."""
    if path:
        try:
            write_json("--json", path, result)
        except TrajgenError as e:
            return bad_input(e)
        print(f"json: {path}")
    return status
