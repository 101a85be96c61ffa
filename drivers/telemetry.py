"""Telemetry written as the stream runs, so a fault keeps everything up to it.

CSV (``.csv``): one row per frame, flushed as written. NPZ (``.npz``): the same
columns as arrays, written when the stream stops (on any stop, faults
included; only a killed process loses it).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np


def telemetry_columns(joint_names: Sequence[str]) -> list[str]:
    """Column names: frame bookkeeping, then per joint goal / present values."""
    columns = ["frame", "phase", "t_s", "sent_s", "lateness_s"]
    for prefix in ("goal_rad", "goal_tick", "position_rad", "velocity_rad_s", "current_a"):
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
        self._arrays: list[list] = []
        if self.path.suffix == ".csv":
            self._file = open(self.path, "w", newline="")  # noqa: SIM115 (closed in close())
            self._writer = csv.writer(self._file)
            self._writer.writerow(self.columns)
            self._file.flush()

    def write(self, row: Sequence) -> None:
        """Append one row (values in ``columns`` order; NaN where not measured)."""
        if self._writer is not None:
            self._writer.writerow("" if isinstance(v, float) and math.isnan(v) else v for v in row)
            self._file.flush()
        else:
            self._arrays.append(list(row))
        self.rows += 1

    def close(self) -> None:
        """Flush and close (NPZ: write the file now)."""
        if self._file is not None:
            self._file.close()
            self._file = None
            self._writer = None
        elif self._arrays is not None:
            columns = list(zip(*self._arrays, strict=True)) if self._arrays else []
            data = {
                name: np.asarray(columns[k] if columns else [])
                for k, name in enumerate(self.columns)
            }
            np.savez(self.path, **data)
            self._arrays = None
