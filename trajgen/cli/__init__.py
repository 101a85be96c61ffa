"""The ``trajgen`` command line: the one place where the core, the drivers and the simulator meet.

``trajgen`` (the numpy core), ``trajgen.drivers`` and ``trajgen.sim`` never
import this package. Each subcommand lives in a module of its own that
registers itself on the parser and imports its heavy dependencies (MuJoCo,
dynamixel-sdk, matplotlib) only when it runs.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import sys

from trajgen import __version__
from trajgen.cli import excite, fit, follow, identify, plan, scan, sim, stream, sweep, virtual_bus
from trajgen.cli.common import (
    EXIT_INTERRUPTED,
    EXIT_OK,
    Parser,
    bad_input,
    exit_status_text,
    from_ctrl_c,
    set_command,
    tell,
)
from trajgen.errors import TrajgenError

#: The subcommand modules, in the order ``--help`` lists them.
COMMANDS = (plan, sim, fit, sweep, stream, follow, scan, virtual_bus, excite, identify)


def build_parser() -> argparse.ArgumentParser:
    """The ``trajgen`` argument parser with every subcommand registered."""
    parser = Parser(
        prog="trajgen",
        description=(
            "Smooth orientation trajectories for pan-tilt-roll gimbals and robot wrists: "
            "Kim & Nam's circular blending quaternion spline, streamed to Dynamixel servos "
            "or checked for torque in a MuJoCo model. Angles are in degrees in files and "
            "on the command line, in radians in the library; times in seconds."
        ),
        epilog=exit_status_text("a check failed (each command's --help says which)", signals=True),
    )
    parser.add_argument("--version", action="version", version=f"trajgen {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.register(sub)
    return parser


def main(argv=None) -> int:
    """Entry point; returns the exit status (the table of :func:`exit_status_text`).

    Bad input of any subcommand is a :class:`trajgen.TrajgenError` (keyframe
    file, option, plan size) and ends with exit status 2 and one line
    starting ``trajgen <command>:``; Ctrl-C, also while the command's heavy
    modules (MuJoCo, the servo SDK) load, ends with 130 and one line; any other
    exception is a bug and shows its traceback. A closed stdout (``trajgen
    plan | head -1``) ends quietly.
    """
    set_command(None)
    try:
        parser = build_parser()
        args, unknown = parser.parse_known_args(argv)
        if unknown:  # said by the subcommand's parser: "trajgen plan: error: ..."
            commands = parser._subparsers._group_actions[0].choices
            commands[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
        set_command(args.command)
        return args.func(args)
    except TrajgenError as e:
        return bad_input(e)
    except KeyboardInterrupt:
        return _interrupted()
    except (ImportError, ctypes.ArgumentError) as e:
        if from_ctrl_c(e):
            return _interrupted()
        raise
    except BrokenPipeError:
        # The reader has gone (``| head``): stop writing, and keep Python from
        # complaining when it flushes stdout at exit.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    finally:
        set_command(None)


def _interrupted() -> int:
    print("", file=sys.stderr)  # after a progress line or ^C
    tell("interrupted")
    return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
