"""The ``trajgen follow`` command: arguments and printing around
``trajgen.follower.Follower`` and ``trajgen.drivers.session.Session.follow``.

The file's plan becomes an :class:`~trajgen.online.OnlineSpline` that JSON lines
on stdin change (read as bytes, a line at most ``MAX_LINE_BYTES`` long, on a
thread of their own); bring-up, the stop signals, the safe stop and the report
are those of ``trajgen stream``.
"""

from __future__ import annotations

import itertools
import sys

from trajgen.cli import stream as stream_command
from trajgen.cli.common import exit_status_text, tell
from trajgen.follower import CHANGE_MARGIN_S, Follower, load_compiled_kernel, online_spline
from trajgen.keyframe_lines import capped_lines

FOLLOW_DESCRIPTION = f"""\
Stream the keyframe file's plan as `trajgen stream` does, and change it while it
runs from JSON lines on stdin, one keyframe per line:

  {{"in": 0.8, "pan": 20, "tilt": 5}}          reach this 0.8 s from now
  {{"t": 12.5, "quat": [1, 0, 0, 0]}}          ... at stream time 12.5 s
  {{"in": 1, "pan": -10, "mode": "extend"}}    after the keyframes still planned

A line with neither "t" nor "in" is an untimed target, reached as early as the
file's [limits] (speed, acceleration, jerk per joint) and the torque-speed
envelope of its servos (x [gimbal] torque_margin) allow, from the motion in
progress; a target within one encoder tick of the current goal changes nothing:

  {{"pan": 20, "tilt": 5}}                    angles (deg), or "quat": [w, x, y, z]
  {{"look_at": [2.0, 0.5, -0.3]}}             a point to look at (m, base frame)
  {{"pan": -10, "max_speed": 90}}             this motion's joints at most 90 deg/s

A gimbal of other [gimbal] axes takes angles by its own joint names
({{"in": 1, "wrist_flex": 30}}); a two-axis head also "look": [x, y, z] (a
direction), and of a "quat" it keeps where it points (exactly: the head cannot
turn about its look axis). "look_at" is for pan-tilt-roll and two-axis gimbals.

"mode": "retarget" (the default) drops the keyframes still ahead and goes
through the new one instead; "extend" keeps them and adds the new one after
them. A change is built and checked in steps, one between two frames of the
stream, and starts {CHANGE_MARGIN_S:g} s after the frame being streamed when it is
begun (longer where the steps need it: at low rates, or for a keyframe far
ahead); its keyframe must lie at least 0.2 s after that. Each line is checked as a keyframe
file checks a keyframe, and the new path against the gimbal's joint limits and
gimbal-lock margin; a bad line is reported on stderr and skipped, and the
stream goes on. The path is C^k across every change (k from the file's
[spline] table) and holds at rest when the keyframes run out. At the end of
stdin the stream ends once the last keyframe is reached.

Bring-up, stop signals, safe stop and report are those of `trajgen stream`;
bring-up checks the whole range the joint limits allow against the servos'
installed limits. --virtual streams on simulated time paced by the wall clock:
in real time beside the lines where the host keeps up, slower (never late, and
said at the end) where it does not; unlike `trajgen stream --virtual`, which
runs as fast as it can. It ends with the torque report of what was streamed.
On a signal the servos hold their last goal, or are released with --torque-off."""


def register(subparsers) -> None:
    """Add the ``follow`` subcommand to an argparse ``subparsers``."""
    import argparse

    p = subparsers.add_parser(
        "follow",
        help="stream a plan that keyframes arriving on stdin (JSON lines) change",
        description=FOLLOW_DESCRIPTION,
        epilog=exit_status_text(stream_command.STREAM_FAILED, signals=True),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    stream_command.add_stream_arguments(p)
    p.set_defaults(func=run_follow)


def run_follow(args) -> int:
    """Run ``trajgen follow`` on the lines of stdin; returns the exit status."""
    stdin = getattr(sys.stdin, "buffer", sys.stdin)  # bytes: a line is decoded once capped
    return follow(args, capped_lines(stdin))


#: Refused lines reported one by one; after these, only counted (binary noise on stdin
#: would otherwise print a line per newline byte).
SHOWN_SKIPS = 20


def _skipped():
    """An ``on_skip``: print the first ``SHOWN_SKIPS`` refused lines, then say once that
    the rest are counted in the summary."""
    count = itertools.count(1)

    def show(message: str) -> None:
        n = next(count)
        if n <= SHOWN_SKIPS:
            tell(f"{message} (line skipped)")
        if n == SHOWN_SKIPS:
            print(
                f"trajgen follow: {SHOWN_SKIPS} lines skipped; more are counted, not shown",
                file=sys.stderr,
                flush=True,
            )

    return show


def follow(args, lines) -> int:
    """``trajgen follow`` with keyframe lines from ``lines`` (see ``Follower.read``);
    returns the exit status."""
    made = {}

    def make_job(args):
        from trajgen.jobs.stream_job import kinematics_of
        from trajgen.sim.check import envelope_check
        from trajgen.sim.limits import limits_from_tables

        job = stream_command.plan(args)
        made["follower"] = Follower(
            online_spline(job.source),
            job.rate_hz,
            kinematics_of(job.source),
            on_skip=_skipped(),
            limits=limits_from_tables(job.source.tables, job.source.path),
            envelope=envelope_check(job.gimbal),
        )
        load_compiled_kernel()  # before the stream starts: evaluations then run compiled
        if job.source.method != "blending" and job.source.timing is None:  # fitted: as is
            print(
                f"trajgen follow: note: {job.source.path}: follow plans with the blending spline "
                "(changes are spliced onto it), not the file's [spline] method = "
                f"{job.source.method!r}",
                file=sys.stderr,
            )
        return job

    def go(session, job):
        try:
            outcome = session.follow(made["follower"], lines)
        finally:
            print(made["follower"].format())
        if outcome.clock is not None:  # --virtual: simulated time, paced by the wall clock
            made["clock"] = outcome.clock
            print(f"follow: {outcome.clock.format()}")
        return outcome

    def extra():
        if "follower" not in made:
            return {}
        summary = made["follower"].summary()
        if "clock" in made:
            summary["simulated_time"] = made["clock"].summary()
        return {"follow": summary}

    return stream_command.run_plan(args, make_job, go, extra)
