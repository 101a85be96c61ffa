"""What moves the virtual servos: the Plant protocol and a first-order plant.

Joint ``j`` of a plant is the servo with the ``j``-th id of the virtual bus.
Angles are in the servos' own frame (0 rad = tick 2048, no direction flip).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Plant(Protocol):
    """The mechanics behind the virtual servos (``sim.plant.GimbalPlant`` is one).

    Attributes
    ----------
    n_joints : int
        Number of joints (one per servo).
    """

    n_joints: int

    def set_goal(self, positions_rad: np.ndarray) -> None:
        """Goal angles (rad), shape (n_joints,)."""

    def set_torque_enabled(self, joint: int, enabled: bool) -> None:
        """Torque on or off for one joint (off: the joint is free)."""

    def advance(self, dt_s: float) -> None:
        """Move time forward by ``dt_s`` seconds."""

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present position (rad), velocity (rad/s), current (A), each (n_joints,)."""


class FirstOrderPlant:
    """Servos that follow their goals with a time constant (pure numpy, for tests).

    With torque on, each angle moves toward its goal as ``dq/dt = (goal - q) / tau``
    (solved exactly over each ``advance``); with torque off it stays where it is.
    The current is ``current_per_rad_a`` times the position error, a stand-in
    for the load.

    Parameters
    ----------
    n_joints : int, optional
        Number of joints.
    time_constant_s : float, optional
        tau (s); 0 makes the servo reach its goal at once.
    initial_rad : array_like, shape (n_joints,), optional
        Starting angles (rad); zero by default.
    current_per_rad_a : float, optional
        Current (A) per rad of position error.

    Raises
    ------
    ValueError
        If ``n_joints`` < 1, ``time_constant_s`` < 0, or ``initial_rad`` has the
        wrong shape.
    """

    def __init__(
        self,
        n_joints: int = 3,
        *,
        time_constant_s: float = 0.02,
        initial_rad: np.ndarray | None = None,
        current_per_rad_a: float = 1.0,
    ) -> None:
        if n_joints < 1:
            raise ValueError(f"Expected `n_joints` >= 1, got {n_joints}.")
        if not time_constant_s >= 0:
            raise ValueError(f"Expected `time_constant_s` >= 0, got {time_constant_s}.")
        self.n_joints = n_joints
        self.time_constant_s = float(time_constant_s)
        self.current_per_rad_a = float(current_per_rad_a)
        q0 = np.zeros(n_joints) if initial_rad is None else np.asarray(initial_rad, float)
        if q0.shape != (n_joints,):
            raise ValueError(f"Expected `initial_rad` of shape ({n_joints},), got {q0.shape}.")
        self._q = q0.copy()
        self._qd = np.zeros(n_joints)
        self._goal = q0.copy()
        self._torque = np.zeros(n_joints, dtype=bool)
        self.time_s = 0.0

    def set_goal(self, positions_rad: np.ndarray) -> None:
        """Goal angles (rad), shape (n_joints,)."""
        self._goal = np.asarray(positions_rad, dtype=float).copy()

    def set_torque_enabled(self, joint: int, enabled: bool) -> None:
        """Torque on or off for one joint."""
        self._torque[joint] = enabled

    def advance(self, dt_s: float) -> None:
        """Move time forward by ``dt_s`` seconds."""
        if dt_s <= 0:
            return
        if self.time_constant_s == 0:
            decay = 0.0
        else:
            decay = np.exp(-dt_s / self.time_constant_s)
        target = np.where(self._torque, self._goal, self._q)
        q_new = target + (self._q - target) * decay
        self._qd = (q_new - self._q) / dt_s
        self._q = q_new
        self.time_s += dt_s

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present position (rad), velocity (rad/s), current (A), each (n_joints,)."""
        error = np.where(self._torque, self._goal - self._q, 0.0)
        return self._q.copy(), self._qd.copy(), self.current_per_rad_a * error
