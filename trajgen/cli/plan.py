"""The ``trajgen plan`` command: sample a keyframe file's spline to CSV."""

from __future__ import annotations

import csv
import sys

import numpy as np

from trajgen.cli.common import EXIT_OK, add_file_argument, positive_float
from trajgen.keyframes import load_keyframe_file

CSV_HEADER = ["t_s", "qw", "qx", "qy", "qz", "wx", "wy", "wz", "ax", "ay", "az"]


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


def register(subparsers) -> None:
    """Add the ``plan`` subcommand to an argparse ``subparsers`` object."""
    plan = subparsers.add_parser(
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
