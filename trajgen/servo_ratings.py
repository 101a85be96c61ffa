"""Dynamixel X-series ratings: the one table both the simulator and the drivers read.

Plain data, kept in the numpy-only core because ``trajgen.sim`` and
``trajgen.drivers`` must not import each other and both need it: the simulator
builds its motors from the ratings, the drivers check a servo's Model Number
and convert its current register. Each package adds what only it needs (the
simulator's friction and gains, the drivers' current unit) keyed by the same
canonical name, and every model name a user writes goes through
:func:`servo_rating`, so ``"xm430-w350"`` means the same thing to ``trajgen sim``
and to ``trajgen stream``.

Source: the ROBOTIS e-Manual specification tables of each model (12 V ratings:
stall torque, stall current, no-load speed; mass, housing size, gear ratio;
Model Number from the control table).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RPM_TO_RAD_S = 2.0 * math.pi / 60.0

#: The registers that shape an X-series servo's position loop, by their SDK
#: control-table names: what the virtual bus hands its plant
#: (``trajgen.drivers.virtual.plant.Plant.set_control``) and what the simulated
#: firmware loop (``trajgen.sim.firmware``) reads.
CONTROL_REGISTERS = (
    "Position P Gain",
    "Position I Gain",
    "Position D Gain",
    "Feedforward 1st Gain",
    "Feedforward 2nd Gain",
    "PWM Limit",
    "Goal PWM",
    "Profile Velocity",
    "Profile Acceleration",
    "Operating Mode",
)

#: Present PWM / Goal PWM / PWM Limit value of 100 % of the supply (e-Manual).
PWM_FULL_SCALE = 885

#: Position P Gain scale: KP = P / 128, PWM units per pulse of error (e-Manual;
#: BAM measured /256 on an XL330, so the simulator keeps it a parameter).
P_DIVISOR = 128.0


@dataclass(frozen=True)
class ServoRating:
    """One model's published figures (SI units, 12 V).

    Attributes
    ----------
    name : str
        Canonical e-Manual name, e.g. ``"XM430-W350"``.
    number : int
        Model Number register value.
    stall_torque_nm, stall_current_a : float
        Stall torque (N m) and stall current (A).
    no_load_speed_rad_s : float
        No-load speed (rad/s).
    mass_kg : float
        Servo mass (kg).
    size_m : tuple of float, shape (3,)
        Housing width, height, depth (m); the horn axis runs along the depth.
    gear_ratio : float
        Gear reduction.
    """

    name: str
    number: int
    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rad_s: float
    mass_kg: float
    size_m: tuple[float, float, float]
    gear_ratio: float


def _rating(name, number, stall_nm, stall_a, no_load_rpm, mass_kg, size_mm, gear):
    size = tuple(s / 1000.0 for s in size_mm)
    return ServoRating(
        name, number, stall_nm, stall_a, no_load_rpm * RPM_TO_RAD_S, mass_kg, size, gear
    )


#: Every supported model, by canonical name.
RATINGS: dict[str, ServoRating] = {
    r.name: r
    for r in (
        _rating("XM430-W350", 1020, 4.1, 2.3, 46.0, 0.082, (28.5, 46.5, 34.0), 353.5),
        _rating("XL430-W250", 1060, 1.5, 1.4, 61.0, 0.0572, (28.5, 46.5, 34.0), 258.5),
        _rating("XH430-W350", 1000, 3.4, 1.3, 30.0, 0.082, (28.5, 46.5, 34.0), 353.5),
        _rating("XM540-W270", 1120, 10.6, 4.4, 30.0, 0.165, (33.5, 58.5, 44.0), 272.5),
    )
}

#: The model used where a file names none.
DEFAULT_SERVO = "XM430-W350"


def servo_rating(name) -> ServoRating:
    """The rating of model ``name``: case and surrounding blanks do not matter.

    Raises
    ------
    TypeError
        If ``name`` is not a string.
    ValueError
        If the model is unknown; the message lists the known ones.
    """
    if not isinstance(name, str):
        raise TypeError(f"Expected a servo model name, got {name!r}.")
    rating = RATINGS.get(name.strip().upper())
    if rating is None:
        raise ValueError(f"unknown model {name!r} (known: {', '.join(RATINGS)})")
    return rating
