"""Supply voltage and temperature against a servo's own limits.

An X-series servo compares Present Input Voltage (144) with its Min / Max
Voltage Limit (34 / 32) and Present Temperature (146) with its Temperature
Limit (31). Past a limit it latches a Hardware Error Status bit and, for the
errors its Shutdown register covers (overheating by default), turns its
torque off: a loaded joint drops. The driver reads both at a low rate and
warns, then stops the stream (holding or releasing, as asked) *before* the
servo's own threshold, while the servo still obeys.
"""

from __future__ import annotations

from dataclasses import dataclass

from trajgen.drivers.control_table import VOLTAGE_UNIT_V

#: Warn this close to a voltage limit (V), inside it.
VOLTAGE_WARN_MARGIN_V = 0.5
#: Stop this close to a voltage limit (V), inside it (the servo's error is at the limit).
VOLTAGE_STOP_MARGIN_V = 0.2
#: Warn this many deg C below the Temperature Limit.
TEMPERATURE_WARN_MARGIN_C = 10
#: Stop this many deg C below the Temperature Limit (the servo shuts down at it).
TEMPERATURE_STOP_MARGIN_C = 3


@dataclass(frozen=True)
class PowerLimits:
    """A servo's own limits, read at bring-up.

    Attributes
    ----------
    min_voltage_v, max_voltage_v : float
        Min / Max Voltage Limit (34 / 32), V.
    temperature_limit_c : int
        Temperature Limit (31), deg C.
    """

    min_voltage_v: float
    max_voltage_v: float
    temperature_limit_c: int

    @classmethod
    def from_registers(cls, min_raw: int, max_raw: int, temperature_c: int) -> PowerLimits:
        """From the register values (voltages in 0.1 V units)."""
        return cls(min_raw * VOLTAGE_UNIT_V, max_raw * VOLTAGE_UNIT_V, int(temperature_c))


def health_problem(
    who: str, limits: PowerLimits, voltage_v: float, temperature_c: float
) -> tuple[str, str] | None:
    """``("stop" | "warn", message)`` for a reading near or past the limits, else None.

    Parameters
    ----------
    who : str
        The servo, for the message (``"servo 2 (tilt)"``).
    limits : PowerLimits
    voltage_v : float
        Present Input Voltage (V).
    temperature_c : float
        Present Temperature (deg C).
    """
    low, high = limits.min_voltage_v, limits.max_voltage_v
    t_limit = limits.temperature_limit_c
    supply = f"input voltage {voltage_v:.1f} V"
    if voltage_v <= low + VOLTAGE_STOP_MARGIN_V:
        return "stop", (
            f"{who}: {supply}, at or under its Min Voltage Limit {low:.1f} V (+ "
            f"{VOLTAGE_STOP_MARGIN_V} V margin): check the supply and its wiring"
        )
    if voltage_v >= high - VOLTAGE_STOP_MARGIN_V:
        return "stop", (
            f"{who}: {supply}, at or over its Max Voltage Limit {high:.1f} V (- "
            f"{VOLTAGE_STOP_MARGIN_V} V margin): check the supply"
        )
    if temperature_c >= t_limit - TEMPERATURE_STOP_MARGIN_C:
        return "stop", (
            f"{who}: temperature {temperature_c:g} deg C, within {TEMPERATURE_STOP_MARGIN_C} "
            f"deg C of its Temperature Limit {t_limit} deg C (where it shuts down): let it cool"
        )
    if voltage_v < low + VOLTAGE_WARN_MARGIN_V or voltage_v > high - VOLTAGE_WARN_MARGIN_V:
        return "warn", (
            f"{who}: {supply}, within {VOLTAGE_WARN_MARGIN_V} V of its voltage limits "
            f"{low:.1f}..{high:.1f} V"
        )
    if temperature_c >= t_limit - TEMPERATURE_WARN_MARGIN_C:
        return "warn", (
            f"{who}: temperature {temperature_c:g} deg C, within {TEMPERATURE_WARN_MARGIN_C} "
            f"deg C of its Temperature Limit {t_limit} deg C"
        )
    return None
