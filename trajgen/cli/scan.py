"""The ``trajgen scan`` command: list the Dynamixel servos on a serial port."""

from __future__ import annotations

import argparse

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    add_bus_arguments,
    bad_input,
    exit_status_text,
    open_bus,
    tell,
)

SCAN_DESCRIPTION = """\
Broadcast-ping a serial port and list the Dynamixel servos that answer, with
model and firmware version."""


def register(subparsers) -> None:
    """Add the ``scan`` subcommand to an argparse ``subparsers`` object."""
    s = subparsers.add_parser(
        "scan",
        help="list the Dynamixel servos on a serial port",
        description=SCAN_DESCRIPTION,
        epilog=exit_status_text("no servo answered, or the bus failed"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_bus_arguments(s, virtual=None)
    s.set_defaults(func=run_scan)


def run_scan(args) -> int:
    """Run ``trajgen scan``; returns the exit status."""
    from trajgen.drivers.control_table import Model, model_numbered
    from trajgen.drivers.defaults import DEFAULT_BAUD
    from trajgen.drivers.errors import CommError

    baud = args.baud or DEFAULT_BAUD
    try:
        bus = open_bus(args.port, baud)
    except CommError as e:
        return bad_input(e)
    try:
        found = bus.scan()
    except CommError as e:
        tell(f"scan failed: {e}")
        return EXIT_FAILED
    finally:
        bus.close()  # Ctrl-C: closed here, reported by trajgen.cli.main (130)
    if not found:
        print(f"no servos answered on {args.port} at {baud} baud")
        return EXIT_FAILED
    for servo_id, (number, firmware) in found.items():
        model = model_numbered(number)
        name = model.name if isinstance(model, Model) else model
        print(f"id {servo_id:3d}  model {number:5d} ({name})  firmware {firmware}")
    return EXIT_OK
