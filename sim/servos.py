"""Dynamixel X-series servo data for the simulated gimbal (SI units, 12 V ratings).

Ratings (stall torque, stall current, no-load speed at 12 V), mass, housing size
and gear ratio come from ``trajgen.servo_ratings``, the table the drivers read
too. The rest is not published and is stated per field:

- ``armature``: reflected rotor inertia (kg m^2). 0.045 for the XM430-W350 is
  Menagerie's ROBOTIS OP3 value (no stated source). The XH430-W350 has the same
  gear ratio and takes the same value. The XL430-W250 (258.5:1) and XM540-W270
  (272.5:1) scale it by gear ratio squared (same rotor inertia assumed, an
  estimate; the XM540's larger motor makes its value a lower bound).
- ``damping``: viscous gear friction (N m s/rad), an estimate of 0.01. The motor's
  own back-EMF is not part of it: ``<dcmotor>`` models that from the ratings.
- ``frictionloss``: Coulomb friction (N m). Menagerie's OP3 uses 0.03 for the
  XM430-W350; the others scale it with stall torque (estimate).
- ``position_p_gain``, ``position_i_gain``, ``position_d_gain``: the
  firmware's factory defaults of registers 84, 82, 80 (e-Manual control
  tables; datasheet values). ``sim.firmware`` turns them into the servo's
  position loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trajgen.servo_ratings import DEFAULT_SERVO as _DEFAULT_NAME
from trajgen.servo_ratings import RATINGS, servo_rating

SUPPLY_VOLTAGE_V = 12.0

_OP3_ARMATURE = 0.045
_OP3_FRICTIONLOSS = 0.03
_XM430_GEAR = 353.5
_XM430_STALL = 4.1


@dataclass(frozen=True)
class ServoModel:
    """One Dynamixel model's ratings and simulation parameters (SI units).

    Attributes
    ----------
    name : str
        Model name, e.g. ``"XM430-W350"``.
    stall_torque_nm : float
        Stall torque (N m) at 12 V.
    stall_current_a : float
        Stall current (A) at 12 V.
    no_load_speed_rad_s : float
        No-load speed (rad/s) at 12 V.
    mass_kg : float
        Servo mass (kg).
    size_m : tuple of float
        Housing width, height, depth (m); the horn axis runs along the depth.
    gear_ratio : float
        Gear reduction.
    armature : float
        Reflected rotor inertia (kg m^2); see the module docstring for sources.
    damping : float
        Viscous friction (N m s/rad).
    frictionloss : float
        Coulomb friction (N m).
    position_p_gain, position_i_gain, position_d_gain : int
        Factory defaults of the Position P / I / D Gain registers.
    """

    name: str
    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rad_s: float
    mass_kg: float
    size_m: tuple[float, float, float]
    gear_ratio: float
    armature: float
    damping: float
    frictionloss: float
    position_p_gain: int = 800
    position_i_gain: int = 0
    position_d_gain: int = 0

    @property
    def torque_constant_nm_a(self) -> float:
        """Torque constant (N m/A), approximated as stall torque / stall current.

        The e-Manual's torque-current curves are close to linear through the
        origin; this ratio ignores the no-load current.
        """
        return self.stall_torque_nm / self.stall_current_a

    def tau_max(self, speed_rad_s):
        """Torque available (N m) at joint speed ``speed_rad_s`` at 12 V.

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


def _servo(name: str, armature: float | None = None, pid=(800, 0, 0)) -> ServoModel:
    r = RATINGS[name]
    if armature is None:
        armature = _OP3_ARMATURE * (r.gear_ratio / _XM430_GEAR) ** 2
    return ServoModel(
        name=r.name,
        stall_torque_nm=r.stall_torque_nm,
        stall_current_a=r.stall_current_a,
        no_load_speed_rad_s=r.no_load_speed_rad_s,
        mass_kg=r.mass_kg,
        size_m=r.size_m,
        gear_ratio=r.gear_ratio,
        armature=armature,
        damping=0.01,
        frictionloss=_OP3_FRICTIONLOSS * r.stall_torque_nm / _XM430_STALL,
        position_p_gain=pid[0],
        position_i_gain=pid[1],
        position_d_gain=pid[2],
    )


XM430_W350 = _servo("XM430-W350", 0.045)
XL430_W250 = _servo("XL430-W250", pid=(640, 0, 4000))
XH430_W350 = _servo("XH430-W350", 0.045)
XM540_W270 = _servo("XM540-W270")

SERVOS: dict[str, ServoModel] = {
    s.name: s for s in (XM430_W350, XL430_W250, XH430_W350, XM540_W270)
}
DEFAULT_SERVO = SERVOS[_DEFAULT_NAME]


def servo_by_name(name: str) -> ServoModel:
    """Look up a servo model by its name (e.g. ``"XM430-W350"``; case and blanks do not
    matter, see :func:`trajgen.servo_ratings.servo_rating`).

    Raises
    ------
    TypeError
        If ``name`` is not a string.
    ValueError
        If the model is unknown; the message lists the known ones.
    """
    return SERVOS[servo_rating(name).name]
