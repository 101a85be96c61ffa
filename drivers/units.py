"""Radians <-> register units, at the edge of the driver.

A joint maps to a servo by id, direction (+1 or -1) and zero (the tick that
is joint angle 0): ``tick = zero + direction * round(angle / RAD_PER_TICK)``,
4096 ticks a turn. The defaults are ids 1, 2, 3 = pan, tilt, roll, direction
+1, zero 2048 (for other ids, direction +1 and zero 2048 for each). The encoder
and velocity units are the servo table's (``trajgen.servo_table``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from trajgen.servo_table import RAD_PER_TICK, TICKS_PER_REV, VELOCITY_UNIT_RAD_S, ZERO_TICK
from trajgen.validate import check_number

from .errors import BadArgument

__all__ = [
    "RAD_PER_TICK",
    "TICKS_PER_REV",
    "VELOCITY_UNIT_RAD_S",
    "ZERO_TICK",
    "JointMap",
    "rad_to_servo_ticks",
    "servo_ticks_to_rad",
    "to_signed",
    "to_unsigned",
]


def to_signed(value: int, size: int) -> int:
    """Two's-complement decoding of an unsigned ``size``-byte register value.

    Raises
    ------
    ValueError
        If ``size`` is not 1, 2 or 4, or ``value`` does not fit in it.
    """
    if size not in (1, 2, 4):
        raise BadArgument(f"Expected `size` 1, 2 or 4 bytes, got {size}.")
    bits = 8 * size
    if not 0 <= value < 1 << bits:
        raise BadArgument(f"Expected `value` in 0..{(1 << bits) - 1}, got {value}.")
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def to_unsigned(value: int, size: int) -> int:
    """Two's-complement encoding of a signed value into ``size`` bytes.

    Raises
    ------
    ValueError
        If ``value`` does not fit in ``size`` bytes (signed or unsigned).
    """
    bits = 8 * size
    if not -(1 << (bits - 1)) <= value < 1 << bits:
        raise BadArgument(f"Expected `value` to fit in {size} bytes, got {value}.")
    return value & ((1 << bits) - 1)


def rad_to_servo_ticks(angle_rad: np.ndarray | float) -> np.ndarray:
    """Servo-frame position ticks of an angle (zero at 2048, no direction)."""
    return ZERO_TICK + np.rint(np.asarray(angle_rad) / RAD_PER_TICK).astype(np.int64)


def servo_ticks_to_rad(ticks: np.ndarray | int) -> np.ndarray:
    """Servo-frame angle (rad) of position ticks (zero at 2048, no direction)."""
    return (np.asarray(ticks) - ZERO_TICK) * RAD_PER_TICK


@dataclass(frozen=True)
class JointMap:
    """Which servo drives each joint, and how its ticks relate to the joint angle.

    Attributes
    ----------
    ids : tuple of int, shape (n,)
        Servo ids in joint order (pan, tilt, roll; any 2 or 3 joints, or more),
        distinct, 0..252.
    directions : tuple of int, shape (n,)
        +1 or -1 per joint; default +1 for every id.
    zeros : tuple of int, shape (n,)
        Tick at joint angle 0, per joint; default 2048 for every id.

    Raises
    ------
    ValueError
        If the lengths differ, ids repeat or fall outside 0..252, a direction
        is not +-1.
    """

    ids: tuple[int, ...] = (1, 2, 3)
    directions: tuple[int, ...] | None = None
    zeros: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        if isinstance(self.ids, Sequence):
            if self.directions is None:
                object.__setattr__(self, "directions", (1,) * len(self.ids))
            if self.zeros is None:
                object.__setattr__(self, "zeros", (ZERO_TICK,) * len(self.ids))
        for name in ("ids", "directions", "zeros"):
            value = getattr(self, name)
            if not isinstance(value, Sequence):
                raise TypeError(f"Expected `{name}` to be a sequence of int, got {value!r}.")
            ints = tuple(check_number(f"{name}[{i}]", v, integer=True) for i, v in enumerate(value))
            object.__setattr__(self, name, ints)
        n = len(self.ids)
        if n == 0 or len(self.directions) != n or len(self.zeros) != n:
            raise BadArgument(
                "Expected `ids`, `directions`, `zeros` of one non-zero length, got "
                f"{len(self.ids)}, {len(self.directions)}, {len(self.zeros)}."
            )
        if len(set(self.ids)) != n or not all(0 <= i <= 252 for i in self.ids):
            raise BadArgument(f"Expected distinct `ids` in 0..252, got {self.ids}.")
        if not all(d in (1, -1) for d in self.directions):
            raise BadArgument(f"Expected `directions` of +1 or -1, got {self.directions}.")

    def __len__(self) -> int:
        return len(self.ids)

    def to_ticks(self, q_rad: np.ndarray) -> np.ndarray:
        """Goal ticks of joint angles.

        Parameters
        ----------
        q_rad : array_like, shape (..., n)
            Joint angles (rad).

        Returns
        -------
        ndarray of int64, shape (..., n)

        Raises
        ------
        ValueError
            If the last axis is not ``n`` long or an angle is not finite.
        """
        q = np.asarray(q_rad, dtype=float)
        if q.ndim == 0 or q.shape[-1] != len(self):
            raise BadArgument(f"Expected `q_rad` of shape (..., {len(self)}), got {q.shape}.")
        if not np.all(np.isfinite(q)):
            raise BadArgument("Expected finite `q_rad`, got NaN or inf.")
        d = np.asarray(self.directions)
        return np.asarray(self.zeros) + np.rint(d * q / RAD_PER_TICK).astype(np.int64)

    def to_rad(self, ticks: np.ndarray) -> np.ndarray:
        """Joint angles (rad) of position ticks, shape (..., n) -> (..., n)."""
        t = np.asarray(ticks, dtype=float)
        return np.asarray(self.directions) * (t - np.asarray(self.zeros)) * RAD_PER_TICK

    def limit_ticks(self, joint: int, low_rad: float, high_rad: float) -> tuple[int, int]:
        """Min and Max Position Limit (ticks) that keep joint ``joint`` in ``low_rad..high_rad``.

        Parameters
        ----------
        joint : int
            Joint index (0..n-1).
        low_rad, high_rad : float
            The joint's range (rad), in joint angles (direction and zero applied).

        Returns
        -------
        (int, int)
            ``(min, max)`` ticks, ``min < max`` whatever the joint's direction.

        Raises
        ------
        ValueError
            If the ticks fall outside the registers' range 0..4095.
        """
        angles = np.zeros((2, len(self)))
        angles[:, joint] = (low_rad, high_rad)
        low, high = sorted(int(v) for v in self.to_ticks(angles)[:, joint])
        if not 0 <= low < high <= TICKS_PER_REV - 1:
            raise BadArgument(
                f"ticks {low}..{high} fall outside the registers' range 0..{TICKS_PER_REV - 1}"
            )
        return low, high

    def velocity_to_rad_s(self, raw: np.ndarray) -> np.ndarray:
        """Joint velocities (rad/s) of signed Present Velocity values, shape (..., n)."""
        return np.asarray(self.directions) * np.asarray(raw, dtype=float) * VELOCITY_UNIT_RAD_S

    def signed_joint(self, values: np.ndarray) -> np.ndarray:
        """Apply each joint's direction to a servo-frame quantity (current, torque)."""
        return np.asarray(self.directions) * np.asarray(values, dtype=float)
