"""What every subcommand shares: the parser, exit statuses, the error line, argument
builders (one wording, metavar and default per flag), argument types, output paths
(checked before work, written atomically) and loading a keyframe file with every
table checked."""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import stat
import sys
import tempfile
import textwrap
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from trajgen.errors import TrajgenError
from trajgen.jobs.checked_file import check_timing as check_timing  # the commands' import
from trajgen.keyframes import (
    BUILTIN_EXAMPLE,
    DEFAULT_RATE_HZ,
)
from trajgen.servo_table import SERVOS

#: Exit statuses shared by every subcommand.
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

#: Image formats ``--plot`` accepts (matplotlib's Agg backend writes each).
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")
#: Telemetry formats (``trajgen stream --telemetry``, ``excite``, read by ``identify``).
TELEMETRY_SUFFIXES = (".csv", ".npz", ".mcap")

#: Folders of kernel interfaces, never an output (``--out /proc/...``).
_KERNEL_FOLDERS = ("/proc", "/sys")

#: The subcommand that is running, for the start of every message (``trajgen plan:``).
_running = {"command": None}


class BadInput(TrajgenError):
    """A command-line option that cannot be used; the message names the option."""


class Parser(argparse.ArgumentParser):
    """An argument parser that takes no abbreviation (``--rat`` is not ``--rate``) and
    whose usage errors are one line (exit status 2). Subcommands' parsers are of
    this class too (argparse gives them their parent's)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def set_command(name: str | None) -> None:
    """Name the running subcommand (``main`` does), for :func:`prefix`."""
    _running["command"] = name


def prefix() -> str:
    """How every message of the running command starts: ``"trajgen plan"``."""
    command = _running["command"]
    return "trajgen" if command is None else f"trajgen {command}"


def tell(message: str) -> None:
    """Print ``"trajgen <command>: {message}"`` on stderr."""
    print(f"{prefix()}: {message}", file=sys.stderr, flush=True)


def warn(message) -> None:
    """Print ``"trajgen <command>: warning: {message}"`` on stderr."""
    tell(f"warning: {message}")


def bad_input(message) -> int:
    """Print the one-line error for bad input and return its exit status."""
    tell(f"error: {message}")
    return EXIT_BAD_INPUT


def exit_status_text(failed: str, *, signals: bool = False) -> str:
    """The exit-status paragraph of a command's ``--help``, the same table for every
    command; ``failed`` says what gives status 1 for this one."""
    stopped = (
        "128 + the signal number when stopped by a signal (130 SIGINT/Ctrl-C, 143 SIGTERM, "
        "129 SIGHUP)"
        if signals
        else f"{EXIT_INTERRUPTED} interrupted (Ctrl-C)"
    )
    return textwrap.fill(
        f"exit status: {EXIT_OK} ok, {EXIT_FAILED} {failed}, {EXIT_BAD_INPUT} bad input "
        f"(one line on stderr naming the option, file or field), {stopped}.",
        width=79,
    )


def add_file_argument(parser: argparse.ArgumentParser) -> None:
    """The optional keyframe-file argument every subcommand shares."""
    parser.add_argument(
        "file",
        nargs="?",
        default=str(BUILTIN_EXAMPLE),
        help="keyframe file (TOML; times in s, angles in degrees); default: the built-in "
        "look-around example",
    )


def add_rate_argument(parser: argparse.ArgumentParser, what: str = "stream rate") -> None:
    """The ``--rate`` option every subcommand shares, with the one default."""
    parser.add_argument(
        "--rate",
        type=positive_float,
        metavar="HZ",
        help=f"{what} (Hz); default: the file's [stream] rate_hz, else {DEFAULT_RATE_HZ:g}",
    )


def add_lead_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--lead`` option of everything that streams (and ``trajgen sim``)."""
    from trajgen.lead import LEADS

    parser.add_argument(
        "--lead",
        choices=LEADS,
        help="send each goal ahead of the plan by the servo's lag: model (inverse dynamics "
        "of the plan), advance (the plan tau later) or none; default the file's "
        "[stream] lead, else model (docs/lead.md)",
    )


def add_json_argument(
    parser: argparse.ArgumentParser, what: str = "the report", *, atomic: bool = True
) -> None:
    """The ``--json OUT.json`` option every reporting subcommand shares (``atomic``: the
    command writes it with :func:`write_json`)."""
    parser.add_argument(
        "--json",
        metavar="OUT.json",
        help=f"also write {what} as JSON to OUT.json (units in the key names: _s, _rad, _nm, "
        f"...{'; written whole or not at all' if atomic else ''})",
    )


