"""The ``trajgen`` command line: the one place where the core, the drivers and the simulator meet.

``trajgen`` (the numpy core), ``trajgen.drivers`` and ``trajgen.sim`` never
import this package. Each subcommand lives in a module of its own that
registers itself on the parser and imports its heavy dependencies (MuJoCo,
dynamixel-sdk, matplotlib) only when it runs.
"""

from __future__ import annotations

import argparse
import os
import sys

from trajgen import __version__
from trajgen.cli import excite, fit, follow, identify, plan, scan, sim, stream, sweep, virtual_bus
from trajgen.cli.common import EXIT_INTERRUPTED, EXIT_OK, bad_input
from trajgen.errors import TrajgenError

#: The subcommand modules, in the order ``--help`` lists them.
COMMANDS = (plan, sim, fit, sweep, stream, follow, scan, virtual_bus, excite, identify)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (exit status 2)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``trajgen`` argument parser with every subcommand registered."""
    parser = _Parser(
        prog="trajgen",
        description=(
            "Smooth orientation trajectories for pan-tilt-roll gimbals and robot wrists: "
            "Kim & Nam's circular blending quaternion spline, streamed to Dynamixel servos "
            "or checked for torque in a MuJoCo model."
        ),
        epilog="Exit status: 0 ok, 1 a check or the stream failed, 2 bad input, 130 interrupted.",
    )
    parser.add_argument("--version", action="version", version=f"trajgen {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.register(sub)
    return parser


def main(argv=None) -> int:
    """Entry point; returns the exit status.

    Bad input of any subcommand is a :class:`trajgen.TrajgenError` (keyframe
    file, option, plan size) and ends with exit status 2 and one line; any
    other exception is a bug and shows its traceback. A closed stdout (``trajgen
    plan | head -1``) ends quietly.
    """
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except TrajgenError as e:
        return bad_input(e)
    except KeyboardInterrupt:
        print("trajgen: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader has gone (``| head``): stop writing, and keep Python from
        # complaining when it flushes stdout at exit.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
