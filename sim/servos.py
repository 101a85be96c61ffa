"""The simulator's view of a Dynamixel X-series servo (SI units, at its rated voltage).

Every figure comes from the model's entry in ``trajgen.servo_table``, the table
the drivers read too: ratings (stall torque and current, no-load speed at the
rated voltage), mass, housing size, gear ratio, the factory Position P / I / D
Gain registers (84 / 82 / 80) that ``sim.firmware`` turns into the servo's
position loop, and the simulation estimates (armature, damping, frictionloss)
with the sources and scaling rules the table states. This module adds only
what the simulator derives from them: the torque-speed line and the torque
constant it uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trajgen.servo_table import DEFAULT_SERVO as _DEFAULT_NAME
from trajgen.servo_table import SERVOS as _SPECS
from trajgen.servo_table import ServoSpec, servo_spec


@dataclass(frozen=True)
class ServoModel:
    """One Dynamixel model as the simulator uses it: a view of its table entry.

    Attributes
    ----------
    spec : trajgen.servo_table.ServoSpec
        The entry; every property below reads it.
    """

    spec: ServoSpec

    @property
    def name(self) -> str:
        """Model name, e.g. ``"XM430-W350"``."""
        return self.spec.name

    @property
    def voltage_v(self) -> float:
        """Supply voltage (V) the motor is simulated at: the rated voltage of the ratings."""
        return self.spec.voltage_v

    @property
    def stall_torque_nm(self) -> float:
        """Stall torque (N m) at ``voltage_v``."""
        return self.spec.stall_torque_nm

    @property
    def stall_current_a(self) -> float:
        """Stall current (A) at ``voltage_v``."""
        return self.spec.stall_current_a

    @property
    def no_load_speed_rad_s(self) -> float:
        """No-load speed (rad/s) at ``voltage_v``."""
        return self.spec.no_load_speed_rad_s

    @property
    def mass_kg(self) -> float:
        """Servo mass (kg)."""
        return self.spec.mass_kg

    @property
    def size_m(self) -> tuple[float, float, float]:
        """Housing width, height, depth (m); the horn axis runs along the depth."""
        return self.spec.size_m

    @property
    def gear_ratio(self) -> float:
        """Gear reduction."""
        return self.spec.gear_ratio

    @property
    def armature(self) -> float:
        """Reflected rotor inertia (kg m^2), an estimate (``trajgen.servo_table``)."""
        return self.spec.armature

    @property
    def damping(self) -> float:
        """Viscous gear friction (N m s/rad), an estimate; the motor's back-EMF is apart."""
        return self.spec.damping

    @property
    def frictionloss(self) -> float:
        """Coulomb friction (N m), an estimate."""
        return self.spec.frictionloss

    @property
    def position_p_gain(self) -> int:
        """Factory Position P Gain (84), register units."""
        return self.spec.defaults["Position P Gain"]

    @property
    def position_i_gain(self) -> int:
        """Factory Position I Gain (82), register units."""
        return self.spec.defaults["Position I Gain"]

    @property
    def position_d_gain(self) -> int:
        """Factory Position D Gain (80), register units."""
        return self.spec.defaults["Position D Gain"]

    @property
    def torque_constant_nm_a(self) -> float:
        """Torque constant (N m/A), approximated as stall torque / stall current.

        The e-Manual's torque-current curves are close to linear through the
        origin; this ratio ignores the no-load current.
        """
        return self.stall_torque_nm / self.stall_current_a

    def tau_max(self, speed_rad_s):
        """Torque available (N m) at joint speed ``speed_rad_s`` at ``voltage_v``.

        ``tau_max(w) = tau_stall (1 - |w| / w0)``: the torque-speed line of a DC
        motor driven at its rated voltage. It is negative beyond the no-load speed.

        Parameters
        ----------
        speed_rad_s : float or ndarray
            Joint speed (rad/s), any shape.

        Returns
        -------
        float or ndarray
            Same shape as ``speed_rad_s``.
        """
        return self.stall_torque_nm * (1.0 - np.abs(speed_rad_s) / self.no_load_speed_rad_s)


#: Every model of the table, by canonical name.
SERVOS: dict[str, ServoModel] = {name: ServoModel(spec) for name, spec in _SPECS.items()}
DEFAULT_SERVO = SERVOS[_DEFAULT_NAME]
XM430_W350 = SERVOS["XM430-W350"]
XL430_W250 = SERVOS["XL430-W250"]
XM540_W270 = SERVOS["XM540-W270"]


def servo_by_name(name: str) -> ServoModel:
    """Look up a servo model by its name (e.g. ``"XM430-W350"``; case and blanks do not
    matter, see :func:`trajgen.servo_table.servo_spec`).

    Raises
    ------
    TypeError
        If ``name`` is not a string.
    ValueError
        If the model is unknown; the message lists the known ones.
    """
    return SERVOS[servo_spec(name).name]
