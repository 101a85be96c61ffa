"""Dynamixel X-series servo facts: the one table the core, the drivers and the simulator read.

Plain data in the numpy-free core, because ``trajgen.sim`` and
``trajgen.drivers`` must not import each other and both need it: the simulator
builds its motors and position loops from an entry, the drivers check a
servo's Model Number, convert its current register and serve its control table
on the virtual bus. Adding a model is one :class:`ServoSpec` in ``SERVOS``
(``docs/servos.md`` says how); nothing else in the repository restates a figure
of it.

Sources. Ratings (stall torque and current, no-load speed at the rated
voltage), mass, size and gear ratio: each model's ROBOTIS e-Manual page
(``ServoSpec.url``), the "Specifications" table, which the e-Manual renders from
``_data/dxl_x_info.yml`` of ``github.com/ROBOTIS-GIT/emanual``. Register
defaults, Model Number, units: the same page's "Control Table of EEPROM / RAM
Area" (initial value, range, unit columns). The X-series-wide facts below
(encoder, PWM scale, gain scales, baud rates, error bits) are on every X page.
Register *addresses* are not here: they come from the model files that ship
with ``dynamixel-sdk`` (``trajgen.drivers.control_table``), checked against
this table by ``tests/test_servo_table.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType

from .errors import BadArgument

RPM_TO_RAD_S = 2.0 * math.pi / 60.0

# -- X-series-wide facts (every X-series e-Manual page) ------------------------

#: Encoder resolution: "Resolution 4096 [pulse/rev]".
TICKS_PER_REV = 4096
#: Present Position of joint angle 0 in the SDK's model files
#: (``value_of_zero_radian_position 2048``), the middle of 0..4095.
ZERO_TICK = TICKS_PER_REV // 2
#: One position tick (rad): 0.088 deg.
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
#: Velocity registers' unit: 0.229 rev/min (Present Velocity, Velocity Limit...), in rad/s.
VELOCITY_UNIT_RAD_S = 0.229 * 2.0 * math.pi / 60.0
#: Present PWM / Goal PWM / PWM Limit value of 100 % of the supply (unit 0.113 %).
PWM_FULL_SCALE = 885
#: Largest value of every gain register (Position / Velocity P, I, D, Feedforward): 16,383.
GAIN_MAX = 16_383
#: Position loop gain scales: KP = P / 128, KI = I / 65536, KD = D / 16
#: ("Position PID Gain(80, 82, 84)"). BAM (Rhoban's actuator models) measured
#: /256 for P on an XL330, so the simulator keeps ``P_DIVISOR`` a parameter.
P_DIVISOR = 128.0
I_DIVISOR = 65536.0
D_DIVISOR = 16.0
#: Present Load unit where register 126 is Present Load (XL430, 2XL430): 0.1 %.
LOAD_UNIT = 0.001
#: Bus Watchdog (98) unit: 20 ms.
WATCHDOG_UNIT_S = 0.020
#: Return Delay Time's unit (s): 2 us ("Return Delay Time(9)": 0..254, up to 508 us).
RETURN_DELAY_UNIT_S = 2e-6
#: A servo's processing time (s) between a request's last byte and its Return Delay
#: Time (e-Manual: some tens of us), as the driver assumes it and the virtual bus has it.
TURNAROUND_S = 20e-6
#: Baud Rate (8) register value -> bit/s ("Baud Rate(8)"); the 330 series stops at 6 (4 Mbps).
BAUD_RATES = MappingProxyType(
    {
        0: 9_600,
        1: 57_600,
        2: 115_200,
        3: 1_000_000,
        4: 2_000_000,
        5: 3_000_000,
        6: 4_000_000,
        7: 4_500_000,
    }
)
#: Hardware Error Status (70) bit -> what it means ("Hardware Error Status(70)").
HARDWARE_ERROR_BITS = MappingProxyType(
    {
        0: "input voltage",
        2: "overheating",
        3: "motor encoder",
        4: "electrical shock",
        5: "overload",
    }
)
#: Operating Mode (11) values ("Operating Mode(11)").
CURRENT_MODE = 0
VELOCITY_MODE = 1
POSITION_MODE = 3
EXTENDED_POSITION_MODE = 4
CURRENT_BASED_POSITION_MODE = 5
PWM_MODE = 16
#: The modes of a model with current control (XM, XH, XL330, XC330 pages: "Operating
#: Mode(11)" lists current, velocity, position, extended position, current-based
#: position and PWM control).
_MODES_WITH_CURRENT = (
    CURRENT_MODE,
    VELOCITY_MODE,
    POSITION_MODE,
    EXTENDED_POSITION_MODE,
    CURRENT_BASED_POSITION_MODE,
    PWM_MODE,
)
#: The modes of the XL430-W250 and 2XL430-W250 (no current sensing: velocity,
#: position, extended position and PWM control only, their pages' "Operating Mode(11)").
_MODES_WITHOUT_CURRENT = (VELOCITY_MODE, POSITION_MODE, EXTENDED_POSITION_MODE, PWM_MODE)
#: Addresses below this are EEPROM: writable only while Torque Enable is 0.
EEPROM_END = 64

#: The registers that shape an X-series servo's position loop, by their SDK
#: control-table names: what the virtual bus hands its plant and what the
#: simulated firmware loop (``trajgen.sim.firmware``) reads.
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

#: The factory values every entry states (``ServoSpec.defaults``): the ones that
#: differ between models on the e-Manual control tables. Current Limit is None
#: where the model has none (XL430, 2XL430).
DEFAULT_REGISTERS = (
    "Return Delay Time",
    "Temperature Limit",
    "Max Voltage Limit",
    "Min Voltage Limit",
    "PWM Limit",
    "Current Limit",
    "Velocity Limit",
    "Moving Threshold",
    "Shutdown",
    "Velocity I Gain",
    "Velocity P Gain",
    "Position D Gain",
    "Position I Gain",
    "Position P Gain",
)


def hardware_error_mask(name: str) -> int:
    """The Hardware Error Status bit mask of error ``name`` (e.g. ``"overload"`` -> 0x20).

    Raises
    ------
    ValueError
        If ``name`` is not one of ``HARDWARE_ERROR_BITS``.
    """
    for bit, meaning in HARDWARE_ERROR_BITS.items():
        if meaning == name:
            return 1 << bit
    known = ", ".join(HARDWARE_ERROR_BITS.values())
    raise BadArgument(f"unknown hardware error {name!r} (known: {known})")


# -- Simulation parameters nobody publishes: stated estimates -----------------
#
# Reflected rotor inertia (armature) and gear friction are not in any e-Manual.
# The reference is Menagerie's ROBOTIS OP3 model (XM430-W350: armature 0.045
# kg m^2, frictionloss 0.03 N m; no stated source). Other models scale it:
# same rotor, so armature by gear ratio squared (430 and 540 cases; the 540's
# larger motor makes it a lower bound); for the 330 series, whose motor is far
# smaller, the rotor inertia is also scaled by the motor's own stall torque
# (stall torque / gear ratio) relative to the XM430-W350's. Coulomb friction
# scales with stall torque. Viscous gear friction is 0.01 N m s/rad for the
# 430 and 540 cases and scales with stall torque for the 330 series. All are
# estimates; ``trajgen identify`` fits them to a logged servo.

_OP3_ARMATURE = 0.045
_OP3_FRICTIONLOSS = 0.03
_REF_GEAR = 353.5  # the XM430-W350 entry's gear ratio and stall torque (a test holds them equal)
_REF_STALL_NM = 4.1
_DAMPING = 0.01


def _armature_by_gear(gear_ratio: float) -> float:
    return _OP3_ARMATURE * (gear_ratio / _REF_GEAR) ** 2


def _armature_by_motor(gear_ratio: float, stall_nm: float) -> float:
    motor = (stall_nm / gear_ratio) / (_REF_STALL_NM / _REF_GEAR)
    return _armature_by_gear(gear_ratio) * motor


def _friction_by_stall(stall_nm: float) -> float:
    return _OP3_FRICTIONLOSS * stall_nm / _REF_STALL_NM


@dataclass(frozen=True, eq=False)
class ServoSpec:
    """One model's published figures, register defaults and simulation estimates.

    Ratings are the e-Manual's at ``voltage_v``: the recommended voltage (bold
    on the page), except the XL430 models, whose page recommends 11.1 V and
    whose 12 V figures are used (``note`` says so).

    Attributes
    ----------
    name : str
        Canonical e-Manual name, e.g. ``"XM430-W350"``.
    number : int
        Model Number register (0) value.
    url : str
        The e-Manual page every figure of the entry comes from.
    voltage_v : float
        Rated supply voltage (V) of the ratings; the simulator drives the motor at it.
    stall_torque_nm, stall_current_a : float
        Stall torque (N m) and stall current (A) at ``voltage_v``.
    no_load_speed_rpm : float
        No-load speed (rev/min) at ``voltage_v``, as published.
    torque_constant_nm_a : float or None
        Torque constant (N m/A) where the page prints one (in brackets after the
        stall torque); None where it does not.
    mass_kg : float
        Mass (kg).
    size_mm : tuple of float, shape (3,)
        Housing width, height, depth (mm); the horn axis runs along the depth.
    gear_ratio : float
        Gear reduction.
    current_unit_a : float or None
        Unit of Present Current (126) in A (2.69 mA or 1 mA); None where
        register 126 is Present Load (0.1 % units), which is converted through
        the stall current.
    defaults : mapping of str to int or None
        Factory value of every register in ``DEFAULT_REGISTERS``.
    ranges : mapping of str to (int, int)
        Write ranges that differ from the X-series rule (voltage limits, Baud
        Rate, Velocity Limit, Current Limit).
    indirect_blocks : tuple of (int, int, int)
        (first Indirect Address, first Indirect Data, count) per block.
    indirect_targets : (int, int)
        Range an Indirect Address may point in.
    operating_modes : tuple of int
        The Operating Mode (11) values the model accepts (its page's "Operating
        Mode(11)" table); any other write is refused with a data range error.
    axes : int
        Motors in the case: 2 for the 2XL430-W250 (each axis answers on its own
        id with its own control table), else 1.
    armature, damping, frictionloss : float
        Simulation estimates (kg m^2, N m s/rad, N m); see the module comment.
    note : str
        What the entry states beyond the figures (unpublished ratings, quirks).
    """

    name: str
    number: int
    url: str
    voltage_v: float
    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rpm: float
    torque_constant_nm_a: float | None
    mass_kg: float
    size_mm: tuple[float, float, float]
    gear_ratio: float
    current_unit_a: float | None
    defaults: MappingProxyType
    ranges: MappingProxyType
    indirect_blocks: tuple[tuple[int, int, int], ...]
    indirect_targets: tuple[int, int]
    armature: float
    damping: float
    frictionloss: float
    operating_modes: tuple[int, ...]
    axes: int = 1
    note: str = field(default="", compare=False)

    @property
    def no_load_speed_rad_s(self) -> float:
        """No-load speed (rad/s) at ``voltage_v``."""
        return self.no_load_speed_rpm * RPM_TO_RAD_S

    @property
    def size_m(self) -> tuple[float, float, float]:
        """Housing width, height, depth (m)."""
        return tuple(s / 1000.0 for s in self.size_mm)

    @property
    def present_load(self) -> bool:
        """Whether register 126 is Present Load (0.1 %) rather than Present Current."""
        return self.current_unit_a is None

    def current_a(self, raw: int) -> float:
        """Convert a signed register 126 value to amperes (Present Load: share of stall current)."""
        if self.current_unit_a is None:
            return raw * LOAD_UNIT * self.stall_current_a
        return raw * self.current_unit_a

    def current_raw(self, current_a: float) -> int:
        """Convert amperes to a register 126 value (inverse of ``current_a``)."""
        if self.current_unit_a is None:
            return round(current_a / (LOAD_UNIT * self.stall_current_a))
        return round(current_a / self.current_unit_a)


_X430_INDIRECT = ((168, 224, 28), (578, 634, 28))
_X430_TARGETS = (64, 661)
# The 330 series has one block of 20: Indirect Address 1..20 at 168..206,
# Indirect Data 1..20 at 208..227 (its e-Manual pages; the SDK's xl330 model
# files put Indirect Data 1 at 224, copied from the 430 table).
_X330_INDIRECT = ((168, 208, 20),)
_X330_TARGETS = (64, 227)
_X330_RANGES = {
    "Baud Rate": (0, 6),
    "Max Voltage Limit": (31, 70),
    "Min Voltage Limit": (31, 70),
    "Velocity Limit": (0, 2047),
}
_X12V_RANGES = {"Max Voltage Limit": (95, 160), "Min Voltage Limit": (95, 160)}
_XL430_RANGES = {"Max Voltage Limit": (60, 140), "Min Voltage Limit": (60, 140)}

_URL = "https://emanual.robotis.com/docs/en/dxl/x/{}/"


def _defaults(rdt, temp, vmax, vmin, pwm, current, vel, moving, shutdown, vi, vp, pd, pi, pp):
    values = (rdt, temp, vmax, vmin, pwm, current, vel, moving, shutdown, vi, vp, pd, pi, pp)
    return MappingProxyType(dict(zip(DEFAULT_REGISTERS, values, strict=True)))


def _spec(
    name,
    number,
    family,
    *,
    volts,
    stall_nm,
    stall_a,
    rpm,
    kt,
    mass_kg,
    size_mm,
    gear,
    current_unit_a,
    defaults,
    ranges,
    modes,
    axes=1,
    note="",
):
    ranges = dict(ranges)
    if defaults["Current Limit"] is not None:
        ranges["Current Limit"] = (0, defaults["Current Limit"])
    x330 = family == "330"
    return ServoSpec(
        name=name,
        number=number,
        url=_URL.format(name.lower()),
        voltage_v=volts,
        stall_torque_nm=stall_nm,
        stall_current_a=stall_a,
        no_load_speed_rpm=rpm,
        torque_constant_nm_a=kt,
        mass_kg=mass_kg,
        size_mm=size_mm,
        gear_ratio=gear,
        current_unit_a=current_unit_a,
        defaults=defaults,
        ranges=MappingProxyType(ranges),
        indirect_blocks=_X330_INDIRECT if x330 else _X430_INDIRECT,
        indirect_targets=_X330_TARGETS if x330 else _X430_TARGETS,
        armature=_armature_by_motor(gear, stall_nm) if x330 else _armature_by_gear(gear),
        damping=_DAMPING * stall_nm / _REF_STALL_NM if x330 else _DAMPING,
        frictionloss=_friction_by_stall(stall_nm),
        operating_modes=modes,
        axes=axes,
        note=note,
    )


_W330 = (20.0, 34.0, 26.0)
_W430 = (28.5, 46.5, 34.0)
_W540 = (33.5, 58.5, 44.0)
_MA269 = 0.00269  # Present Current unit 2.69 mA
_MA1 = 0.001  # Present Current unit 1 mA (330 series)

# One entry per model; figures from the page at ``_URL`` of its name. The
# defaults columns follow DEFAULT_REGISTERS:
#   Return Delay, Temperature Limit, Max / Min Voltage Limit, PWM Limit,
#   Current Limit, Velocity Limit, Moving Threshold, Shutdown, Velocity I / P,
#   Position D / I / P Gain.
# fmt: off
_ENTRIES = (
    _spec("XM430-W350", 1020, "430", volts=12.0, stall_nm=4.1, stall_a=2.3, rpm=46.0, kt=None,
          mass_kg=0.082, size_mm=_W430, gear=353.5, current_unit_a=_MA269, ranges=_X12V_RANGES,
          modes=_MODES_WITH_CURRENT,
          defaults=_defaults(250, 80, 160, 95, 885, 1193, 350, 10, 52, 1920, 100, 0, 0, 800),
          note="armature and frictionloss: Menagerie's ROBOTIS OP3 values"),
    _spec("XL430-W250", 1060, "430", volts=12.0, stall_nm=1.5, stall_a=1.4, rpm=61.0, kt=None,
          mass_kg=0.0572, size_mm=_W430, gear=258.5, current_unit_a=None, ranges=_XL430_RANGES,
          modes=_MODES_WITHOUT_CURRENT,
          defaults=_defaults(250, 72, 140, 60, 885, None, 265, 10, 52, 1000, 100, 4000, 0, 640),
          note="recommended 11.1 V (1.4 N m, 57 rpm); the 12 V figures are used. No Current "
               "Limit or Goal Current; register 126 is Present Load"),
    _spec("XH430-W350", 1000, "430", volts=12.0, stall_nm=3.4, stall_a=1.3, rpm=30.0, kt=None,
          mass_kg=0.082, size_mm=_W430, gear=353.5, current_unit_a=_MA269, ranges=_X12V_RANGES,
          modes=_MODES_WITH_CURRENT,
          defaults=_defaults(250, 80, 160, 95, 885, 648, 130, 10, 52, 1920, 100, 0, 0, 900),
          note="Position P Gain default 900 (its control table), not the XM430-W350's 800"),
    _spec("XM540-W270", 1120, "540", volts=12.0, stall_nm=10.6, stall_a=4.4, rpm=30.0, kt=2.409,
          mass_kg=0.165, size_mm=_W540, gear=272.5, current_unit_a=_MA269, ranges=_X12V_RANGES,
          modes=_MODES_WITH_CURRENT,
          defaults=_defaults(250, 80, 160, 95, 885, 2047, 128, 10, 52, 1920, 100, 0, 0, 800)),
    _spec("XH540-W270", 1100, "540", volts=12.0, stall_nm=9.9, stall_a=4.9, rpm=39.0, kt=None,
          mass_kg=0.165, size_mm=_W540, gear=272.5, current_unit_a=_MA269, ranges=_X12V_RANGES,
          modes=_MODES_WITH_CURRENT,
          defaults=_defaults(250, 80, 160, 95, 885, 2047, 167, 10, 52, 1920, 100, 0, 0, 800)),
    _spec("XL330-M288", 1200, "330", volts=5.0, stall_nm=0.52, stall_a=1.47, rpm=103.0, kt=None,
          mass_kg=0.018, size_mm=_W330, gear=288.4, current_unit_a=_MA1, ranges=_X330_RANGES,
          modes=_MODES_WITH_CURRENT,
          defaults=_defaults(250, 70, 70, 35, 885, 1750, 445, 10, 53, 1600, 180, 0, 0, 400),
          note="recommended 5 V (3.7 ~ 6 V); no performance graph on its page"),
    _spec("XL330-M077", 1190, "330", volts=5.0, stall_nm=0.215, stall_a=1.47, rpm=383.0, kt=None,
          mass_kg=0.018, size_mm=_W330, gear=77.5, current_unit_a=_MA1, ranges=_X330_RANGES,
          modes=_MODES_WITH_CURRENT,
          defaults=_defaults(250, 70, 70, 35, 885, 1750, 1620, 10, 53, 400, 40, 0, 400, 400),
          note="recommended 5 V (3.7 ~ 6 V); Position I Gain default 400; no performance "
               "graph on its page"),
    _spec("XC330-M288", 1240, "330", volts=5.0, stall_nm=0.93, stall_a=1.80, rpm=81.0, kt=None,
          mass_kg=0.023, size_mm=_W330, gear=288.35, current_unit_a=_MA1, ranges=_X330_RANGES,
          modes=_MODES_WITH_CURRENT,
          defaults=_defaults(250, 70, 70, 35, 885, 2352, 350, 10, 52, 1600, 50, 500, 0, 1100),
          note="recommended 5 V (3.7 ~ 6 V); no performance graph on its page"),
    _spec("2XL430-W250", 1090, "430", volts=12.0, stall_nm=1.5, stall_a=1.4, rpm=61.0, kt=None,
          mass_kg=0.0982, size_mm=(36.0, 46.5, 36.0), gear=257.4, current_unit_a=None,
          ranges=_XL430_RANGES, axes=2,
          modes=_MODES_WITHOUT_CURRENT,
          defaults=_defaults(250, 72, 140, 60, 885, None, 250, 10, 52, 1800, 100, 2000, 0, 640),
          note="two axes in one case (mass and size of the whole case, ratings per axis): each "
               "axis answers on its own id with its own control table; the two ids must differ "
               "(an equal id is refused with a data limit error); Baud Rate and Protocol Type "
               "change for both axes at once. Recommended 11.1 V; the 12 V figures are used. "
               "Register 126 is Present Load"),
)
# fmt: on

#: Every supported model, by canonical name.
SERVOS: MappingProxyType = MappingProxyType({s.name: s for s in _ENTRIES})

#: The model used where a file names none.
DEFAULT_SERVO = "XM430-W350"


def servo_spec(name) -> ServoSpec:
    """The entry of model ``name``: case and surrounding blanks do not matter.

    Raises
    ------
    TypeError
        If ``name`` is not a string.
    ValueError
        If the model is unknown; the message lists the known ones.
    """
    if not isinstance(name, str):
        raise TypeError(f"Expected a servo model name, got {name!r}.")
    spec = SERVOS.get(name.strip().upper())
    if spec is None:
        raise BadArgument(f"unknown model {name!r} (known: {', '.join(SERVOS)})")
    return spec


def servo_numbered(number: int) -> ServoSpec | None:
    """The entry whose Model Number is ``number``, or None."""
    return next((s for s in SERVOS.values() if s.number == number), None)
