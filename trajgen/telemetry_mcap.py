"""A stream's telemetry as ROS 2 messages in MCAP: the topics, and the rows back.

One telemetry row (the columns of ``trajgen.drivers.telemetry``) becomes four
messages, all stamped with the stream clock's reading when the goal went out
(column ``clock_s``), each with the frame number as its MCAP sequence number:

- ``/trajgen/goal``: ``sensor_msgs/msg/JointState``, the goal sent (rad);
- ``/trajgen/present``: ``sensor_msgs/msg/JointState``, the state read back:
  position (rad), velocity (rad/s), effort (N m: present current times the
  servo's torque constant, where its model is known; empty otherwise); NaN
  where the read failed or was not made;
- ``/trajgen/plan``: ``sensor_msgs/msg/JointState``, the planned position (rad):
  the row's ``plan_rad_*`` columns where it has them, else the goal (then the
  goal sent is the plan);
- ``/trajgen/frame``: ``trajgen_msgs/msg/StreamFrame``, the rest of the row
  (frame number, phase, plan time, lateness, goal ticks, current in A), so
  that every column comes back exactly.

A metadata record ``trajgen.telemetry`` holds the columns, the joint names and
the effort scale. :func:`read_columns` turns a file back into the columns, as
a CSV telemetry file holds them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np

from trajgen.errors import BadArgument
from trajgen.ros2_messages import (
    HEADER_TYPES,
    McapContents,
    definition,
    header,
    read_messages,
    to_ns,
)

GOAL, PRESENT, PLAN, FRAME = "/trajgen/goal", "/trajgen/present", "/trajgen/plan", "/trajgen/frame"

#: Name of the metadata record describing the columns.
METADATA_NAME = "trajgen.telemetry"

#: ``trajgen_msgs/msg/StreamFrame``: a telemetry row's bookkeeping.
STREAM_FRAME = (
    "trajgen_msgs/msg/StreamFrame",
    definition(
        "# One frame of a trajgen stream; header.stamp is clock_s.\n"
        "std_msgs/Header header\n"
        "uint32 frame\n"
        "string phase\n"
        "float64 t_s\n"
        "float64 sent_s\n"
        "float64 lateness_s\n"
        "float64 clock_s\n"
        "string[] name\n"
        "int32[] goal_tick\n"
        "float64[] current_a\n"
        "float64[] voltage_v\n"
        "float64[] temperature_c\n",
        *HEADER_TYPES,
    ),
)

#: The row's scalar columns, carried by ``StreamFrame`` fields of the same name.
_SCALARS = ("frame", "phase", "t_s", "sent_s", "lateness_s", "clock_s")
#: Per-joint column prefix -> (topic, field).
_JOINT_FIELDS = {
    "goal_rad": (GOAL, "position"),
    "goal_tick": (FRAME, "goal_tick"),
    "position_rad": (PRESENT, "position"),
    "velocity_rad_s": (PRESENT, "velocity"),
    "current_a": (FRAME, "current_a"),
    "voltage_v": (FRAME, "voltage_v"),  # read at a low rate: NaN between
    "temperature_c": (FRAME, "temperature_c"),
    "plan_rad": (PLAN, "position"),
}
_OPTIONAL = ("plan_rad", "voltage_v", "temperature_c")


class RowMessages:
    """The MCAP messages of telemetry rows with given columns.

    Parameters
    ----------
    columns : sequence of str
        The telemetry columns, in row order.
    joint_names : sequence of str
    effort_nm_per_a : sequence of float, optional
        Each joint's torque constant (N m/A): effort = current x this. None:
        no effort (the current stays in ``/trajgen/frame``, in A).
    current_scale : sequence of str, optional
        Each joint's current register scale, as stated in the metadata.

    Raises
    ------
    ValueError
        If a column has no field here (every column must come back), or one
        is missing.
    """

    def __init__(
        self,
        columns: Sequence[str],
        joint_names: Sequence[str],
        effort_nm_per_a: Sequence[float] | None = None,
        current_scale: Sequence[str] | None = None,
    ) -> None:
        self.columns = list(columns)
        self.current_scale = None if current_scale is None else list(current_scale)
        self.joint_names = list(joint_names)
        self.effort_nm_per_a = None if effort_nm_per_a is None else list(effort_nm_per_a)
        index = {c: k for k, c in enumerate(self.columns)}
        known = set(_SCALARS)
        self._joint: dict[str, list[int]] = {}
        for prefix in _JOINT_FIELDS:
            names = [f"{prefix}_{j}" for j in self.joint_names]
            if all(n in index for n in names):
                self._joint[prefix] = [index[n] for n in names]
                known.update(names)
            elif prefix not in _OPTIONAL:
                raise BadArgument(f"Expected telemetry columns {names}, got {self.columns}.")
        unknown = [c for c in self.columns if c not in known]
        if unknown:
            raise BadArgument(f"No MCAP field for telemetry column {unknown[0]!r}.")
        missing = [c for c in _SCALARS if c not in index]
        if missing:
            raise BadArgument(f"Expected a telemetry column {missing[0]!r}.")
        self._scalar = {c: index[c] for c in _SCALARS}

    def metadata(self) -> dict[str, str]:
        """The ``trajgen.telemetry`` metadata record (string values, JSON inside)."""
        return {
            "columns": json.dumps(self.columns),
            "joint_names": json.dumps(self.joint_names),
            "effort_nm_per_a": json.dumps(self.effort_nm_per_a),
            "current_scale": json.dumps(self.current_scale),
            "effort": "present current (A) x torque constant (N m/A) = stall torque / stall "
            "current at 12 V of the servo model"
            if self.effort_nm_per_a is not None
            else "not written (servo models unknown); current in A on /trajgen/frame",
        }

    def messages(self, row: Sequence) -> list[tuple[str, dict, int, int]]:
        """The messages of one row: ``(topic, message, log_time_ns, sequence)``."""
        frame = int(row[self._scalar["frame"]])
        clock_s = float(row[self._scalar["clock_s"]])
        stamp, log_time = header(clock_s), to_ns(clock_s)
        names = self.joint_names

        def joint(prefix):
            return [float(row[k]) for k in self._joint[prefix]]

        current = joint("current_a")
        present = {"header": stamp, "name": names, "position": joint("position_rad")}
        present["velocity"] = joint("velocity_rad_s")
        present["effort"] = (
            []
            if self.effort_nm_per_a is None
            else [c * k for c, k in zip(current, self.effort_nm_per_a, strict=True)]
        )
        goal = joint("goal_rad")
        plan = joint("plan_rad") if "plan_rad" in self._joint else goal
        bookkeeping = {c: row[k] for c, k in self._scalar.items()}
        bookkeeping.update(
            header=stamp,
            frame=frame,
            name=names,
            goal_tick=[int(row[k]) for k in self._joint["goal_tick"]],
            current_a=current,
        )
        for prefix in ("voltage_v", "temperature_c"):
            bookkeeping[prefix] = joint(prefix) if prefix in self._joint else []
        empty: list[float] = []
        return [
            (GOAL, _state(stamp, names, goal, empty), log_time, frame),
            (PRESENT, present, log_time, frame),
            (PLAN, _state(stamp, names, plan, empty), log_time, frame),
            (FRAME, bookkeeping, log_time, frame),
        ]


def _state(stamp, names, position, velocity) -> dict:
    return {"header": stamp, "name": names, "position": position, "velocity": velocity}


def read_columns(path, contents: McapContents | None = None) -> dict[str, np.ndarray]:
    """The telemetry columns of an MCAP run log, as the CSV of the same run holds them.

    Frames whose four messages are not all in the file (the last one of a
    file cut short) are left out.

    Parameters
    ----------
    path : str or Path
    contents : McapContents, optional
        Filled in: whether the file was complete, and its metadata.

    Returns
    -------
    dict of str to ndarray, shape (N,)
        Every column of the run (``frame`` and ``goal_tick_*`` int, ``phase``
        str, the rest float; NaN where not measured).

    Raises
    ------
    ValueError
        If the file is not a trajgen run log.
    McapMissing
        If the ``mcap`` extra is not installed.
    """
    contents = McapContents() if contents is None else contents
    by_topic: dict[str, dict[int, object]] = {GOAL: {}, PRESENT: {}, PLAN: {}, FRAME: {}}
    for m in read_messages(path, contents):
        if m.topic in by_topic:
            by_topic[m.topic][m.sequence] = m.message
    layout = contents.metadata.get(METADATA_NAME)
    if layout is None:
        raise BadArgument(f"{path}: not a trajgen run log (no {METADATA_NAME!r} metadata)")
    columns = json.loads(layout["columns"])
    joints = json.loads(layout["joint_names"])
    frames = [k for k in by_topic[FRAME] if all(k in by_topic[t] for t in by_topic)]
    out: dict[str, np.ndarray] = {}
    for name in _SCALARS:
        values = [getattr(by_topic[FRAME][k], name) for k in frames]
        out[name] = np.array(values, dtype=int if name == "frame" else None)
    for prefix, (topic, field) in _JOINT_FIELDS.items():
        if f"{prefix}_{joints[0]}" not in columns:
            continue
        table = np.array([getattr(by_topic[topic][k], field) for k in frames], float)
        table = table.reshape(len(frames), len(joints))
        for j, joint in enumerate(joints):
            column = table[:, j]
            out[f"{prefix}_{joint}"] = column.astype(int) if prefix == "goal_tick" else column
    return {c: out[c] if len(frames) else np.zeros(0) for c in columns}


__all__ = ["FRAME", "GOAL", "PLAN", "PRESENT", "RowMessages", "STREAM_FRAME", "read_columns"]
