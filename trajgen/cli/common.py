"""What every subcommand shares: exit statuses, the bad-input line, argument types,
output-path checks, and loading a keyframe file with every table checked."""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trajgen.errors import TrajgenError
from trajgen.keyframes import BUILTIN_EXAMPLE, KeyframeFile, load_keyframe_file
from trajgen.sampling import MAX_SAMPLES, check_sample_count
from trajgen.servo_table import SERVOS

#: Exit statuses shared by every subcommand.
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

#: Image formats ``--plot`` accepts (matplotlib's Agg backend writes each).
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")

#: Keyframe files above this many keyframes print a line before the spline is built.
_LARGE_FILE_KEYFRAMES = 100_000


class BadInput(TrajgenError):
    """A command-line option that cannot be used; the message names the option."""


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


def add_rate_argument(parser: argparse.ArgumentParser, what: str = "stream rate") -> None:
    """The ``--rate`` option every subcommand shares, with the one default."""
    parser.add_argument(
        "--rate",
        type=positive_float,
        metavar="HZ",
        help=f"{what} (Hz); default the file's [stream] rate_hz, else 200",
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
    """argparse type: a baud rate a Dynamixel X-series servo supports."""
    from trajgen.drivers.config import baud_rates_text
    from trajgen.drivers.control_table import BAUD_RATES

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value not in BAUD_RATES.values():
        raise argparse.ArgumentTypeError(
            f"{value} is not an X-series baud rate (one of {baud_rates_text()})"
        )
    return value


def check_output_path(option: str, path: str | None, suffixes: tuple[str, ...] = ()) -> None:
    """Refuse an output path that cannot be written, before any work is done.

    Parameters
    ----------
    option : str
        The option, named in the message (``"--json"``).
    path : str or None
        What the user gave; None (option not given) passes.
    suffixes : tuple of str
        Accepted extensions (lower case, with the dot); empty accepts any.

    Raises
    ------
    BadInput
        The folder is missing or not writable, the path is a directory or an
        existing file that cannot be written, or the extension is not one of
        ``suffixes``.
    """
    if path is None:
        return
    p = Path(path)
    if not path or p.is_dir():
        raise BadInput(f"{option} {path!r}: is a directory; give a file name")
    if suffixes and p.suffix.lower() not in suffixes:
        raise BadInput(f"{option} {path!r}: expected a {' or '.join(suffixes)} file")
    folder = p.parent
    if not folder.is_dir():
        raise BadInput(f"{option} {path!r}: no such folder {str(folder)!r}")
    if p.exists() and not os.access(p, os.W_OK):
        raise BadInput(f"{option} {path!r}: file is not writable")
    if not p.exists() and not os.access(folder, os.W_OK | os.X_OK):
        raise BadInput(f"{option} {path!r}: folder {str(folder)!r} is not writable")


def check_module(option: str, module: str, package: str) -> None:
    """Refuse ``option`` up front when the optional ``module`` is not installed."""
    if importlib.util.find_spec(module) is None:
        raise BadInput(f"{option} needs the {package} package: pip install {package}")


def check_plot_path(path: str | None) -> None:
    """Refuse ``--plot PATH`` up front: a writable image path, and matplotlib installed."""
    check_output_path("--plot", path, PLOT_SUFFIXES)
    if path is not None:
        check_module("--plot", "matplotlib", "matplotlib")


@dataclass(frozen=True)
class CheckedFile:
    """A keyframe file with every table checked; its spline is built on first use.

    Attributes
    ----------
    keyframes : KeyframeFile
    gimbal : trajgen.sim.GimbalConfig
        From ``[gimbal]``.
    bus : trajgen.drivers.config.BusConfig
        From ``[bus]``.
    limits : trajgen.sim.limits.JointLimits
        From ``[limits]``.
    """

    keyframes: KeyframeFile
    gimbal: object
    bus: object
    limits: object

    @property
    def spline(self):
        """The file's spline (built on first use; raises KeyframeFileError if refused)."""
        n = len(self.keyframes.times)
        if n > _LARGE_FILE_KEYFRAMES:
            print(f"trajgen: building the spline through {n:,} keyframes...", file=sys.stderr)
        return self.keyframes.spline()


def load_checked(path, *, any_axes: bool = False) -> CheckedFile:
    """Load a keyframe file and check every table of it, whatever the command.

    ``plan`` does not use ``[gimbal]`` or ``[bus]``, but a mistake in them is
    refused by every command alike, so a file that plans also simulates and
    streams.

    Parameters
    ----------
    path : str or Path
    any_axes : bool
        Accept a ``[gimbal] axes`` / ``joints`` other than pan-tilt-roll (only
        ``trajgen plan`` does so far); otherwise such a file is refused in one line
        (``trajgen.sim.model.gimbal_config_from_tables``).

    Raises
    ------
    KeyframeFileError
        For any table, keyframe or field; one line naming file and field.
    """
    from trajgen.drivers.config import bus_config_from_tables
    from trajgen.sim.limits import limits_from_tables
    from trajgen.sim.model import gimbal_config_from_tables

    kf = load_keyframe_file(path)
    gimbal = gimbal_config_from_tables(kf.tables, kf.path, any_axes=any_axes)
    bus = bus_config_from_tables(kf.tables, kf.path)
    limits = limits_from_tables(kf.tables, kf.path)
    return CheckedFile(kf, gimbal, bus, limits)


def check_timing(kf: KeyframeFile, rate_hz: float, max_samples: int = MAX_SAMPLES) -> int:
    """Refuse a plan that cannot be sampled sensibly at ``rate_hz``; returns the sample count.

    Two keyframes closer than one sample period cannot both be followed by the
    stream (the motion between them falls between two samples), and a sample
    count above ``max_samples`` would not fit in memory.

    Raises
    ------
    KeyframeFileError
        Two keyframes closer than one period, naming them.
    PlanTooLarge
        Too many samples, with the count and the limit.
    """
    gaps = np.diff(kf.times)
    i = int(np.argmin(gaps))
    if gaps[i] < 1.0 / rate_hz:
        raise kf.error(
            f"keyframes {i + 1} and {i + 2}",
            f"{gaps[i]:.3g} s apart, less than one sample period ({1 / rate_hz:.3g} s at "
            f"{rate_hz:g} Hz): no stream can follow that; space them out or raise the rate",
        )
    try:
        return check_sample_count(kf.times[0], kf.times[-1], rate_hz, max_samples)
    except TrajgenError as e:
        raise type(e)(f"{kf.path}: {e}") from None


def fastest_servo_rad_s() -> tuple[str, float]:
    """The supported servo with the highest no-load speed: name and speed (rad/s)."""
    fastest = max(SERVOS.values(), key=lambda r: r.no_load_speed_rad_s)
    return fastest.name, fastest.no_load_speed_rad_s


def speed_warning(peak_rad_s: float) -> str | None:
    """A warning when a planned angular speed is beyond what any supported servo can turn."""
    name, top = fastest_servo_rad_s()
    if math.isfinite(peak_rad_s) and peak_rad_s <= top:
        return None
    return (
        f"peak |omega| {peak_rad_s:.3g} rad/s is beyond the no-load speed of every supported "
        f"servo (fastest: {name}, {top:.2f} rad/s); `trajgen sim` will fail this motion"
    )


class Progress:
    """A stderr progress line, shown only once the work has taken over a second.

    Call it with the fraction done (0..1). ``fraction`` keeps the last one
    (what was done when a run is interrupted).
    """

    #: Quiet for work shorter than this (s).
    AFTER_S = 1.0

    def __init__(self, label: str, stream=None):
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.start = time.monotonic()
        self.shown = False
        self.fraction = 0.0

    def __call__(self, fraction: float) -> None:
        self.fraction = fraction
        if not self.shown and time.monotonic() - self.start < self.AFTER_S:
            return
        self.shown = True
        end = "\n" if fraction >= 1.0 else ""
        self.stream.write(f"\r{self.label} {100 * fraction:3.0f}%{end}")
        self.stream.flush()


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
