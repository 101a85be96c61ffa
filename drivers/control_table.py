"""X-series control tables as data: registers, models, addresses.

Addresses and sizes come from the model files that ship with
``dynamixel-sdk`` (``dynamixel_easy_sdk.control_table.ControlTable``), which
transcribe the ROBOTIS e-Manual control tables; they are read on first use.
Every model fact (Model Number, ratings, current unit, factory register
values, indirect blocks, baud rates, error bits) is an entry of
``trajgen.servo_table``, the table the simulator reads too; what is stated
here is what only the driver needs: which registers it uses, which hold signed
values, and the access and range rules the virtual servo enforces.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from enum import Enum

from trajgen.servo_table import (
    BAUD_RATES,
    CURRENT_BASED_POSITION_MODE,
    CURRENT_MODE,
    EEPROM_END,
    EXTENDED_POSITION_MODE,
    GAIN_MAX,
    HARDWARE_ERROR_BITS,
    POSITION_MODE,
    PWM_FULL_SCALE,
    PWM_MODE,
    RETURN_DELAY_UNIT_S,
    SERVOS,
    TICKS_PER_REV,
    VELOCITY_MODE,
    WATCHDOG_UNIT_S,
    ServoSpec,
    servo_numbered,
    servo_spec,
)

__all__ = [
    "BAUD_RATES",
    "EEPROM_END",
    "EXTENDED_POSITION_MODE",
    "HARDWARE_ERROR_BITS",
    "MODELS",
    "POSITION_MODE",
    "RETURN_DELAY_UNIT_S",
    "WATCHDOG_UNIT_S",
    "Model",
    "Register",
    "RegisterRule",
    "control_items",
    "describe_hardware_error",
    "layout",
    "model_named",
    "model_numbered",
    "rules",
]


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

#: A servo model: its entry of ``trajgen.servo_table`` (Model Number, ratings,
#: ``current_a`` / ``current_raw`` for register 126, register defaults).
Model = ServoSpec

#: Every supported model, by canonical name (the servo table's entries).
MODELS = SERVOS

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

# Operating Mode values: trajgen.servo_table (each model's own in ServoSpec.operating_modes).
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


def model_named(name: str) -> Model:
    """The ``Model`` called ``name`` (case and blanks do not matter).

    Raises
    ------
    TypeError
        If ``name`` is not a string.
    ValueError
        If the model is not one of ``MODELS``.
    """
    return servo_spec(name)


def model_numbered(number: int) -> Model | str:
    """The ``Model`` with Model Number ``number``, or the SDK's name for it.

    Returns the SDK model-file name (``"mx_28"``) for models outside ``MODELS``
    and ``"unknown"`` for numbers the SDK does not know either; used in messages.
    """
    model = servo_numbered(number)
    if model is not None:
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
# X-series control tables (access, range) and, per model, from its servo-table
# entry (factory values, ranges that differ, indirect blocks). A range that
# depends on another register (Goal Position within the position limits, Goal
# PWM within PWM Limit...) is in ``LIMITED_BY``.


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


_GAIN = (0, GAIN_MAX)
_TICK_MAX = TICKS_PER_REV - 1
_FROM_TABLE = None  # initial value (and range where it differs): the model's servo-table entry

#: Access and range of the X-series registers. Where a model's factory value or
#: range differs (``trajgen.servo_table.DEFAULT_REGISTERS``, ``ServoSpec.ranges``)
#: the entry supplies it: see ``rules``.
X_SERIES_RULES: dict[str, RegisterRule] = {
    "Model Number": _r(),
    "Model Information": _r(0),
    "Firmware Version": _r(),
    "ID": _rw(1, 0, 252),
    "Baud Rate": _rw(1, 0, 7),
    "Return Delay Time": _rw(_FROM_TABLE, 0, 254),
    "Drive Mode": _rw(0, 0, 13),
    "Operating Mode": _rw(POSITION_MODE, 0, 16),
    "Secondary(Shadow) ID": _rw(255, 0, 255),
    "Protocol Type": _rw(2, 1, 2),
    "Homing Offset": _rw(0, -1_044_479, 1_044_479, signed=True),
    "Moving Threshold": _rw(_FROM_TABLE, 0, 1023),
    "Temperature Limit": _rw(_FROM_TABLE, 0, 100),
    "Max Voltage Limit": _rw(_FROM_TABLE, None, None),
    "Min Voltage Limit": _rw(_FROM_TABLE, None, None),
    "PWM Limit": _rw(_FROM_TABLE, 0, PWM_FULL_SCALE),
    "Current Limit": _rw(_FROM_TABLE, None, None),
    "Velocity Limit": _rw(_FROM_TABLE, 0, 1023),
    "Max Position Limit": _rw(_TICK_MAX, 0, _TICK_MAX, signed=True),
    "Min Position Limit": _rw(0, 0, _TICK_MAX, signed=True),
    "Shutdown": _rw(_FROM_TABLE, 0, 255),
    "Torque Enable": _rw(0, 0, 1),
    "LED": _rw(0, 0, 1),
    "Status Return Level": _rw(2, 0, 2),
    "Registered Instruction": _r(0),
    "Hardware Error Status": _r(0),
    "Velocity I Gain": _rw(_FROM_TABLE, *_GAIN),
    "Velocity P Gain": _rw(_FROM_TABLE, *_GAIN),
    "Position D Gain": _rw(_FROM_TABLE, *_GAIN),
    "Position I Gain": _rw(_FROM_TABLE, *_GAIN),
    "Position P Gain": _rw(_FROM_TABLE, *_GAIN),
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
    "Present Input Voltage": _r(_FROM_TABLE),
    "Present Temperature": _r(30),
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


def rules(model: Model) -> dict[str, RegisterRule]:
    """Every register rule of ``model``, Indirect Address / Data n included.

    The X-series rules with the model's factory values and ranges from its
    servo-table entry; a register the entry says the model lacks (Current Limit
    None) has no rule.
    """
    out = dict(X_SERIES_RULES)
    for name, value in model.defaults.items():
        if value is None:
            del out[name]
        else:
            out[name] = dataclasses.replace(out[name], initial=value)
    for name, (low, high) in model.ranges.items():
        out[name] = dataclasses.replace(out[name], low=low, high=high)
    # The virtual servo's supply: the rated voltage (unit 0.1 V).
    out["Present Input Voltage"] = _r(round(model.voltage_v * 10))
    n = 0
    for _, data0, count in model.indirect_blocks:
        for k in range(count):
            n += 1
            out[f"Indirect Address {n}"] = _rw(data0 + k, *model.indirect_targets)
            out[f"Indirect Data {n}"] = _rw(0, 0, 255)
    return out


@functools.cache
def control_items(model: Model) -> dict[str, tuple[int, int]]:
    """Address and size (bytes) of every register of ``model``, by SDK name.

    From the SDK's model file, plus every Indirect Address / Data n from the
    entry's indirect blocks (the file lists only the first of each block, and
    for the 330 series at the 430's addresses). Only registers with a rule are
    kept.
    """
    from dynamixel_easy_sdk.control_table import ControlTable

    table = ControlTable.getControlTable(model.number)
    known = rules(model)
    out = {name: (item.address, item.size) for name, item in table.items() if name in known}
    n = 0
    for address0, data0, count in model.indirect_blocks:
        for k in range(count):
            n += 1
            out[f"Indirect Address {n}"] = (address0 + 2 * k, 2)
            out[f"Indirect Data {n}"] = (data0 + k, 1)
    return out
