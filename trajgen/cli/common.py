"""What every subcommand shares, gathered for their imports: the messages and exit
statuses (``messages``), the parser, option builders and types (``arguments``),
output files (``outputs``); and here, loading a keyframe file with every table
checked, the advice on a planned speed, and opening a bus."""

from __future__ import annotations

import math
import warnings

from trajgen.cli.arguments import (
    Parser,
    add_bus_arguments,
    add_file_argument,
    add_ids_argument,
    add_json_argument,
    add_lead_argument,
    add_rate_argument,
    add_telemetry_argument,
    baud_rate,
    positive_float,
    positive_int,
    servo_ids,
)
from trajgen.cli.messages import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    BadInput,
    Progress,
    bad_input,
    exit_status_text,
    from_ctrl_c,
    prefix,
    progress_line,
    set_command,
    tell,
    warn,
)
from trajgen.cli.outputs import (
    PLOT_SUFFIXES,
    TELEMETRY_SUFFIXES,
    check_module,
    check_output_path,
    check_plot_path,
    output_file,
    output_path,
    write_json,
)
from trajgen.jobs.checked_file import check_timing
from trajgen.servo_table import SERVOS

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_FAILED",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "PLOT_SUFFIXES",
    "TELEMETRY_SUFFIXES",
    "BadInput",
    "Parser",
    "Progress",
    "add_bus_arguments",
    "add_file_argument",
    "add_ids_argument",
    "add_json_argument",
    "add_lead_argument",
    "add_rate_argument",
    "add_telemetry_argument",
    "bad_input",
    "baud_rate",
    "check_module",
    "check_output_path",
    "check_plot_path",
    "check_timing",
    "exit_status_text",
    "from_ctrl_c",
    "fastest_servo_rad_s",
    "load_checked",
    "open_bus",
    "output_file",
    "output_path",
    "positive_float",
    "positive_int",
    "prefix",
    "progress_line",
    "servo_ids",
    "set_command",
    "speed_warning",
    "tell",
    "warn",
    "write_json",
]


def load_checked(path, *, spline: bool = True, any_axes: bool = False):
    """``trajgen.jobs.load_checked`` (every table of a keyframe file checked) with a slow
    spline build's cost and progress said on stderr."""
    from trajgen.jobs import load_checked as load

    return load(path, spline=spline, any_axes=any_axes, say=tell, progress=progress_line)


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


def open_bus(port: str, baud: int):
    """Open a ServoBus, turning the latency-timer warning into a stderr line."""
    from trajgen.drivers.bus import ServoBus

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        bus = ServoBus(port, baud=baud).open()
    for w in caught:
        warn(w.message)
    return bus
