"""The ``trajgen excite`` command: stream a multi-sine excitation with telemetry.

The excitation (``sim.excite.Multisine``, about the file's first keyframe) is
the path a ``trajgen.drivers.session.Session`` streams, as ``trajgen stream``
runs it, so bring-up, the approach, the fixed-rate loop, telemetry and the safe
stop are the stream's own.

This module imports quickly: MuJoCo, dynamixel-sdk and pyserial load inside
:func:`run_excite`.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

from trajgen.cli import stream
from trajgen.cli.common import (
    EXIT_OK,
    BadInput,
    exit_status_text,
    load_checked,
    positive_float,
)

DESCRIPTION = """\
Stream a multi-sine excitation to the gimbal with telemetry every frame, for
`trajgen identify`: each joint of the file's gimbal (any [gimbal] axes, 2 or 3
joints) a sum of five sines between 0.3 and 2 Hz (its own frequencies), faded
in and out so it starts and ends at rest, about the file's first keyframe.
Planned like any stream (joint limits, the gimbal-lock guard) and checked
against the torque envelope (torque_margin x the rated-voltage torque-speed
line) before anything moves; then streamed exactly as `trajgen stream` does
(bring-up, approach, telemetry, safe stop).

With --virtual the excitation runs on the simulated gimbal of the file's
[gimbal] tables and the torque report is printed (judged on torque only: an
excitation is meant to lag).

It takes every option of `trajgen stream` (bus, ids, rate, safety, outputs);
--telemetry is required. An excitation that leaves the envelope or the joint
limits is bad input (exit status 2), refused before anything moves.

Then: trajgen identify FILE LOG.csv --out FITTED.toml"""

#: The longest excitation (s). Identification needs tens of seconds; the multi-sine is
#: scaled on a fine grid whose time and memory grow with its length (5,000 s took 55 s
#: and 2.0 GB here), so a slip of the keyboard (``--seconds 1e5``) is refused up front.
MAX_SECONDS = 600.0

#: Tracking budget (rad) of the torque report with --virtual: an excitation lags on purpose.
_NO_TRACKING_BUDGET = math.pi


def register(subparsers) -> None:
    """Add the ``excite`` subcommand to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "excite",
        help="stream a multi-sine excitation with telemetry (for trajgen identify)",
        description=DESCRIPTION,
        epilog=exit_status_text(stream.STREAM_FAILED, signals=True),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    stream.add_stream_arguments(p, telemetry_required=True)
    p.add_argument(
        "--seconds",
        type=positive_float,
        default=8.0,
        metavar="S",
        help=f"duration (s), 3 to {MAX_SECONDS:g} (default %(default)g)",
    )
    p.add_argument(
        "--amplitude",
        type=positive_float,
        metavar="DEG",
        help="largest excursion of every joint (deg) (default 25 for the first joint, "
        "15 for the second, 20 for a third: pan 25, tilt 15, roll 20)",
    )
    p.set_defaults(func=run_excite)


@dataclass(frozen=True)
class ExcitationFile:
    """A keyframe file whose path is an excitation: what ``trajgen stream`` streams.

    Attributes
    ----------
    path : Path
        The keyframe file (for its [bus] and [gimbal] tables, and in messages).
    tables : dict
        Its tables.
    rate_hz : float or None
        Stream rate (Hz).
    motion : sim.excite.Multisine
        The excitation.
    axes : trajgen.axes.AxisSequence
        The gimbal's axes and joint names (``[gimbal] axes``, ``joints``), whose
        kinematics the stream plans with.
    """

    path: Path
    tables: dict
    rate_hz: float | None
    motion: object = field(repr=False)
    axes: object = None

    def spline(self):
        """The excitation, an orientation path (the spline protocol)."""
        return self.motion


def excitation_file(args) -> ExcitationFile:
    """Plan the excitation of ``args.file`` and check it; no hardware.

    Raises
    ------
    ValueError, TypeError, OSError
        Bad input: the file, the options, or an excitation that leaves the
        joint limits, nears gimbal lock or leaves the torque envelope.
    """
    from trajgen.errors import KinematicsError
    from trajgen.gimbal import GimbalKinematics
    from trajgen.jobs.stream_job import kinematics_of
    from trajgen.sim.check import check_planned_torque
    from trajgen.sim.excite import Multisine
    from trajgen.stream import plan_joint_trajectory

    stream.check_stream_outputs(args)
    checked = load_checked(args.file, any_axes=True)  # every table of the file
    kf, config = checked.keyframes, checked.gimbal
    kinematics = kinematics_of(kf) or GimbalKinematics()
    center = kinematics.inverse(kf.quats[:1])[0]
    amplitude = (
        None if args.amplitude is None else (math.radians(args.amplitude),) * kinematics.n_joints
    )
    if args.amplitude is not None and args.amplitude > 180:
        raise BadInput(f"--amplitude {args.amplitude:g}: more than 180 deg, half a turn")
    if args.seconds > MAX_SECONDS:
        raise BadInput(
            f"--seconds {args.seconds:g}: longer than {MAX_SECONDS:g} s, the longest excitation "
            "(identification needs tens of seconds)"
        )
    try:
        motion = Multisine(
            center_rad=center,
            seconds=args.seconds,
            amplitude_rad=amplitude,
            kinematics=kinematics,
        )
    except ValueError as e:
        raise BadInput(f"--seconds: {e}") from e
    rate = kf.stream_rate(args.rate)
    try:
        trajectory = plan_joint_trajectory(motion, rate, kinematics)  # limits, lock guard
    except KinematicsError as e:
        raise BadInput(f"the excitation: {e}; lower --amplitude") from None
    reasons = check_planned_torque(trajectory, config)
    if reasons:
        raise BadInput(
            f"the excitation leaves the torque envelope: {reasons[0]}; lower --amplitude"
        )
    tables = dict(kf.tables)
    if args.virtual:
        tables["gimbal"] = {
            **tables.get("gimbal", {}),
            "max_tracking_error_rad": _NO_TRACKING_BUDGET,
        }
    return ExcitationFile(kf.path, tables, rate, motion, kf.axes)


def run_excite(args) -> int:
    """Run ``trajgen excite``; returns the exit status."""

    def make_job(args):
        from trajgen.drivers.config import bus_config_from_tables
        from trajgen.jobs import StreamJob

        source = excitation_file(args)
        config = bus_config_from_tables(source.tables, source.path)
        # Every stream option applies: --torque-off, --max-delay, --set-limits, ...
        return stream.planned(
            lambda **options: StreamJob.plan(source, config, source.rate_hz, **options), args
        )

    status = stream.run_plan(args, make_job)
    if status == EXIT_OK:
        print(f"next: trajgen identify {args.file} {args.telemetry} --out FITTED.toml")
    return status
