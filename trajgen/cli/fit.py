"""The ``trajgen fit`` command: the fastest smooth retiming that passes the torque check.

This module imports quickly: MuJoCo loads inside :func:`run_fit`.
"""

from __future__ import annotations

import sys
import time

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    add_file_argument,
    add_rate_argument,
    bad_input,
    check_module,
    check_output_path,
    exit_status_text,
    load_checked,
    output_file,
    tell,
)
from trajgen.cli.outputs import check_model_beside
from trajgen.errors import TrajgenError

_PROGRESS_AFTER_S = 1.0

DESCRIPTION = """\
Retime a keyframe file's motion to the servos: the path through the keyframes
(orientations and order; the C3 smooth spline) stays, its clock is replaced by
a smooth time law (a quintic B-spline: the motion stays C3 and at rest at both
ends) that is as fast as `trajgen sim`'s torque check allows: planned torque
within torque_margin x the rated-voltage torque-speed envelope, torque rate within
[limits] torque_rate_nm_s (default 300 N m/s), no simulated step at the torque
limit, tracking within the limit, and the file's optional [limits] table:

  [limits]
  speed_rad_s = 3.0                      # every joint, or {pan = ..., tilt = ...}
  acceleration_rad_s2 = 30.0
  jerk_rad_s3 = 600.0
  torque_rate_nm_s = 300.0

Optimised by a sequential LP (scipy's HiGHS: pip install 'trajgen[fit]'), then
slowed locally where the simulated servo needs it. Prints per segment the old
and new duration and the limit that binds; checks that the same motion 5%
faster fails. Writes the fitted file to --out (whole or not at all, never over
the input): the keyframes at their new times
and a [timing] table with the time law (docs/fit.md), which sim, stream, follow
and plan play exactly; every other table of the input is kept (comments are not)."""


def register(subparsers) -> None:
    """Add the ``fit`` subcommand to an argparse ``subparsers`` object."""
    import argparse

    p = subparsers.add_parser(
        "fit",
        help="fit a keyframe file's timing to the servos' torque",
        description=DESCRIPTION,
        epilog=exit_status_text(
            "no timing passes the torque check and [limits] (e.g. a pose the servos cannot "
            "hold against gravity)"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_file_argument(p)
    p.add_argument(
        "--out", metavar="OUT.toml", required=True, help="write the fitted file to OUT.toml"
    )
    add_rate_argument(p)
    p.set_defaults(func=run_fit)


class _Progress:
    """Progress lines on stderr, shown once the fit has taken over a second."""

    def __init__(self, stream=None):
        self.stream = sys.stderr if stream is None else stream
        self.start = time.monotonic()

    def __call__(self, line: str) -> None:
        elapsed = time.monotonic() - self.start
        if elapsed >= _PROGRESS_AFTER_S:
            self.stream.write(f"trajgen fit: {elapsed:5.1f} s {line.strip()}\n")
            self.stream.flush()


def run_fit(args) -> int:
    """Run ``trajgen fit``; returns the exit status (0 fitted, 1 refused, 2 bad input)."""
    from trajgen.sim.errors import SimError
    from trajgen.sim.fit import fit_timing

    try:
        check_output_path("--out", args.out, (".toml",), [args.file])
        check_module("fit", "scipy", "scipy")  # HiGHS solves the time law's LPs
        checked = load_checked(args.file, any_axes=True)  # every table, [bus] included
        check_model_beside("--out", args.out, args.file, checked.keyframes.tables)
        result = fit_timing(
            checked.keyframes,
            config=checked.gimbal,
            limits=checked.limits,
            rate_hz=args.rate,
            progress=_Progress(),
        )
    except SimError as e:
        tell(f"fit refused: {e}")
        return EXIT_FAILED
    except TrajgenError as e:
        return bad_input(e)
    print(result.format())
    header = (
        f"# Fitted by `trajgen fit` from {args.file}: {result.old_duration_s:.3f} s -> "
        f"{result.duration_s:.3f} s.\n"
    )
    try:
        with output_file("--out", args.out) as f:
            f.write(header + result.toml())
    except TrajgenError as e:
        return bad_input(e)
    print(f"written: {args.out}")
    return EXIT_OK
