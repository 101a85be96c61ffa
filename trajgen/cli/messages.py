"""What every subcommand says and how it ends: the exit statuses, the one-line
messages (``trajgen <command>: ...``), the exit-status paragraph of ``--help``,
bad input, and the progress line of long work."""

from __future__ import annotations

import ctypes
import sys
import textwrap
import time

from trajgen.errors import TrajgenError

#: Exit statuses shared by every subcommand.
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

#: The subcommand that is running, for the start of every message (``trajgen plan:``).
_running = {"command": None}


class BadInput(TrajgenError):
    """A command-line option that cannot be used; the message names the option."""


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


def from_ctrl_c(error: BaseException) -> bool:
    """Whether ``error`` is Ctrl-C: a KeyboardInterrupt, or one in disguise: an
    ImportError left by it in the middle of an import (a module half-initialised), or
    ctypes' ``ArgumentError`` for one raised while it converted an argument (MuJoCo's
    OpenGL set-up on import), which keeps only its name."""
    if isinstance(error, ctypes.ArgumentError) and ": KeyboardInterrupt:" in str(error):
        return True
    while error is not None:  # the error, then what it came from
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__cause__ or error.__context__
    return False


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


def progress_line(label: str) -> Progress:
    """The running command's progress line: ``trajgen <command>: {label} 42%``."""
    return Progress(f"{prefix()}: {label}")
