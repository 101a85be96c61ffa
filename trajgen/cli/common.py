"""What every subcommand shares: exit statuses, the bad-input line, argument types."""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

from trajgen.keyframes import BUILTIN_EXAMPLE

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


def baud_rate(text: str) -> int:
    """argparse type: a positive integer baud rate."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a baud rate > 0, got {text!r}")
    return value


def servo_ids(text: str) -> tuple[int, ...]:
    """argparse type: three comma-separated servo ids (pan, tilt, roll)."""
    try:
        ids = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ids like 1,2,3, got {text!r}") from None
    if len(ids) != 3 or len(set(ids)) != 3 or not all(0 <= i <= 252 for i in ids):
        raise argparse.ArgumentTypeError(f"expected 3 distinct ids in 0..252, got {text!r}")
    return ids


def open_bus(port: str, baud: int):
    """Open a ServoBus, turning the latency-timer warning into a stderr line."""
    from trajgen.drivers.bus import ServoBus

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        bus = ServoBus(port, baud=baud).open()
    for w in caught:
        print(f"trajgen: warning: {w.message}", file=sys.stderr)
    return bus
