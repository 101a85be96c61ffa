"""Extra joint limits a keyframe file may set: the ``[limits]`` table.

```toml
[limits]
speed_rad_s = 3.0                                  # every joint
acceleration_rad_s2 = {pan = 20.0, tilt = 10.0}    # per joint; roll unlimited
jerk_rad_s3 = 500.0
torque_rate_nm_s = 300.0                           # |d torque / dt| per joint (trajgen fit)
```

Each key is optional; a missing key or joint means no limit beyond the torque
check. Joint jerk is taken by central differences of the planned acceleration
at the stream rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trajgen.axes import AxisSequence
from trajgen.validate import check_keys, check_number

from .errors import BadArgument

#: ``[limits]`` keys and the quantity each bounds.
LIMIT_KEYS = {
    "speed_rad_s": "speed",
    "acceleration_rad_s2": "acceleration",
    "jerk_rad_s3": "jerk",
}

#: ``[limits]`` key of the torque-rate bound the retiming fit keeps, and its default
#: (N m/s): docs/fit.md, "The torque-rate bound".
TORQUE_RATE_KEY = "torque_rate_nm_s"
DEFAULT_TORQUE_RATE_NM_S = 300.0


@dataclass(frozen=True)
class JointLimits:
    """Per-joint bounds on |speed|, |acceleration| and |jerk| (inf = none).

    Parameters
    ----------
    speed_rad_s, acceleration_rad_s2, jerk_rad_s3 : float or tuple of float
        Bounds in rad/s, rad/s^2, rad/s^3, one per joint (``joints``); one number
        for every joint. Each > 0. Default: no limit.
    joints : tuple of str
        The joints' names, base out; default pan, tilt, roll.

    Raises
    ------
    TypeError, ValueError
        If a bound is not a number > 0 or a tuple of one per joint.
    """

    speed_rad_s: tuple | float = math.inf
    acceleration_rad_s2: tuple | float = math.inf
    jerk_rad_s3: tuple | float = math.inf
    joints: tuple = AxisSequence().joints

    def __post_init__(self):
        n = len(self.joints)
        for name in LIMIT_KEYS:
            value = getattr(self, name)
            if not isinstance(value, (tuple, list)):
                value = (value,) * n
            if len(value) != n:
                raise BadArgument(f"Expected `{name}` to have {n} entries, got {value!r}.")
            # inf is "no limit"; anything else a finite number > 0.
            bounds = tuple(
                math.inf if v == math.inf else check_number(name, v, low=0.0, low_open=True)
                for v in value
            )
            object.__setattr__(self, name, bounds)

    def as_array(self) -> np.ndarray:
        """Bounds as shape (3, n): rows speed, acceleration, jerk; a column per joint."""
        return np.array([getattr(self, name) for name in LIMIT_KEYS])


def limits_from_tables(tables: dict, path) -> JointLimits:
    """Build :class:`JointLimits` from a keyframe file's ``[limits]`` table (absent: none),
    for the joints of its ``[gimbal]`` (``axes``, ``joints``).

    Raises
    ------
    trajgen.keyframes.KeyframeFileError
        One line naming the file, the table and the key.
    """
    from trajgen.keyframe_axes import axes_from_table
    from trajgen.keyframes import KeyframeFileError

    names = axes_from_table(tables.get("gimbal", {}), Path(path)).joints

    def error(message):
        return KeyframeFileError(f"{Path(path)}: [limits] {message}")

    table = tables.get("limits", {})
    if not isinstance(table, dict):
        raise KeyframeFileError(f"{Path(path)}: [limits]: expected a table, got {table!r}")
    kwargs = {"joints": names}
    check_keys(
        table,
        (*LIMIT_KEYS, TORQUE_RATE_KEY),
        error=lambda p: KeyframeFileError(f"{Path(path)}: [limits]: {p}"),
    )
    for key, value in table.items():
        if key == TORQUE_RATE_KEY:
            torque_rate_from_tables(tables, path)
            continue
        if isinstance(value, dict):
            check_keys(value, names, error=lambda p, k=key: error(f"{k}: {p}"), kind="joint")
            value = tuple(value.get(j, math.inf) for j in names)
        try:
            kwargs[key] = getattr(JointLimits(**{key: value, "joints": names}), key)
        except (TypeError, ValueError):
            table_text = ", ".join(f"{j} = ..." for j in names)
            raise error(
                f"{key}: expected a number > 0 or a table {{{table_text}}}, got {value!r}"
            ) from None
    return JointLimits(**kwargs)


def torque_rate_from_tables(tables: dict, path) -> float:
    """The ``[limits] torque_rate_nm_s`` bound (N m/s), default ``DEFAULT_TORQUE_RATE_NM_S``.

    Raises
    ------
    trajgen.keyframes.KeyframeFileError
        If it is not a number > 0.
    """
    from trajgen.keyframes import KeyframeFileError

    table = tables.get("limits", {})
    value = (
        table.get(TORQUE_RATE_KEY, DEFAULT_TORQUE_RATE_NM_S) if isinstance(table, dict) else None
    )
    return check_number(
        TORQUE_RATE_KEY,
        value,
        low=0.0,
        low_open=True,
        error=lambda p: KeyframeFileError(f"{Path(path)}: [limits] {TORQUE_RATE_KEY}: {p}"),
    )


def joint_jerk(trajectory) -> np.ndarray:
    """Joint jerk (rad/s^3), shape (N, n): central differences of ``trajectory.qdd``."""
    return np.gradient(np.asarray(trajectory.qdd, dtype=float), trajectory.t, axis=0)


def check_limits(trajectory, limits: JointLimits) -> tuple[str, ...]:
    """Reasons the planned stream breaks ``limits`` (empty when it keeps them).

    Parameters
    ----------
    trajectory : trajgen.stream.JointTrajectory
    limits : JointLimits

    Returns
    -------
    tuple of str
        One line per joint and quantity over its bound, naming the peak and its time.
    """
    values = (np.abs(trajectory.qd), np.abs(trajectory.qdd), np.abs(joint_jerk(trajectory)))
    bounds = limits.as_array()
    units = ("rad/s", "rad/s^2", "rad/s^3")
    reasons = []
    for (quantity, value, unit), bound in zip(
        zip(LIMIT_KEYS.values(), values, units, strict=True), bounds, strict=True
    ):
        for j, name in enumerate(limits.joints):
            k = int(np.argmax(value[:, j]))
            if value[k, j] > bound[j]:
                reasons.append(
                    f"{name}: {quantity} {value[k, j]:.3g} {unit} > limit {bound[j]:g} {unit} "
                    f"at t = {trajectory.t[k]:.3f} s"
                )
    return tuple(reasons)
