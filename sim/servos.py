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


def _from_spec(attribute: str, doc: str) -> property:
    """A read-only property that reads ``attribute`` of the entry."""
    return property(lambda self: getattr(self.spec, attribute), doc=doc)


def _factory(register: str) -> property:
    """A read-only property: the entry's factory value of ``register`` (register units)."""
    return property(lambda self: self.spec.defaults[register], doc=f"Factory {register}.")


@dataclass(frozen=True)
class ServoModel:
    """One Dynamixel model as the simulator uses it: a view of its table entry.

    Attributes
    ----------
    spec : trajgen.servo_table.ServoSpec
        The entry; every other attribute reads it.
    """

    spec: ServoSpec

    name = _from_spec("name", 'Model name, e.g. ``"XM430-W350"``.')
    voltage_v = _from_spec("voltage_v", "Supply (V) the motor is simulated at: the rated one.")
    stall_torque_nm = _from_spec("stall_torque_nm", "Stall torque (N m) at ``voltage_v``.")
    stall_current_a = _from_spec("stall_current_a", "Stall current (A) at ``voltage_v``.")
    no_load_speed_rad_s = _from_spec("no_load_speed_rad_s", "No-load speed (rad/s).")
    mass_kg = _from_spec("mass_kg", "Servo mass (kg).")
    size_m = _from_spec("size_m", "Housing width, height, depth (m); horn axis along depth.")
    gear_ratio = _from_spec("gear_ratio", "Gear reduction.")
    armature = _from_spec("armature", "Reflected rotor inertia (kg m^2), an estimate.")
    damping = _from_spec("damping", "Viscous gear friction (N m s/rad), an estimate.")
    frictionloss = _from_spec("frictionloss", "Coulomb friction (N m), an estimate.")
    position_p_gain = _factory("Position P Gain")
    position_i_gain = _factory("Position I Gain")
    position_d_gain = _factory("Position D Gain")

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
