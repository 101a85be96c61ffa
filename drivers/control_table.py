"""X-series control tables as data: registers, models, addresses.

Addresses and sizes come from the model files that ship with
``dynamixel-sdk`` (``dynamixel_easy_sdk.control_table.ControlTable``), which
transcribe the ROBOTIS e-Manual control tables; they are read on first use.
What those files lack is stated here (current unit, baud rates, and the access,
initial value and range of each register, which the virtual servo enforces),
with the e-Manual X-series pages as the source;
the ratings and Model Numbers come from ``trajgen.servo_ratings``, the table the
simulator reads too.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import Enum

from trajgen.servo_ratings import RATINGS, servo_rating


class Register(Enum):
    """Registers the driver uses; the value is the e-Manual / SDK data name."""

    MODEL_NUMBER = "Model Number"
    FIRMWARE_VERSION = "Firmware Version"
    ID = "ID"
    BAUD_RATE = "Baud Rate"
    RETURN_DELAY_TIME = "Return Delay Time"
    DRIVE_MODE = "Drive Mode"
    OPERATING_MODE = "Operating Mode"
    SECONDARY_ID = "Secondary(Shadow) ID"
    TEMPERATURE_LIMIT = "Temperature Limit"
    MAX_VOLTAGE_LIMIT = "Max Voltage Limit"
    MIN_VOLTAGE_LIMIT = "Min Voltage Limit"
    MAX_POSITION_LIMIT = "Max Position Limit"
    MIN_POSITION_LIMIT = "Min Position Limit"
    SHUTDOWN = "Shutdown"
    TORQUE_ENABLE = "Torque Enable"
    STATUS_RETURN_LEVEL = "Status Return Level"
    HARDWARE_ERROR_STATUS = "Hardware Error Status"
    VELOCITY_I_GAIN = "Velocity I Gain"
    VELOCITY_P_GAIN = "Velocity P Gain"
    POSITION_D_GAIN = "Position D Gain"
    POSITION_I_GAIN = "Position I Gain"
    POSITION_P_GAIN = "Position P Gain"
    FEEDFORWARD_2ND_GAIN = "Feedforward 2nd Gain"
    FEEDFORWARD_1ST_GAIN = "Feedforward 1st Gain"
    BUS_WATCHDOG = "Bus Watchdog"
    GOAL_PWM = "Goal PWM"
    PROFILE_ACCELERATION = "Profile Acceleration"
    PROFILE_VELOCITY = "Profile Velocity"
    GOAL_POSITION = "Goal Position"
    PRESENT_CURRENT = "Present Current"  # XL430: "Present Load" at the same address
    PRESENT_VELOCITY = "Present Velocity"
    PRESENT_POSITION = "Present Position"
    PRESENT_INPUT_VOLTAGE = "Present Input Voltage"
    PRESENT_TEMPERATURE = "Present Temperature"


# Registers holding two's-complement values (e-Manual: range includes negatives).
SIGNED = frozenset(
    {
        Register.BUS_WATCHDOG,
        Register.GOAL_PWM,
        Register.GOAL_POSITION,
        Register.MAX_POSITION_LIMIT,
        Register.MIN_POSITION_LIMIT,
        Register.PRESENT_CURRENT,
        Register.PRESENT_VELOCITY,
        Register.PRESENT_POSITION,
    }
)

# EEPROM area: writable only while Torque Enable is 0.
EEPROM_END = 64

# What a change of Operating Mode resets to its initial value (e-Manual,
# "Operating Mode (11)"; Goal Current too, on the models that have it).
MODE_RESETS = (
    Register.VELOCITY_I_GAIN,
    Register.VELOCITY_P_GAIN,
    Register.POSITION_D_GAIN,
    Register.POSITION_I_GAIN,
    Register.POSITION_P_GAIN,
    Register.FEEDFORWARD_2ND_GAIN,
    Register.FEEDFORWARD_1ST_GAIN,
    Register.GOAL_PWM,
    Register.PROFILE_ACCELERATION,
    Register.PROFILE_VELOCITY,
)

# Operating Mode values (e-Manual, "Operating Mode (11)").
CURRENT_MODE = 0
VELOCITY_MODE = 1
POSITION_MODE = 3
EXTENDED_POSITION_MODE = 4
CURRENT_BASED_POSITION_MODE = 5
PWM_MODE = 16
OPERATING_MODE_NAMES = {
    CURRENT_MODE: "current control",
    VELOCITY_MODE: "velocity control",
    POSITION_MODE: "position control",
    EXTENDED_POSITION_MODE: "extended position control",
    CURRENT_BASED_POSITION_MODE: "current-based position control",
    PWM_MODE: "PWM control",
}

# Secondary ID (12) value that turns it off (e-Manual: 253..255 disable it).
SECONDARY_ID_OFF = 255

# Present Input Voltage and the voltage limits are in 0.1 V; temperatures in 1 deg C.
VOLTAGE_UNIT_V = 0.1

# Hardware Error Status bits (e-Manual, "Hardware Error Status (70)").
HARDWARE_ERROR_BITS = {
    0: "input voltage",
    2: "overheating",
    3: "motor encoder",
    4: "electrical shock",
    5: "overload",
}

# Bus Watchdog unit (e-Manual, "Bus Watchdog (98)").
WATCHDOG_UNIT_S = 0.020

#: Baud rates an X-series servo can be set to (e-Manual, "Baud Rate (8)"), by register value.
BAUD_RATES = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}


@dataclass(frozen=True)
class Model:
    """One servo model.

    Attributes
    ----------
    name : str
        e-Manual name, e.g. ``"XM430-W350"``.
    number : int
        Model Number register value.
    stall_torque_nm, stall_current_a : float
        Stall torque (N m) and current (A) at 12 V.
    no_load_speed_rad_s : float
        No-load speed (rad/s) at 12 V.
    current_unit_a : float or None
        Present Current unit (A); None where register 126 is Present Load
        (XL430, 0.1 % of stall), which the driver converts through the stall
        current instead.
    """

    name: str
    number: int
    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rad_s: float
    current_unit_a: float | None

    def current_a(self, raw: int) -> float:
        """Convert a signed register 126 value to amperes."""
        if self.current_unit_a is None:
            return raw * 0.001 * self.stall_current_a
        return raw * self.current_unit_a

    def current_raw(self, current_a: float) -> int:
        """Convert amperes to a register 126 value (inverse of ``current_a``)."""
        if self.current_unit_a is None:
            return round(current_a / (0.001 * self.stall_current_a))
        return round(current_a / self.current_unit_a)


#: Present Current unit (A) per model (e-Manual: 2.69 mA; None where register 126
#: is Present Load, 0.1 % of stall).
_CURRENT_UNIT_A = {
    "XM430-W350": 0.00269,
    "XL430-W250": None,
    "XH430-W350": 0.00269,
    "XM540-W270": 0.00269,
}

MODELS: dict[str, Model] = {
    r.name: Model(
        r.name,
        r.number,
        r.stall_torque_nm,
        r.stall_current_a,
        r.no_load_speed_rad_s,
        _CURRENT_UNIT_A[r.name],
    )
    for r in RATINGS.values()
}


def model_named(name: str) -> Model:
    """The ``Model`` called ``name`` (case and blanks do not matter).

    Raises
    ------
    TypeError
        If ``name`` is not a string.
    ValueError
        If the model is not one of ``MODELS``.
    """
    return MODELS[servo_rating(name).name]


def model_numbered(number: int) -> Model | str:
    """The ``Model`` with Model Number ``number``, or the SDK's name for it.

    Returns the SDK model-file name (``"mx_28"``) for models outside ``MODELS``
    and ``"unknown"`` for numbers the SDK does not know either; used in messages.
    """
    for model in MODELS.values():
        if model.number == number:
            return model
    from dynamixel_easy_sdk.control_table import ControlTable
    from dynamixel_easy_sdk.dynamixel_error import DxlRuntimeError

    try:
        return ControlTable.getModelName(number).removesuffix(".model")
    except DxlRuntimeError:
        return "unknown"


@functools.cache
def layout(model: Model) -> dict[Register, tuple[int, int]]:
    """Address and size (bytes) of every ``Register`` for ``model``.

    Read from the SDK's model file for ``model.number``.

    Raises
    ------
    KeyError
        If the model file lacks a register (a bug in this table).
    """
    from dynamixel_easy_sdk.control_table import ControlTable

    table = ControlTable.getControlTable(model.number)
    aliases = {Register.PRESENT_CURRENT: ("Present Current", "Present Load")}
    out = {}
    for register in Register:
        names = aliases.get(register, (register.value,))
        item = next((table[n] for n in names if n in table), None)
        if item is None:
            raise KeyError(f"{model.name}: the SDK's control table has no {register.value!r}")
        out[register] = (item.address, item.size)
    return out


def describe_hardware_error(status: int) -> str:
    """Names of the bits set in a Hardware Error Status value, e.g. ``"overload"``."""
    names = [name for bit, name in HARDWARE_ERROR_BITS.items() if status >> bit & 1]
    return ", ".join(names) or f"unknown bits {status:#04x}"


# -- What the e-Manual says of each register, for the virtual servo --------------
#
# Addresses and sizes come from the SDK's model files (``layout`` above and
# ``control_items``); what those files lack is stated here from the e-Manual
# X-series control tables (XM430-W350, XL430-W250, XH430-W350, XM540-W270 pages:
# access, initial value, range). A range that depends on another register (Goal
# Position within the position limits, Goal PWM within PWM Limit...) is in
# ``LIMITED_BY``.


@dataclass(frozen=True)
class RegisterRule:
    """Access, initial value and range of one register (e-Manual control table).

    Attributes
    ----------
    writable : bool
        RW (True) or R (False).
    initial : int or None
        Value at power-up; None where the servo sets it itself (Goal Position =
        present position, present values measured, Model Number...).
    low, high : int or None
        Range a write must fall in (data range error outside); None: any value
        the register holds.
    signed : bool
        Whether the register holds a two's-complement value.
    """

    writable: bool
    initial: int | None
    low: int | None = None
    high: int | None = None
    signed: bool = False


def _rw(initial, low, high, signed=False):
    return RegisterRule(True, initial, low, high, signed)


def _r(initial=None, signed=False):
    return RegisterRule(False, initial, signed=signed)


_GAIN = (0, 16_383)

#: Rules of the X-series registers (XM430-W350 values; see MODEL_RULES for the others).
X_SERIES_RULES: dict[str, RegisterRule] = {
    "Model Number": _r(),
    "Model Information": _r(0),
    "Firmware Version": _r(),
    "ID": _rw(1, 0, 252),
    "Baud Rate": _rw(1, 0, 7),
    "Return Delay Time": _rw(250, 0, 254),
    "Drive Mode": _rw(0, 0, 13),
    "Operating Mode": _rw(3, 0, 16),
    "Secondary(Shadow) ID": _rw(255, 0, 255),
    "Protocol Type": _rw(2, 1, 2),
    "Homing Offset": _rw(0, -1_044_479, 1_044_479, signed=True),
    "Moving Threshold": _rw(10, 0, 1023),
    "Temperature Limit": _rw(80, 0, 100),
    "Max Voltage Limit": _rw(160, 95, 160),
    "Min Voltage Limit": _rw(95, 95, 160),
    "PWM Limit": _rw(885, 0, 885),
    "Current Limit": _rw(1193, 0, 1193),
    "Velocity Limit": _rw(350, 0, 1023),
    "Max Position Limit": _rw(4095, 0, 4095, signed=True),
    "Min Position Limit": _rw(0, 0, 4095, signed=True),
    "Shutdown": _rw(52, 0, 255),
    "Torque Enable": _rw(0, 0, 1),
    "LED": _rw(0, 0, 1),
    "Status Return Level": _rw(2, 0, 2),
    "Registered Instruction": _r(0),
    "Hardware Error Status": _r(0),
    "Velocity I Gain": _rw(1920, *_GAIN),
    "Velocity P Gain": _rw(100, *_GAIN),
    "Position D Gain": _rw(0, *_GAIN),
    "Position I Gain": _rw(0, *_GAIN),
    "Position P Gain": _rw(800, *_GAIN),
    "Feedforward 2nd Gain": _rw(0, *_GAIN),
    "Feedforward 1st Gain": _rw(0, *_GAIN),
    # 1..127 arms it, 0 disarms (and clears a trip); the servo writes -1 on a trip.
    "Bus Watchdog": _rw(0, 0, 127, signed=True),
    "Goal PWM": _rw(None, None, None, signed=True),
    "Goal Current": _rw(None, None, None, signed=True),
    "Goal Velocity": _rw(0, None, None, signed=True),
    "Profile Acceleration": _rw(0, 0, 32_767),
    "Profile Velocity": _rw(0, 0, 32_767),
    "Goal Position": _rw(None, -1_048_575, 1_048_575, signed=True),
    "Realtime Tick": _r(0),
    "Moving": _r(0),
    "Moving Status": _r(0),
    "Present PWM": _r(0, signed=True),
    "Present Current": _r(0, signed=True),
    "Present Load": _r(0, signed=True),
    "Present Velocity": _r(0, signed=True),
    "Present Position": _r(0, signed=True),
    "Velocity Trajectory": _r(0, signed=True),
    "Position Trajectory": _r(0, signed=True),
    "Present Input Voltage": _r(120),
    "Present Temperature": _r(30),
}

#: Where the other models differ from X_SERIES_RULES (their e-Manual pages).
MODEL_RULES: dict[str, dict[str, RegisterRule]] = {
    "XM430-W350": {},
    "XL430-W250": {
        "Temperature Limit": _rw(72, 0, 100),
        "Max Voltage Limit": _rw(140, 60, 140),
        "Min Voltage Limit": _rw(60, 60, 140),
        "Velocity Limit": _rw(265, 0, 1023),
        "Velocity I Gain": _rw(1000, *_GAIN),
        "Position D Gain": _rw(4000, *_GAIN),
        "Position P Gain": _rw(640, *_GAIN),
    },
    "XH430-W350": {
        "Current Limit": _rw(648, 0, 648),
        "Velocity Limit": _rw(130, 0, 1023),
        "Position P Gain": _rw(900, *_GAIN),
    },
    "XM540-W270": {
        "Current Limit": _rw(2047, 0, 2047),
        "Velocity Limit": _rw(128, 0, 1023),
    },
}

#: Registers whose range is set by other registers: a write outside it is
#: refused with the data limit error. Goal Position's limits apply in Position
#: Mode only; the others are symmetric, +-the limit register.
LIMITED_BY = {
    "Goal Position": ("Min Position Limit", "Max Position Limit"),
    "Goal PWM": ("PWM Limit",),
    "Goal Current": ("Current Limit",),
    "Goal Velocity": ("Velocity Limit",),
}

#: Indirect Address / Indirect Data blocks of the X-series: (first Indirect
#: Address, first Indirect Data, count). Indirect Address n is 2 bytes, Indirect
#: Data n 1 byte; Indirect Address n initially points at Indirect Data n, and
#: may point anywhere in 64..661 (e-Manual, "Indirect Address").
INDIRECT_BLOCKS = ((168, 224, 28), (578, 634, 28))
INDIRECT_TARGETS = (64, 661)


def rules(model: Model) -> dict[str, RegisterRule]:
    """Every register rule of ``model``, Indirect Address / Data n included."""
    out = dict(X_SERIES_RULES)
    out.update(MODEL_RULES[model.name])
    n = 0
    for _, data0, count in INDIRECT_BLOCKS:
        for k in range(count):
            n += 1
            out[f"Indirect Address {n}"] = _rw(data0 + k, *INDIRECT_TARGETS)
            out[f"Indirect Data {n}"] = _rw(0, 0, 255)
    return out


@functools.cache
def control_items(model: Model) -> dict[str, tuple[int, int]]:
    """Address and size (bytes) of every register of ``model``, by SDK name.

    From the SDK's model file, plus every Indirect Address / Data n (the file
    lists only the first of each block). Only registers with a rule are kept.
    """
    from dynamixel_easy_sdk.control_table import ControlTable

    table = ControlTable.getControlTable(model.number)
    known = rules(model)
    out = {name: (item.address, item.size) for name, item in table.items() if name in known}
    n = 0
    for address0, data0, count in INDIRECT_BLOCKS:
        for k in range(count):
            n += 1
            out[f"Indirect Address {n}"] = (address0 + 2 * k, 2)
            out[f"Indirect Data {n}"] = (data0 + k, 1)
    return out
