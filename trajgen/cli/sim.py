"""The ``trajgen sim`` command: run a keyframe file through the simulated gimbal.

Without a file it runs trajgen's built-in look-around example.

This module imports quickly: MuJoCo and matplotlib load inside :func:`run_sim`.
"""

from __future__ import annotations

import json
import sys
import time

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    add_file_argument,
    bad_input,
    positive_float,
)

_PROGRESS_AFTER_S = 1.0

DESCRIPTION = """\
Plan the joint stream of a keyframe file, play it to a simulated pan-tilt-roll
gimbal of Dynamixel servos (MuJoCo, 1 ms physics, setpoints held for one stream
period) and check torque: the planned torque (inverse dynamics) must stay within
torque_margin x the 12 V torque-speed envelope tau_stall (1 - |w| / w0), no
simulated step may reach the servo's torque limit, and the tracking error must stay
below the limit. The file's [gimbal] table picks the servos (servo = "XM430-W350"
or servo = {pan = ..., tilt = ..., roll = ...}), payload_kg, payload_offset_m,
torque_margin and max_tracking_error_rad.

exit status: 0 every joint within the envelope, 1 a joint outside it (or the
simulation failed), 2 bad input."""


def register(subparsers) -> None:
    """Add the ``sim`` subcommand to an argparse ``subparsers`` object."""
    import argparse

    p = subparsers.add_parser(
        "sim",
        help="check a keyframe file's torque on a simulated gimbal",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_file_argument(p)
    p.add_argument(
        "--rate",
        type=positive_float,
        metavar="HZ",
        help="stream rate (Hz); default the file's [stream] rate_hz, else 200",
    )
    p.add_argument("--json", metavar="OUT", help="also write the report as JSON to OUT")
    p.add_argument(
        "--plot",
        metavar="OUT.png",
        help="plot joint angles, velocities and torque against the envelope to OUT.png",
    )
    p.add_argument(
        "--video",
        metavar="OUT.mp4",
        help="render the simulated motion to OUT.mp4 (offscreen; needs imageio-ffmpeg)",
    )
    p.set_defaults(func=run_sim)


class _Progress:
    """A stderr progress line, shown only once a run has taken over a second."""

    def __init__(self, stream=None):
        self.stream = sys.stderr if stream is None else stream
        self.start = time.monotonic()
        self.shown = False

    def __call__(self, fraction: float) -> None:
        if not self.shown and time.monotonic() - self.start < _PROGRESS_AFTER_S:
            return
        self.shown = True
        end = "\n" if fraction >= 1.0 else ""
        self.stream.write(f"\rtrajgen sim: simulating {100 * fraction:3.0f}%{end}")
        self.stream.flush()


def run_sim(args) -> int:
    """Run ``trajgen sim``; returns the exit status (0 ok, 1 check failed, 2 bad input)."""
    try:
        return _run(args)
    except KeyboardInterrupt:
        print("", file=sys.stderr)
        return EXIT_INTERRUPTED


def _run(args) -> int:
    from trajgen.sim.check import check_torque
    from trajgen.sim.errors import SimError

    try:
        report = check_torque(args.file, rate_hz=args.rate, progress=_Progress())
    except SimError as e:
        print(f"trajgen: simulation failed: {e}", file=sys.stderr)
        return EXIT_FAILED
    except (ValueError, TypeError, OSError) as e:
        # KeyframeFileError and KinematicsError are ValueErrors.
        return bad_input(e)
    print(report.format())
    try:
        if args.json:
            with open(args.json, "w", encoding="utf-8") as f:
                json.dump(report.to_json_dict(), f, indent=2)
            print(f"json: {args.json}")
        if args.plot:
            from trajgen.sim.plot import plot_report

            print(f"plot: {plot_report(report, args.plot)}")
        if args.video:
            from trajgen.sim.video import render_video

            print(f"video: {render_video(report.record, args.video, report.config)}")
    except (OSError, ValueError, ModuleNotFoundError) as e:
        return bad_input(e)
    return EXIT_OK if report.ok else EXIT_FAILED
