"""The parser and the options every subcommand shares: one wording, metavar and
default per flag (``add_*_argument``), and the argparse types that check them."""

from __future__ import annotations

import argparse

import numpy as np

from trajgen.cli.messages import EXIT_BAD_INPUT
from trajgen.keyframes import BUILTIN_EXAMPLE, DEFAULT_RATE_HZ


class Parser(argparse.ArgumentParser):
    """An argument parser that takes no abbreviation (``--rat`` is not ``--rate``) and
    whose usage errors are one line (exit status 2). Subcommands' parsers are of
    this class too (argparse gives them their parent's)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


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
        "of the plan), advance (the plan tau later) or none; default: the file's "
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
