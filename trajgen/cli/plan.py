"""The ``trajgen plan`` command: sample a keyframe file's spline to CSV
(``trajgen.plan_csv``, block by block) or to MCAP (``trajgen.plan_mcap``)."""

from __future__ import annotations

import sys

import numpy as np

from trajgen.cli.common import (
    EXIT_OK,
    BadInput,
    Progress,
    add_file_argument,
    add_rate_argument,
    bad_input,
    check_module,
    check_output_path,
    check_timing,
    exit_status_text,
    load_checked,
    output_file,
    output_path,
    prefix,
    speed_warning,
    warn,
)
from trajgen.errors import PlanTooLarge, TrajgenError
from trajgen.plan_csv import BLOCK, joint_columns, write_plan_csv
from trajgen.sampling import MAX_SAMPLES


def run_plan(args) -> int:
    """Run ``trajgen plan``; returns the exit status."""
    try:
        return _plan(args)
    except TrajgenError as e:
        return bad_input(e)


def _plan(args) -> int:
    check_output_path("--out", args.out, inputs=[args.file])
    to_mcap = bool(args.out) and args.out.lower().endswith(".mcap")
    if to_mcap:
        check_module("--out", "mcap_ros2", "'trajgen[mcap]'")
    checked = load_checked(args.file, any_axes=True)
    kf = checked.keyframes
    rate = kf.stream_rate(args.rate)
    try:
        total = check_timing(kf, rate, args.max_samples)
    except PlanTooLarge as e:
        raise PlanTooLarge(f"{e}; --max-samples N raises the limit") from None
    spline = checked.spline
    joints = joint_columns(kf)
    if to_mcap:
        from trajgen.plan_mcap import MAX_SAMPLES as MAX_MCAP_SAMPLES

        if total > MAX_MCAP_SAMPLES:
            raise BadInput(
                f"--out {args.out}: {total:,} samples; an MCAP plan is one JointTrajectory "
                f"message of at most {MAX_MCAP_SAMPLES:,} samples: lower --rate, or write CSV"
            )
        return _plan_mcap(args, kf, spline, rate, None if joints is None else joints.kin)
    if args.out:
        line = Progress(f"{prefix()}: writing {total:,} rows")
        with output_file("--out", args.out, newline="") as out:
            rows, peak_w, peak_a = write_plan_csv(
                out, spline, rate, args.max_samples, lambda done: line(done / total), joints
            )
    else:
        rows, peak_w, peak_a = write_plan_csv(
            sys.stdout, spline, rate, args.max_samples, joints=joints
        )
    print(
        f"planned {kf.path.name}: {rows} samples at {rate:g} Hz over "
        f"{spline.t_end - spline.t_start:.3f} s; peak |omega| {peak_w:.4g} rad/s, "
        f"peak |alpha| {peak_a:.4g} rad/s^2" + (f"; wrote {args.out}" if args.out else ""),
        file=sys.stderr,
    )
    warning = speed_warning(peak_w)
    if warning:
        warn(warning)
    return EXIT_OK


def _plan_mcap(args, kf, spline, rate, kinematics) -> int:
    """``--out plan.mcap``: the exact joint plan and the orientation (``trajgen.plan_mcap``),
    by the ``kinematics`` of the file's axes (None: pan-tilt-roll)."""
    from trajgen.plan_mcap import write_plan_mcap

    progress = Progress(f"{prefix()}: writing {args.out}")
    with output_path("--out", args.out) as tmp:
        plan = write_plan_mcap(tmp, spline, rate, progress=progress, kinematics=kinematics)
    print(
        f"planned {kf.path.name}: {len(plan)} samples at {rate:g} Hz over "
        f"{plan.duration_s:.3f} s; peak |qd| {np.abs(plan.qd).max():.4g} rad/s, "
        f"peak |qdd| {np.abs(plan.qdd).max():.4g} rad/s^2; wrote {args.out} "
        "(JointTrajectory, orientation, plan)",
        file=sys.stderr,
    )
    return EXIT_OK


def register(subparsers) -> None:
    """Add the ``plan`` subcommand to an argparse ``subparsers`` object."""
    plan = subparsers.add_parser(
        "plan",
        help="sample a keyframe file's spline to CSV",
        description=(
            "Sample the spline of a keyframe file at a fixed rate, from the first keyframe "
            "time to the last inclusive. One CSV row per sample: time (s), quaternion "
            "(w, x, y, z), space-frame angular velocity (rad/s) and acceleration (rad/s^2); "
            "for a file whose [gimbal] axes are not 'zyx' (e.g. axes = 'zy', a pan-tilt "
            "head) also the camera's look direction and each joint's angle (rad), velocity "
            "(rad/s) and acceleration (rad/s^2), which point the camera exactly at every "
            "keyframe. The whole file is checked, [gimbal] and [bus] included. The CSV goes to "
            "stdout, or is written whole to --out (never half a file)."
        ),
        epilog=exit_status_text(
            "never (plan has no check that fails; a warning says "
            "when the speed is beyond every servo)"
        ),
    )
    add_file_argument(plan)
    add_rate_argument(plan, "sample rate")
    plan.add_argument(
        "--out",
        metavar="OUT.csv",
        help="write the CSV to OUT.csv (default: stdout); OUT.mcap: the joint plan as a ROS 2 "
        "trajectory_msgs/JointTrajectory and the orientation as quaternions (trajgen[mcap])",
    )
    plan.add_argument(
        "--max-samples",
        type=_count,
        default=MAX_SAMPLES,
        metavar="N",
        help=f"refuse plans of more than N rows (default {MAX_SAMPLES:,}); the CSV is "
        f"written {BLOCK:,} rows at a time, so a larger N costs disk, not memory",
    )
    plan.set_defaults(func=run_plan)


def _count(text: str) -> int:
    """argparse type: a positive integer (``1e8`` accepted)."""
    import argparse

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of rows, got {text!r}") from None
    if not (np.isfinite(value) and value >= 2 and value == int(value)):
        raise argparse.ArgumentTypeError(f"expected a whole number >= 2, got {text!r}")
    return int(value)