def add_telemetry_argument(parser: argparse.ArgumentParser, *, required: bool = False) -> None:
    """The ``--telemetry LOG`` option of the streaming subcommands."""
    parser.add_argument(
        "--telemetry",
        metavar="LOG.csv",
        required=required,
        help="write per-frame telemetry to LOG.csv (or .npz, or .mcap: ROS 2 messages for "
        "Foxglove, needs trajgen[mcap]): goals and present positions (ticks and rad), "
        "velocities, currents; what was streamed is kept on any stop",
    )


def add_ids_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--ids P,T,R`` option of the subcommands that talk to servos."""
    parser.add_argument(
        "--ids",
        type=servo_ids,
        metavar="ID,ID[,ID]",
        help="servo ids of the joints in order (pan, tilt, roll); default: the file's "
        "[bus] ids, else 1,2,3",
    )


def add_bus_arguments(parser: argparse.ArgumentParser, virtual: str | None) -> None:
    """``--port`` (or ``--virtual``, excluding each other in the parser) and ``--baud``.

    Parameters
    ----------
    virtual : str or None
        Help of ``--virtual``; None: the command has no virtual bus and needs ``--port``.
    """
    from_file = virtual is not None
    where = parser.add_mutually_exclusive_group() if from_file else parser
    where.add_argument(
        "--port",
        metavar="DEVICE",
        required=not from_file,
        help="serial device, e.g. /dev/ttyUSB0"
        + ("; default: the file's [bus] port" if from_file else ""),
    )
    if from_file:
        where.add_argument("--virtual", action="store_true", help=virtual)
    parser.add_argument(
        "--baud",
        type=baud_rate,
        metavar="BAUD",
        help="baud rate (an X-series rate, up to 4500000); default: "
        + ("the file's [bus] baud, else " if from_file else "")
        + f"{_default_baud()} (the servos' factory setting)",
    )


def _default_baud() -> int:
    from trajgen.drivers.defaults import DEFAULT_BAUD

    return DEFAULT_BAUD


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse type: a whole number >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
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


def check_output_path(
    option: str, path: str | None, suffixes: tuple[str, ...] = (), inputs=()
) -> None:
    """Refuse an output path that cannot be written, before any work is done.

    Parameters
    ----------
    option : str
        The option, named in the message (``"--json"``).
    path : str or None
        What the user gave; None (option not given) passes.
    suffixes : tuple of str
        Accepted extensions (lower case, with the dot); empty accepts any.
    inputs : iterable of str or Path
        Files the command reads: an output that is one of them (by name, through
        a symbolic link or as a hard link) is refused, as writing it would
        destroy the input.

    Raises
    ------
    BadInput
        The folder is missing or not writable, the path is a directory, a
        kernel interface (``/proc``, ``/sys``), an input, an existing file that
        cannot be written, or the extension is not one of ``suffixes``.
    """
    if path is None:
        return
    p = Path(path)
    if not path or p.is_dir():
        raise BadInput(f"{option} {path!r}: is a directory; give a file name")
    # /dev/stdout leads into /proc/self/fd: devices are written in place, not refused.
    names = {os.path.abspath(p)} if _in_place(p) else {os.path.abspath(p), os.path.realpath(p)}
    for kernel in _KERNEL_FOLDERS:
        if any(name == kernel or name.startswith(kernel + os.sep) for name in names):
            raise BadInput(
                f"{option} {path!r}: is in {kernel}, a kernel interface, not a place for "
                "files; give a file name"
            )
    for source in inputs:
        if _same_file(p, Path(source)):
            raise BadInput(
                f"{option} {path!r}: is the input file {str(source)!r}; writing it would "
                "destroy it: give another name"
            )
    if _in_place(p):
        if p.exists() and not os.access(p, os.W_OK):
            raise BadInput(f"{option} {path!r}: is not writable")
        return  # a device or pipe (/dev/null, /dev/stdout): written as it is
    if suffixes and p.suffix.lower() not in suffixes:
        raise BadInput(f"{option} {path!r}: expected a {' or '.join(suffixes)} file")
    folder = p.parent
    if not folder.is_dir():
        raise BadInput(f"{option} {path!r}: no such folder {str(folder)!r}")
    if p.exists() and not os.access(p, os.W_OK):
        raise BadInput(f"{option} {path!r}: file is not writable")
    if not os.access(folder, os.W_OK | os.X_OK):
        # Every output is written to a temporary file in its folder, then renamed.
        raise BadInput(f"{option} {path!r}: folder {str(folder)!r} is not writable")


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file (same path, a link to it, a hard link)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return os.path.realpath(a) == os.path.realpath(b)


def _in_place(path: Path) -> bool:
    """A device, pipe or socket, or anything in /dev (``/dev/stdout`` redirected to a
    file too): written in place, never replaced by a renamed file."""
    if os.path.abspath(path).startswith("/dev/"):
        return True
    try:
        return not stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


@contextmanager
def output_path(option: str, path: str):
    """A temporary path beside ``path`` (same suffix) to write an output to; renamed to
    ``path`` when the block ends without error, removed when it fails, so that
    ``path`` is the whole output or untouched. A device (``/dev/null``) is written
    directly; through a symbolic link, the file it names is replaced (the link stays).

    Raises
    ------
    BadInput
        When writing or renaming fails (a full disk, ``/dev/full``): one line
        naming the option and the path; the temporary file is removed.
    """
    target = Path(path)
    if _in_place(target):
        try:
            yield str(target)
        except OSError as e:
            raise BadInput(f"{option} {path!r}: cannot write: {e.strerror or e}") from None
        return
    target = Path(os.path.realpath(target))  # through a symbolic link: replace what it names
    try:
        fd, tmp = tempfile.mkstemp(
            dir=target.parent, prefix=f".{target.name}.", suffix=f".part{target.suffix}"
        )
        os.close(fd)
    except OSError as e:
        raise BadInput(f"{option} {path!r}: cannot write: {e.strerror or e}") from None
    try:
        yield tmp
        if target.exists():  # keep the permissions of the file being replaced
            os.chmod(tmp, stat.S_IMODE(os.stat(target).st_mode))
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except OSError as e:
        raise BadInput(f"{option} {path!r}: cannot write: {e.strerror or e}") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


@contextmanager
def output_file(option: str, path: str, mode: str = "w", **open_kwargs):
    """An open file that becomes ``path`` only when the block ends without error
    (:func:`output_path`); text files are UTF-8 unless told."""
    if "b" not in mode:
        open_kwargs.setdefault("encoding", "utf-8")
    with output_path(option, path) as tmp:
        try:
            with open(tmp, mode, **open_kwargs) as f:
                yield f
        except OSError as e:
            raise BadInput(f"{option} {path!r}: cannot write: {e.strerror or e}") from None


def write_json(option: str, path: str, data) -> None:
    """Write ``data`` as indented JSON to ``path``, whole or not at all."""
    import json

    with output_file(option, path) as f:
        json.dump(data, f, indent=2)


def check_module(option: str, module: str, package: str) -> None:
    """Refuse ``option`` up front when the optional ``module`` is not installed."""
    if importlib.util.find_spec(module) is None:
        raise BadInput(f"{option} needs the {package} package: pip install {package}")


def check_plot_path(path: str | None, inputs=()) -> None:
    """Refuse ``--plot PATH`` up front: a writable image path, and matplotlib installed."""
    check_output_path("--plot", path, PLOT_SUFFIXES, inputs)
    if path is not None:
        check_module("--plot", "matplotlib", "matplotlib")


def load_checked(path, *, spline: bool = True, any_axes: bool = False):
    """``trajgen.jobs.load_checked`` (every table of a keyframe file checked) with a slow
    spline build's cost and progress said on stderr."""
    from trajgen.jobs import load_checked as load

    def progress(label: str) -> Progress:
        return Progress(f"{prefix()}: {label}")

    return load(path, spline=spline, any_axes=any_axes, say=tell, progress=progress)


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
    """argparse type: comma-separated distinct servo ids in 0..252 (how many is the
    command's to check against the file's joints)."""
    try:
        ids = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ids like 1,2,3, got {text!r}") from None
    if len(set(ids)) != len(ids) or not all(0 <= i <= 252 for i in ids):
        raise argparse.ArgumentTypeError(f"expected distinct ids in 0..252, got {text!r}")
    return ids


def open_bus(port: str, baud: int):
    """Open a ServoBus, turning the latency-timer warning into a stderr line."""
    from trajgen.drivers.bus import ServoBus

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        bus = ServoBus(port, baud=baud).open()
    for w in caught:
        warn(w.message)
    return bus
