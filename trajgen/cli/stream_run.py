"""Running a ``trajgen.jobs.StreamJob`` from the command line, what ``stream``,
``follow`` and ``excite`` share: the options made into the job's keywords
(:func:`job_options`), the job's refusals said with the options' names
(:func:`planned`), the run under the stop signals (:func:`run_plan`) and the
printed ``StreamResult`` (:func:`report`: statistics, each servo's state, the
torque report with --virtual; --plot and --json, written on every stop).

SIGINT, SIGTERM and SIGHUP are handled alike: the servos are stopped safely
(hold, or released with ``--torque-off``), the telemetry and the JSON report
are written, and the exit status is 128 + the signal number (130, 143, 129).
"""

from __future__ import annotations

import math
import warnings
from contextlib import contextmanager

from trajgen.cli.messages import BadInput, bad_input, progress_line, tell, warn
from trajgen.cli.outputs import output_path, write_json
from trajgen.errors import TrajgenError
from trajgen.jobs import IdCount, LimitsRefused, NoPort, StreamJob


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
