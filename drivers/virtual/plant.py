"""What moves the virtual servos: the Plant protocol and a first-order plant.

Joint ``j`` of a plant is the servo with the ``j``-th id of the virtual bus.
Angles are in the servos' own frame (0 rad = tick 2048, no direction flip).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol, runtime_checkable

import numpy as np

from trajgen.drivers.units import RAD_PER_TICK
from trajgen.servo_table import (
    CONTROL_REGISTERS,
    DEFAULT_SERVO,
    P_DIVISOR,
    POSITION_MODE,
    PWM_FULL_SCALE,
    servo_spec,
)

from ..errors import BadArgument


@runtime_checkable
class Plant(Protocol):
    """The mechanics behind the virtual servos (``sim.plant.GimbalPlant`` is one).

    The virtual bus's simulation thread owns the plant: every call below is
    made with the bus's one lock held, so a plant needs no locking of its own.

    Contract with the virtual bus:

    - ``set_control(joint: int, registers: Mapping[str, int]) -> None`` — the
      servo's registers that shape its position loop, in register units, keyed
      by the SDK control-table names: "Position P Gain", "Position I Gain",
      "Position D Gain", "Feedforward 1st Gain", "Feedforward 2nd Gain",
      "PWM Limit", "Goal PWM", "Profile Velocity", "Profile Acceleration",
      "Operating Mode"; the virtual bus calls it for every joint at start and
      whenever one of those registers is written (and after
      REBOOT/FACTORY_RESET). A plant that does not simulate what the
      registers ask for raises, before changing anything; the bus's
      ``unsupported`` names which exceptions mean that, and refuses the
      write;
    - ``present_pwm() -> ndarray (n_joints,)`` — the drive's output as a
      fraction of the supply in [-1, 1] (the bus turns it into Present PWM,
      885 = 100%).

    ``set_goal``, ``set_torque_enabled``, ``advance`` and ``read`` are as
    before: goals in rad, time in s, present values in SI units.

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

    def set_control(self, joint: int, registers: Mapping[str, int]) -> None:
        """The position-loop registers of one joint's servo (``CONTROL_REGISTERS``)."""

    def advance(self, dt_s: float) -> None:
        """Move time forward by ``dt_s`` seconds."""

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present position (rad), velocity (rad/s), current (A), each (n_joints,)."""

    def present_pwm(self) -> np.ndarray:
        """Drive output as a fraction of the supply, in [-1, 1], shape (n_joints,)."""


class FirstOrderPlant:
    """Servos that follow their goals with a time constant (pure numpy, for tests).

    With torque on, each angle moves toward its goal as ``dq/dt = (goal - q) / tau``
    (solved exactly over each ``advance``); with torque off it stays where it is.
    The current is ``current_per_rad_a`` times the position error, a stand-in
    for the load. The drive output is a plain P loop on the error, as the
    X-series computes it with no profile: ``PWM = Position P Gain / 128`` per
    pulse of error, clipped to the smaller of PWM Limit and Goal PWM, 885 =
    100 % of the supply. The gains shape the reported PWM only, not the motion.

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

    Attributes
    ----------
    control : list of dict of str to int
        Per joint, the last ``set_control`` registers (XM430-W350 factory
        values until then: P 800, PWM Limit and Goal PWM 885).
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
            raise BadArgument(f"Expected `n_joints` >= 1, got {n_joints}.")
        if not time_constant_s >= 0:
            raise BadArgument(f"Expected `time_constant_s` >= 0, got {time_constant_s}.")
        self.n_joints = n_joints
        self.time_constant_s = float(time_constant_s)
        self.current_per_rad_a = float(current_per_rad_a)
        q0 = np.zeros(n_joints) if initial_rad is None else np.asarray(initial_rad, float)
        if q0.shape != (n_joints,):
            raise BadArgument(f"Expected `initial_rad` of shape ({n_joints},), got {q0.shape}.")
        self._q = q0.copy()
        self._qd = np.zeros(n_joints)
        self._goal = q0.copy()
        self._torque = np.zeros(n_joints, dtype=bool)
        factory = servo_spec(DEFAULT_SERVO).defaults
        defaults = {name: factory.get(name, 0) for name in CONTROL_REGISTERS}
        defaults.update({"Goal PWM": PWM_FULL_SCALE, "Operating Mode": POSITION_MODE})
        self.control = [dict(defaults) for _ in range(n_joints)]
        self.time_s = 0.0

    def set_goal(self, positions_rad: np.ndarray) -> None:
        """Goal angles (rad), shape (n_joints,)."""
        self._goal = np.asarray(positions_rad, dtype=float).copy()

    def set_torque_enabled(self, joint: int, enabled: bool) -> None:
        """Torque on or off for one joint."""
        self._torque[joint] = enabled

    def set_control(self, joint: int, registers: Mapping[str, int]) -> None:
        """The position-loop registers of one joint's servo (``CONTROL_REGISTERS``).

        Raises
        ------
        ValueError
            If a key is not one of ``CONTROL_REGISTERS``.
        """
        unknown = set(registers) - set(CONTROL_REGISTERS)
        if unknown:
            raise BadArgument(f"Expected keys among CONTROL_REGISTERS, got {sorted(unknown)}.")
        self.control[joint].update({k: int(v) for k, v in registers.items()})

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

    def present_pwm(self) -> np.ndarray:
        """Drive output as a fraction of the supply, in [-1, 1], shape (n_joints,).

        ``clip(P / 128 * error_pulses, +-min(PWM Limit, Goal PWM)) / 885``; 0
        with torque off.
        """
        error_pulses = (self._goal - self._q) / RAD_PER_TICK
        out = np.zeros(self.n_joints)
        for j, registers in enumerate(self.control):
            if not self._torque[j]:
                continue
            limit = min(registers["PWM Limit"], abs(registers["Goal PWM"]))
            pwm = registers["Position P Gain"] / P_DIVISOR * error_pulses[j]
            out[j] = np.clip(pwm, -limit, limit) / PWM_FULL_SCALE
        return out
