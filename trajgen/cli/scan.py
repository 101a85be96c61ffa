"""The ``trajgen scan`` command: list the Dynamixel servos on a serial port."""

from __future__ import annotations

import argparse
import sys

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    bad_input,
    baud_rate,
    open_bus,
)

SCAN_DESCRIPTION = """\
Broadcast-ping a serial port and list the Dynamixel servos that answer, with
model and firmware version.

exit status: 0 servos found, 1 none found or the bus failed, 2 bad input."""


def register(subparsers) -> None:
    """Add the ``scan`` subcommand to an argparse ``subparsers`` object."""
    s = subparsers.add_parser(
        "scan",
        help="list the Dynamixel servos on a serial port",
        description=SCAN_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    s.add_argument("--port", required=True, help="serial device, e.g. /dev/ttyUSB0")
    s.add_argument("--baud", type=baud_rate, default=1_000_000, help="baud rate; default 1000000")
    s.set_defaults(func=run_scan)


def run_scan(args) -> int:
    """Run ``trajgen scan``; returns the exit status."""
    from trajgen.drivers.control_table import Model, model_numbered
    from trajgen.drivers.errors import CommError

    try:
        bus = open_bus(args.port, args.baud)
    except CommError as e:
        return bad_input(e)
    try:
        found = bus.scan()
    except CommError as e:
        print(f"trajgen: scan failed: {e}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    finally:
        bus.close()
    if not found:
        print(f"no servos answered on {args.port} at {args.baud} baud")
        return EXIT_FAILED
    for servo_id, (number, firmware) in found.items():
        model = model_numbered(number)
        name = model.name if isinstance(model, Model) else model
        print(f"id {servo_id:3d}  model {number:5d} ({name})  firmware {firmware}")
    return EXIT_OK
