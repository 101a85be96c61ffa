"""The ``trajgen`` command: plan here; ``sim``, ``stream`` and ``scan`` come from their packages.

This is the one place where the three packages meet: ``trajgen`` itself imports
neither ``sim`` nor ``drivers``. Each package's ``cli`` module registers its
subcommands and imports its heavy dependencies only when one runs.
"""

from __future__ import annotations

import argparse
import csv
import sys

import numpy as np

from .keyframes import BUILTIN_EXAMPLE, KeyframeFileError, load_keyframe_file

#: Exit statuses shared by every subcommand.
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

CSV_HEADER = ["t_s", "qw", "qx", "qy", "qz", "wx", "wy", "wz", "ax", "ay", "az"]


def bad_input(message) -> int:
    """Print the one-line error for bad input and return its exit status."""
    print(f"trajgen: error: {message}", file=sys.stderr)
    return EXIT_BAD_INPUT


def add_file_argument(parser: argparse.ArgumentParser) -> None:
    """The optional keyframe-file argument every subcommand shares."""
    parser.add_argument(
        "file",
        nargs="?",
        default=str(BUILTIN_EXAMPLE),
        help="keyframe file (TOML); default: the built-in look-around example",
    )


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def run_plan(args) -> int:
    kf = load_keyframe_file(args.file)
    rate = args.rate or kf.rate_hz or 100.0
    samples = kf.spline().sample(rate, max_order=2)
    rows = np.column_stack([samples.t, samples.q, samples.omega, samples.alpha])
    out = open(args.out, "w", newline="") if args.out else sys.stdout
    try:
        writer = csv.writer(out)
        writer.writerow(CSV_HEADER)
        writer.writerows(rows.round(12).tolist())
    finally:
        if args.out:
            out.close()
    peak_w = np.linalg.norm(samples.omega, axis=1).max()
    peak_a = np.linalg.norm(samples.alpha, axis=1).max()
    print(
        f"planned {kf.path.name}: {len(samples.t)} samples at {rate:g} Hz over "
        f"{samples.t[-1] - samples.t[0]:.3f} s; peak |omega| {peak_w:.3f} rad/s, "
        f"peak |alpha| {peak_a:.3f} rad/s^2" + (f"; wrote {args.out}" if args.out else ""),
        file=sys.stderr,
    )
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="trajgen",
        description=(
            "Smooth orientation trajectories for pan-tilt-roll gimbals and robot wrists: "
            "Kim & Nam's circular blending quaternion spline, streamed to Dynamixel servos "
            "or checked for torque in a MuJoCo model."
        ),
        epilog="Exit status: 0 ok, 1 a check or the stream failed, 2 bad input, 130 interrupted.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    plan = sub.add_parser(
        "plan",
        help="sample a keyframe file's spline to CSV",
        description=(
            "Sample the spline of a keyframe file at a fixed rate, from the first keyframe "
            "time to the last inclusive. One CSV row per sample: time (s), quaternion "
            "(w, x, y, z), space-frame angular velocity (rad/s) and acceleration (rad/s^2)."
        ),
    )
    add_file_argument(plan)
    plan.add_argument(
        "--rate",
        type=positive_float,
        metavar="HZ",
        help="sample rate (default: the file's [stream] rate_hz, else 100)",
    )
    plan.add_argument("--out", metavar="FILE.csv", help="write the CSV here (default: stdout)")
    plan.set_defaults(func=run_plan)

    from drivers.cli import register as register_drivers
    from sim.cli import register as register_sim

    register_sim(sub)
    register_drivers(sub)
    return parser


def main(argv=None) -> int:
    """Entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyframeFileError as e:
        return bad_input(e)
    except KeyboardInterrupt:
        print("trajgen: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
