"""Bring-up: check the servos on the bus and configure them for streaming.

Order (e-Manual: EEPROM is writable only with torque off, and changing the
Operating Mode resets the profile registers and gains):

1. ping every id and check its model number against the configuration;
2. refuse a servo with a latched hardware error (its Alert bit);
3. torque off; Return Delay Time 0; Drive Mode 0 (normal direction, velocity
   profile: the driver applies directions itself); Operating Mode 3, or 4
   (extended position) when a joint's range needs more than one turn;
   position limits 0..4095 (Position Mode);
4. Profile Acceleration and Velocity 0 (no profile: the stream is the profile);
5. torque on, then the Bus Watchdog, so a servo stops by itself when the host
   goes quiet.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from trajgen.drivers.bus import ServoBus
from trajgen.drivers.control_table import (
    EXTENDED_POSITION_MODE,
    POSITION_MODE,
    WATCHDOG_UNIT_S,
    Model,
    Register,
    model_named,
    model_numbered,
)
from trajgen.drivers.errors import BringUpError, CommError
from trajgen.drivers.units import TICKS_PER_REV, JointMap


def watchdog_units(watchdog_s: float) -> int:
    """Bus Watchdog register value (20 ms units, 1..127) for ``watchdog_s``.

    Raises
    ------
    ValueError
        If ``watchdog_s`` is outside 0.02..2.54 s.
    """
    units = math.ceil(watchdog_s / WATCHDOG_UNIT_S - 1e-9)
    if not 1 <= units <= 127:
        raise ValueError(f"Expected `watchdog_s` in 0.02..2.54 s, got {watchdog_s}.")
    return units


def operating_mode_for(goal_ticks: np.ndarray) -> int:
    """Position Mode if every goal fits in 0..4095, else Extended Position Mode.

    Parameters
    ----------
    goal_ticks : ndarray, shape (M, n)
        Every goal the stream will send.
    """
    inside = np.all((goal_ticks >= 0) & (goal_ticks < TICKS_PER_REV))
    return POSITION_MODE if inside else EXTENDED_POSITION_MODE


def check_servos(bus: ServoBus, joints: JointMap, models: Sequence[Model | str]) -> None:
    """Ping every servo, check its model, and declare it to the bus.

    Raises
    ------
    BringUpError
        If a servo does not answer or is another model.
    """
    if len(models) != len(joints):
        raise ValueError(f"Expected {len(joints)} `models`, got {len(models)}.")
    for servo_id, model in zip(joints.ids, models, strict=True):
        model = model_named(model) if isinstance(model, str) else model
        try:
            number = bus.ping(servo_id)
        except CommError as e:
            raise BringUpError(
                f"servo {servo_id}: no reply to ping at {bus.baud} baud on {bus.port_name} "
                f"(check id, baud rate, power): {e}"
            ) from e
        if number != model.number:
            found = model_numbered(number)
            name = found.name if isinstance(found, Model) else found
            raise BringUpError(
                f"servo {servo_id}: model number {number} ({name}), expected {model.number} "
                f"({model.name}); refusing to stream"
            )
        bus.add_servo(servo_id, model)


def configure(
    bus: ServoBus, joints: JointMap, *, operating_mode: int, watchdog_s: float | None
) -> None:
    """Write the streaming configuration and turn torque on (steps 2-5 above).

    Parameters
    ----------
    bus : ServoBus
        Open bus whose servos ``check_servos`` declared.
    joints : JointMap
    operating_mode : int
        3 (position) or 4 (extended position).
    watchdog_s : float or None
        Bus Watchdog period (s); None leaves it off.

    Raises
    ------
    ServoError
        If a servo reports a hardware error or refuses a write.
    CommError
        If a servo stops answering.
    """
    if operating_mode not in (POSITION_MODE, EXTENDED_POSITION_MODE):
        raise ValueError(f"Expected `operating_mode` 3 or 4, got {operating_mode}.")
    units = None if watchdog_s is None else watchdog_units(watchdog_s)
    for servo_id in joints.ids:
        bus.read(servo_id, Register.HARDWARE_ERROR_STATUS)  # raises on the Alert bit
        bus.write(servo_id, Register.TORQUE_ENABLE, 0)
        bus.write(servo_id, Register.RETURN_DELAY_TIME, 0)
        bus.write(servo_id, Register.DRIVE_MODE, 0)
        bus.write(servo_id, Register.OPERATING_MODE, operating_mode)
        if operating_mode == POSITION_MODE:
            bus.write(servo_id, Register.MIN_POSITION_LIMIT, 0)
            bus.write(servo_id, Register.MAX_POSITION_LIMIT, TICKS_PER_REV - 1)
        bus.write(servo_id, Register.PROFILE_ACCELERATION, 0)
        bus.write(servo_id, Register.PROFILE_VELOCITY, 0)
        bus.write(servo_id, Register.BUS_WATCHDOG, 0)  # clears a tripped watchdog
    for servo_id in joints.ids:
        # Goal Position = present position first, so torque on does not jump.
        bus.write(servo_id, Register.GOAL_POSITION, bus.read(servo_id, Register.PRESENT_POSITION))
        bus.write(servo_id, Register.TORQUE_ENABLE, 1)
    if units is not None:
        for servo_id in joints.ids:
            bus.write(servo_id, Register.BUS_WATCHDOG, units)


def bring_up(
    bus: ServoBus,
    joints: JointMap,
    models: Sequence[Model | str],
    goal_ticks: np.ndarray,
    *,
    watchdog_s: float | None = 0.1,
) -> int:
    """Check the servos and configure them for a stream of ``goal_ticks``.

    Parameters
    ----------
    bus : ServoBus
        An open bus.
    joints : JointMap
    models : sequence of Model or str, shape (n,)
        Expected model per joint.
    goal_ticks : ndarray, shape (M, n)
        Every goal the stream will send (chooses the operating mode).
    watchdog_s : float or None, optional
        Bus Watchdog period (s); None leaves it off.

    Returns
    -------
    int
        The operating mode set (3 or 4).

    Raises
    ------
    BringUpError
        If a servo is missing or of the wrong model.
    ServoError
        If a servo is in hardware error or refuses a write.
    CommError
        If a servo stops answering.
    """
    check_servos(bus, joints, models)
    mode = operating_mode_for(np.asarray(goal_ticks))
    configure(bus, joints, operating_mode=mode, watchdog_s=watchdog_s)
    return mode
