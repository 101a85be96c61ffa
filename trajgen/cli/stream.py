"""The ``trajgen stream`` command: its options (:func:`add_stream_arguments`, shared by
every command that streams) and :func:`plan`, the options made into a
``trajgen.jobs.StreamJob`` (everything that can fail on bad input, before any
hardware), run and printed by ``trajgen.cli.stream_run``. ``trajgen follow`` and
``trajgen excite`` run the same with their own job and stream.

This module imports quickly: dynamixel-sdk, pyserial and MuJoCo load when the
job is planned and run.
"""

from __future__ import annotations

import argparse
import math

from trajgen.cli.common import (
    BadInput,
    add_bus_arguments,
    add_file_argument,
    add_ids_argument,
    add_json_argument,
    add_lead_argument,
    add_rate_argument,
    add_telemetry_argument,
    exit_status_text,
    positive_float,
    progress_line,
    tell,
)
from trajgen.cli.help_texts import STREAM_DESCRIPTION, STREAM_FAILED
from trajgen.cli.outputs import check_stream_outputs
from trajgen.cli.stream_run import planned, run_plan
from trajgen.jobs import StreamJob

__all__ = ["STREAM_FAILED", "add_stream_arguments", "plan", "planned", "register", "run_plan"]


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
    if max(abs(low), abs(high)) > 360:  # the registers span one turn
        raise argparse.ArgumentTypeError(f"expected MIN and MAX within -360..360, got {text!r}")
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
        "JOINT is a name of the file's [gimbal] joints (default: pan, tilt, roll); "
        "without it the installed limits are only read, and a plan leaving them is refused",
    )
    p.add_argument(
        "--configure",
        action="store_true",
        help="let bring-up change EEPROM settings the stream needs (Operating Mode) or is "
        "advised (Return Delay Time 0); default: the file's [bus] configure, else off: it "
        "says what it would change and refuses where the stream needs it",
    )
    p.add_argument(
        "--restore",
        action="store_true",
        help="on exit, write back the settings bring-up changed (EEPROM ones need "
        "--torque-off); default: the file's [bus] restore, else off",
    )
    p.add_argument(
        "--max-approach",
        type=positive_float,
        default=45.0,
        metavar="DEG",
        help="refuse to start when a joint is farther than DEG (joint degrees) from the first "
        "frame (default %(default)g)",
    )


# -- plan --------------------------------------------------------------------


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


def run_stream(args) -> int:
    """Run ``trajgen stream``; returns the exit status."""
    return run_plan(args, plan)
