"""The ``trajgen plan`` command: sample a keyframe file's spline to CSV.

The CSV is written in blocks of :data:`BLOCK` samples, so a plan of any length
(``--max-samples``) needs the memory of one block.
"""

from __future__ import annotations

import csv
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
from trajgen.sampling import MAX_SAMPLES, sample_time_blocks

CSV_HEADER = ["t_s", "qw", "qx", "qy", "qz", "wx", "wy", "wz", "ax", "ay", "az"]

#: Samples evaluated and written at a time.
BLOCK = 100_000


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
    joints = _other_axes(kf)
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
            rows, peak_w, peak_a = _write_csv(
                out, spline, rate, args.max_samples, lambda done: line(done / total), joints
            )
    else:
        rows, peak_w, peak_a = _write_csv(sys.stdout, spline, rate, args.max_samples, None, joints)
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


def _write_csv(
    out, spline, rate: float, max_samples: int, progress, joints=None
) -> tuple[int, float, float]:
    """Write the plan's CSV to ``out`` block by block, calling ``progress(rows)`` after
    each; returns the rows written and the peak |omega| (rad/s) and |alpha| (rad/s^2).
    ``joints`` (:class:`_JointColumns`) adds the look and joint columns."""
    total = 0
    peak_w = peak_a = 0.0
    writer = csv.writer(out)
    writer.writerow(CSV_HEADER + ([] if joints is None else joints.header))
    blocks = sample_time_blocks(
        spline.t_start, spline.t_end, rate, block=BLOCK, max_samples=max_samples
    )
    for t in blocks:
        s = spline.evaluate(t, max_order=2)
        total += len(t)
        columns = [s.t, s.q, s.omega, s.alpha]
        if joints is not None:
            columns += joints(s)
        writer.writerows(np.column_stack(columns).round(12).tolist())
        peak_w = max(peak_w, float(np.linalg.norm(s.omega, axis=1).max()))
        peak_a = max(peak_a, float(np.linalg.norm(s.alpha, axis=1).max()))
        if progress is not None:
            progress(total)
    return total, peak_w, peak_a


class _JointColumns:
    """The look direction and joint columns of a plan for axes other than pan-tilt-roll:
    the joint stream (``GimbalKinematics.inverse`` and ``joint_rates``), unwrapped
    from one block to the next; raises ``KinematicsError`` near lock or a limit."""

    def __init__(self, kf):
        from trajgen.gimbal import GimbalKinematics

        self.kin = GimbalKinematics(axes=kf.axes.sequence, joints=kf.axes.joints)
        names = self.kin.joints
        self.header = ["look_x", "look_y", "look_z"] + [
            f"{j}_{unit}" for unit in ("rad", "rad_s", "rad_s2") for j in names
        ]
        self.last = None

    def __call__(self, s) -> list:
        from trajgen import quat

        q = self.kin.inverse(s.q, s.t, start=self.last)
        qd, qdd = self.kin.joint_rates(q, s.omega, s.alpha)
        self.last = q[-1]
        return [quat.rotate(s.q, self.kin.sequence.look), q, qd, qdd]


def _other_axes(kf) -> _JointColumns | None:
    """Joint columns for a file whose ``[gimbal] axes`` / ``joints`` are not pan-tilt-roll."""
    from trajgen.keyframe_axes import is_default

    return None if is_default(kf.axes) else _JointColumns(kf)


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
