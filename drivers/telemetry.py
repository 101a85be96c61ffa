"""Telemetry written as the stream runs, so a fault keeps everything up to it.

The writer is chosen by the file's extension. CSV (``.csv``): one row per
frame, flushed as written. MCAP (``.mcap``, the ``mcap`` extra): ROS 2
messages per frame, encoded and written by a process of its own
(``drivers.mcap_telemetry``; layout in ``trajgen.telemetry_mcap``), readable
up to its last chunk even after SIGKILL; :func:`add_report` then adds the
run's report and log. NPZ (``.npz``): the same columns as arrays, written
when the stream stops (on any stop, faults and stop signals included; only
SIGKILL loses it). Until then NPZ rows are spooled to
an anonymous temporary file as binary doubles, so memory stays constant
however long the stream; the file is assembled one column at a time.
"""

from __future__ import annotations

import csv
import math
import struct
import tempfile
import warnings
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

# Loaded here, not when a stream opens its log: the Bus Watchdog is already
# running then. It imports ``mcap`` only in its writer process.
from trajgen.drivers import mcap_telemetry
from trajgen.servo_table import LOAD_UNIT

from .errors import BadArgument


def telemetry_columns(joint_names: Sequence[str]) -> list[str]:
    """Column names: frame bookkeeping, then per joint plan / goal / present values.

    ``phase`` is "approach", "lift" (``trajgen.lift``: the plan held at its first
    point while the goals bring the static gravity term in) or "stream";
    ``sent_s`` counts from the start of the approach, or of the lift and stream;
    ``clock_s`` is the stream clock's reading when the goal went out (s).
    ``plan_rad`` is the planned angle, ``goal_rad`` what was sent (led ahead of
    the plan, ``trajgen.lead``), ``position_rad`` where the servo was:
    ``position_rad - plan_rad`` is the real tracking error.
    """
    columns = ["frame", "phase", "t_s", "sent_s", "lateness_s", "clock_s"]
    for prefix in (
        "plan_rad",
        "goal_rad",
        "goal_tick",
        "position_rad",
        "velocity_rad_s",
        "current_a",
    ):
        columns += [f"{prefix}_{name}" for name in joint_names]
    # Read at a low rate (``Streamer(health_s=...)``): NaN in the rows between.
    for prefix in ("voltage_v", "temperature_c"):
        columns += [f"{prefix}_{name}" for name in joint_names]
    return columns


class TelemetryWriter:
    """Rows of per-frame telemetry to a CSV, NPZ or MCAP file.

    Parameters
    ----------
    path : str or Path
        Output file, ``.csv``, ``.npz`` or ``.mcap``.
    joint_names : sequence of str
        Joint names for the column headers.
    models : sequence of drivers.control_table.Model, optional
        Each joint's servo model: MCAP states the present effort (N m) with
        its torque constant (stall torque / stall current at 12 V).

    Raises
    ------
    ValueError
        If the suffix is none of ``.csv``, ``.npz``, ``.mcap``.
    OSError
        If the file cannot be created.
    McapMissing
        For ``.mcap`` without the ``mcap`` extra.
    """

    def __init__(self, path: str | Path, joint_names: Sequence[str], models=None) -> None:
        self.path = Path(path)
        if self.path.suffix not in SUFFIXES:
            raise BadArgument(
                f"Expected a telemetry path ending {', '.join(SUFFIXES)}, got {str(path)!r}."
            )
        self.columns = telemetry_columns(joint_names)
        self.rows = 0
        self._file = None
        self._writer = None
        self._spool = None
        self._mcap = None
        if self.path.suffix == ".mcap":
            kt = None if models is None else [m.stall_torque_nm / m.stall_current_a for m in models]
            scale = None if models is None else [_current_scale(m) for m in models]
            self._mcap = mcap_telemetry.McapRunLog(self.path, self.columns, joint_names, kt, scale)
        elif self.path.suffix == ".csv":
            self._file = open(self.path, "w", newline="")  # noqa: SIM115 (closed in close())
            self._writer = csv.writer(self._file)
            self._writer.writerow(self.columns)
            self._file.flush()
        else:
            self._spool = tempfile.TemporaryFile()  # noqa: SIM115 (closed in close())
            self._pack = struct.Struct(f"<{len(self.columns)}d").pack
            self._phases: list[str] = []

    def write(self, row: Sequence) -> None:
        """Append one row (values in ``columns`` order; NaN where not measured)."""
        if self._mcap is not None:
            self._mcap.write(row)
        elif self._writer is not None:
            self._writer.writerow("" if isinstance(v, float) and math.isnan(v) else v for v in row)
            self._file.flush()
        else:
            phase = row[_PHASE]
            if phase not in self._phases:
                self._phases.append(phase)
            numbers = list(row)
            numbers[_PHASE] = self._phases.index(phase)
            self._spool.write(self._pack(*numbers))
        self.rows += 1

    def close(self) -> None:
        """Flush and close (NPZ: write the file now, one column at a time).

        MCAP: wait for the writer process to finish the file; if it failed
        (the file could not be written), a ``RuntimeWarning`` says so (the
        stream's safe stop still follows).
        """
        if self._mcap is not None:
            try:
                self._mcap.close()
            except (OSError, ImportError) as e:  # after the stream: say it, stop safely
                warnings.warn(str(e), RuntimeWarning, stacklevel=2)
        elif self._file is not None:
            self._file.close()
            self._file = None
            self._writer = None
        elif self._spool is not None:
            self._spool.flush()
            n = len(self.columns)
            table = (
                np.memmap(self._spool, dtype="<f8", mode="r", shape=(self.rows, n))
                if self.rows
                else np.zeros((0, n))
            )
            with zipfile.ZipFile(self.path, "w", allowZip64=True) as archive:
                for k, name in enumerate(self.columns):
                    column = np.array(table[:, k])
                    if name == "frame" or name.startswith("goal_tick_"):
                        column = column.astype(np.int64)
                    elif k == _PHASE:
                        column = np.array(self._phases or [""])[column.astype(np.intp)]
                    with archive.open(f"{name}.npy", "w", force_zip64=True) as f:
                        np.lib.format.write_array(f, column)
            del table
            self._spool.close()
            self._spool = None


def _current_scale(model) -> str:
    """How a model's register 126 became the current column (A)."""
    if model.current_unit_a is None:
        return (
            f"{model.name}: Present Load, {LOAD_UNIT:g} x stall current "
            f"({model.stall_current_a:g} A) per unit"
        )
    return f"{model.name}: Present Current, {1e3 * model.current_unit_a:g} mA per unit"


def add_report(path: str | Path, report: dict, progress=None) -> None:
    """Add a run's report (and its faults and stop reason) to its telemetry file.

    MCAP: a metadata record and ``/rosout`` log messages
    (``drivers.mcap_telemetry.add_report``; ``progress`` is called with the
    fraction done). CSV and NPZ hold rows only: nothing.

    Raises
    ------
    OSError
        If the MCAP file cannot be rewritten.
    """
    if Path(path).suffix == ".mcap":
        mcap_telemetry.add_report(path, report, progress)


#: Telemetry file extensions, one writer each.
SUFFIXES = (".csv", ".npz", ".mcap")

_COLUMNS = {name: k for k, name in enumerate(telemetry_columns(()))}
_PHASE = _COLUMNS["phase"]
