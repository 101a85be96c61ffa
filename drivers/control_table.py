"""X-series control tables as data: registers, models, addresses.

Addresses and sizes come from the model files that ship with
``dynamixel-sdk`` (``dynamixel_easy_sdk.control_table.ControlTable``), which
transcribe the ROBOTIS e-Manual control tables; they are read on first use.
What those files lack is stated here (current unit, factory defaults used by
the virtual bus, baud rates), with the e-Manual X-series pages as the source;
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
    MAX_POSITION_LIMIT = "Max Position Limit"
    MIN_POSITION_LIMIT = "Min Position Limit"
    SHUTDOWN = "Shutdown"
    TORQUE_ENABLE = "Torque Enable"
    STATUS_RETURN_LEVEL = "Status Return Level"
    HARDWARE_ERROR_STATUS = "Hardware Error Status"
    BUS_WATCHDOG = "Bus Watchdog"
    PROFILE_ACCELERATION = "Profile Acceleration"
    PROFILE_VELOCITY = "Profile Velocity"
    GOAL_POSITION = "Goal Position"
    PRESENT_CURRENT = "Present Current"  # XL430: "Present Load" at the same address
    PRESENT_VELOCITY = "Present Velocity"
    PRESENT_POSITION = "Present Position"


# Registers holding two's-complement values (e-Manual: range includes negatives).
SIGNED = frozenset(
    {
        Register.BUS_WATCHDOG,
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

# Operating Mode values (e-Manual, "Operating Mode (11)").
POSITION_MODE = 3
EXTENDED_POSITION_MODE = 4

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


def factory_defaults(model: Model) -> dict[Register, int]:
    """Factory default values of the registers the virtual bus gives meaning to.

    e-Manual X-series control tables: Baud Rate 1 (57600), Return Delay Time 250
    (500 us), Operating Mode 3, position limits 0..4095, Shutdown 52 (overheating,
    electrical shock, overload), Status Return Level 2 (reply to everything).
    """
    return {
        Register.MODEL_NUMBER: model.number,
        Register.ID: 1,
        Register.BAUD_RATE: 1,
        Register.RETURN_DELAY_TIME: 250,
        Register.OPERATING_MODE: POSITION_MODE,
        Register.MAX_POSITION_LIMIT: 4095,
        Register.MIN_POSITION_LIMIT: 0,
        Register.SHUTDOWN: 52,
        Register.STATUS_RETURN_LEVEL: 2,
    }


def describe_hardware_error(status: int) -> str:
    """Names of the bits set in a Hardware Error Status value, e.g. ``"overload"``."""
    names = [name for bit, name in HARDWARE_ERROR_BITS.items() if status >> bit & 1]
    return ", ".join(names) or f"unknown bits {status:#04x}"
