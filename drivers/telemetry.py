"""Telemetry written as the stream runs, so a fault keeps everything up to it.

CSV (``.csv``): one row per frame, flushed as written. NPZ (``.npz``): the same
columns as arrays, written when the stream stops (on any stop, faults and stop
signals included; only SIGKILL loses it). Until then NPZ rows are spooled to
an anonymous temporary file as binary doubles, so memory stays constant
however long the stream; the file is assembled one column at a time.
"""

from __future__ import annotations

import csv
import math
import struct
import tempfile
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np


def telemetry_columns(joint_names: Sequence[str]) -> list[str]:
    """Column names: frame bookkeeping, then per joint plan / goal / present values.

    ``plan_rad`` is the planned angle, ``goal_rad`` what was sent (led ahead of
    the plan, ``trajgen.lead``), ``position_rad`` where the servo was:
    ``position_rad - plan_rad`` is the real tracking error.
    """
    columns = ["frame", "phase", "t_s", "sent_s", "lateness_s"]
    for prefix in (
        "plan_rad",
        "goal_rad",
        "goal_tick",
        "position_rad",
        "velocity_rad_s",
        "current_a",
    ):
        columns += [f"{prefix}_{name}" for name in joint_names]
    return columns


class TelemetryWriter:
    """Rows of per-frame telemetry to a CSV or NPZ file.

    Parameters
    ----------
    path : str or Path
        Output file, ``.csv`` or ``.npz``.
    joint_names : sequence of str
        Joint names for the column headers.

    Raises
    ------
    ValueError
        If the suffix is neither ``.csv`` nor ``.npz``.
    OSError
        If the file cannot be created.
    """

    def __init__(self, path: str | Path, joint_names: Sequence[str]) -> None:
        self.path = Path(path)
        if self.path.suffix not in (".csv", ".npz"):
            raise ValueError(f"Expected a telemetry path ending .csv or .npz, got {str(path)!r}.")
        self.columns = telemetry_columns(joint_names)
        self.rows = 0
        self._file = None
        self._writer = None
        self._spool = None
        if self.path.suffix == ".csv":
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
        if self._writer is not None:
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
        """Flush and close (NPZ: write the file now, one column at a time)."""
        if self._file is not None:
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


_COLUMNS = {name: k for k, name in enumerate(telemetry_columns(()))}
_PHASE = _COLUMNS["phase"]
