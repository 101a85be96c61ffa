"""Bring-up: check the servos on the bus, then configure them for streaming.

Nothing is changed on any servo until every servo has been checked
(``inspect``) and the plan has been checked against what is installed
(``check_plan``):

1. ping every id and check its model number against the configuration;
2. read, from every servo, Hardware Error Status (a latched error refuses the
   whole bus), Torque Enable, Drive Mode, Operating Mode, Max / Min Position
   Limit and Present Position;
3. refuse Drive Mode bit 2 (time-based profile: the servo would re-plan every
   streamed goal); keep bit 0 (reverse) as installed: directions are a mapping
   in the keyframe file, never a Drive Mode write;
4. refuse a plan that leaves a joint's installed position limits (naming the
   joint, the time, the angle and the limit), or that starts far from where
   the servos are. Limits are never widened; only an explicit ``set_limits``
   writes them;

then (``configure``), servo by servo: torque off only where an EEPROM
register must change; Return Delay Time 0; Operating Mode 3, or 4 (extended
position) for a joint whose range needs more than one turn; ``set_limits``
where given; Profile Acceleration and Velocity 0 (the stream is the profile);
Bus Watchdog 0. Last, for every servo: Present Position read again and checked
against the plan before it becomes Goal Position, torque on, then the Bus
Watchdog, so a servo stops by itself when the host goes quiet.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

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
from trajgen.drivers.units import RAD_PER_TICK, TICKS_PER_REV, JointMap
from trajgen.gimbal import JOINT_NAMES
from trajgen.lead import sent_q

#: Drive Mode bits (e-Manual, "Drive Mode (10)").
DRIVE_MODE_REVERSE = 0x01
DRIVE_MODE_TIME_BASED = 0x04

#: Default largest distance (rad) of any joint from the plan's first frame at start.
MAX_APPROACH_RAD = math.radians(45.0)

#: Position limits as they leave the factory (the full single turn).
FACTORY_LIMITS = (0, TICKS_PER_REV - 1)


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
    goal_ticks : ndarray, shape (M, n) or (M,)
        Every goal the stream will send (to several servos, or one).
    """
    inside = np.all((goal_ticks >= 0) & (goal_ticks < TICKS_PER_REV))
    return POSITION_MODE if inside else EXTENDED_POSITION_MODE


def joint_names_for(joints: JointMap, joint_names: Sequence[str] | None = None) -> tuple[str, ...]:
    """Names for messages: ``joint_names``, else pan, tilt, roll for 3 joints, else joint k."""
    if joint_names is not None:
        if len(joint_names) != len(joints):
            raise ValueError(f"Expected {len(joints)} `joint_names`, got {len(joint_names)}.")
        return tuple(joint_names)
    if len(joints) == len(JOINT_NAMES):
        return JOINT_NAMES
    return tuple(f"joint {k}" for k in range(len(joints)))


@dataclass(frozen=True)
class Installed:
    """What one servo holds before bring-up changes anything.

    Attributes
    ----------
    servo_id : int
    torque_on : bool
    drive_mode, operating_mode : int
        Drive Mode (10) and Operating Mode (11) register values.
    min_limit, max_limit : int
        Min / Max Position Limit (52 / 48), ticks.
    present : int
        Present Position (132), ticks.
    """

    servo_id: int
    torque_on: bool
    drive_mode: int
    operating_mode: int
    min_limit: int
    max_limit: int
    present: int

    @property
    def factory_limits(self) -> bool:
        """Whether the limits are the factory 0..4095 (nobody restricted this joint)."""
        return (self.min_limit, self.max_limit) == FACTORY_LIMITS


@dataclass(frozen=True)
class JointRange:
    """The plan of an online stream, for bring-up: where it starts and every angle it may take.

    An online stream's frames are not known in advance; bring-up checks its
    first frame (the approach distance) and the whole range it may cover (the
    installed position limits) instead.

    Attributes
    ----------
    first_rad : ndarray, shape (n,)
        Where the stream starts (rad): its first frame, or where the servos are
        (the streamer checks the first frame again before the approach).
    limits_rad : ndarray, shape (n, 2)
        Lowest and highest angle (rad) per joint the stream may command.
    """

    first_rad: np.ndarray
    limits_rad: np.ndarray


def _plan_rows(plan) -> tuple[np.ndarray, object]:
    """Joint angles (rad, shape (M, n), the first frame first) bring-up checks of a plan
    (a trajectory or a ``JointRange``), and a function naming row ``k`` in messages."""
    if isinstance(plan, JointRange):
        rows = np.vstack([plan.first_rad, np.asarray(plan.limits_rad, float).T])
        return rows, lambda k: "at its start" if k == 0 else "within its joint limits"
    t = np.asarray(plan.t, dtype=float)
    # The goals that will be sent (led ahead of the plan, trajgen.lead), not only the plan.
    return np.asarray(sent_q(plan), dtype=float), lambda k: f"at t = {t[k]:.3f} s"


@dataclass(frozen=True)
class BringUp:
    """What bring-up found and set.

    Attributes
    ----------
    installed : tuple of Installed, shape (n,)
        Each servo as found, in joint order.
    operating_modes : tuple of int, shape (n,)
        Operating Mode set per servo (3 or 4).
    limits_ticks : ndarray of int64, shape (n, 2)
        Min and Max Position Limit per servo after bring-up (ticks).
    present_ticks : ndarray of int64, shape (n,)
        Present Position just before torque on (= the first Goal Position).
    trajectory : object
        The plan the checks were made against (a trajectory, or a ``JointRange``).
    """

    installed: tuple[Installed, ...]
    operating_modes: tuple[int, ...]
    limits_ticks: np.ndarray
    present_ticks: np.ndarray
    trajectory: object

    @property
    def goal_bounds_ticks(self) -> np.ndarray:
        """Lowest and highest goal (ticks) per servo, shape (n, 2), for ``Streamer``.

        The position limits where the servo is in Position Mode; the register's
        whole range in Extended Position Mode (factory limits only, see
        ``check_plan``).
        """
        bounds = self.limits_ticks.copy()
        extended = np.array(self.operating_modes) == EXTENDED_POSITION_MODE
        bounds[extended] = (-(2**31), 2**31 - 1)
        return bounds


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


def inspect(bus: ServoBus, joints: JointMap) -> tuple[Installed, ...]:
    """Read what every servo holds; change nothing.

    Parameters
    ----------
    bus : ServoBus
        Open bus whose servos ``check_servos`` declared.
    joints : JointMap

    Returns
    -------
    tuple of Installed, shape (n,)

    Raises
    ------
    ServoError
        If a servo has a latched hardware error (before any servo is changed).
    CommError
        If a servo stops answering or its replies are not sound.
    """
    found = []
    for servo_id in joints.ids:
        bus.read(servo_id, Register.HARDWARE_ERROR_STATUS)  # raises on the Alert bit
        found.append(
            Installed(
                servo_id=servo_id,
                torque_on=bus.read(servo_id, Register.TORQUE_ENABLE) == 1,
                drive_mode=bus.read(servo_id, Register.DRIVE_MODE),
                operating_mode=bus.read(servo_id, Register.OPERATING_MODE),
                min_limit=bus.read(servo_id, Register.MIN_POSITION_LIMIT),
                max_limit=bus.read(servo_id, Register.MAX_POSITION_LIMIT),
                present=bus.read(servo_id, Register.PRESENT_POSITION),
            )
        )
    return tuple(found)


def _deg(joints: JointMap, j: int, ticks: float) -> str:
    angle = joints.directions[j] * (ticks - joints.zeros[j]) * RAD_PER_TICK
    return f"{math.degrees(angle):.1f} deg"


def check_start(
    present_rad: np.ndarray,
    first_rad: np.ndarray,
    max_approach_rad: float,
    joint_names: Sequence[str],
) -> None:
    """Refuse to start when a joint is farther than ``max_approach_rad`` from the first frame.

    A read-back position becomes a goal (the first Goal Position, the start of
    the move to the first frame); this is its plausibility check.

    Parameters
    ----------
    present_rad, first_rad : ndarray, shape (n,)
        Present joint angles and the plan's first frame (rad).
    max_approach_rad : float
        Largest distance allowed (rad).
    joint_names : sequence of str, shape (n,)

    Raises
    ------
    BringUpError
        Naming the joint, both angles and the bound.
    """
    distance = np.abs(np.asarray(present_rad, float) - np.asarray(first_rad, float))
    j = int(np.argmax(distance))
    if not distance[j] <= max_approach_rad:
        raise BringUpError(
            f"{joint_names[j]} is at {math.degrees(present_rad[j]):.1f} deg, "
            f"{math.degrees(distance[j]):.1f} deg from the plan's first frame "
            f"({math.degrees(first_rad[j]):.1f} deg); more than the "
            f"{math.degrees(max_approach_rad):.1f} deg allowed: move it closer, or raise the "
            "bound (--max-approach) if that reading is right; refusing to start"
        )


def check_plan(
    installed: Sequence[Installed],
    joints: JointMap,
    trajectory,
    *,
    joint_names: Sequence[str] | None = None,
    set_limits: Mapping[int, tuple[int, int]] | None = None,
    max_approach_rad: float = MAX_APPROACH_RAD,
) -> tuple[tuple[int, ...], np.ndarray]:
    """Check a plan against the servos as found; choose each servo's operating mode.

    Parameters
    ----------
    installed : sequence of Installed, shape (n,)
        From ``inspect``.
    joints : JointMap
    trajectory : JointTrajectory (or object with ``t`` (M,) and ``q`` (M, n)), or JointRange
        The plan: times (s) and joint angles (rad), the first row the first
        frame; or, for an online stream, its first frame and range.
    joint_names : sequence of str, optional
        For messages (default pan, tilt, roll).
    set_limits : mapping of int to (int, int), optional
        Servo id -> (min, max) Position Limit (ticks) the caller will write.
    max_approach_rad : float, optional
        Largest distance (rad) of any joint from the plan's first frame.

    Returns
    -------
    operating_modes : tuple of int, shape (n,)
        3 or 4 per servo.
    limits_ticks : ndarray of int64, shape (n, 2)
        The Min / Max Position Limit each servo will hold.

    Raises
    ------
    BringUpError
        If a servo's Drive Mode selects the time-based profile, a servo reads
        a position outside its limits, a joint's plan leaves its position
        limits (or needs more than one turn where limits are installed), or a
        joint starts too far from the first frame.
    """
    names = joint_names_for(joints, joint_names)
    set_limits = dict(set_limits or {})
    q, when = _plan_rows(trajectory)
    ticks = joints.to_ticks(q)
    modes, limits = [], []
    for j, servo in enumerate(installed):
        if servo.drive_mode & DRIVE_MODE_TIME_BASED:
            raise BringUpError(
                f"servo {servo.servo_id} ({names[j]}): Drive Mode {servo.drive_mode:#04x} selects "
                "the time-based profile, which re-plans every streamed goal; clear bit 2 "
                "(e.g. in Dynamixel Wizard); trajgen never writes Drive Mode; refusing to stream"
            )
        low, high = set_limits.get(servo.servo_id, (servo.min_limit, servo.max_limit))
        mode = operating_mode_for(ticks[:, j])
        if mode == EXTENDED_POSITION_MODE and (low, high) != FACTORY_LIMITS:
            # The servo ignores its limits in extended position mode: refuse rather
            # than drop the protection whoever installed them wanted.
            raise BringUpError(
                f"{names[j]} needs more than one turn (ticks {ticks[:, j].min()}..."
                f"{ticks[:, j].max()}, extended position mode, where the servo ignores its "
                f"position limits) but servo {servo.servo_id} has limits {low}..{high} "
                "installed; refusing to stream"
            )
        if mode == POSITION_MODE:
            if not low <= servo.present <= high:
                raise BringUpError(
                    f"servo {servo.servo_id} ({names[j]}) reads Present Position "
                    f"{servo.present} ({_deg(joints, j, servo.present)}), outside its position "
                    f"limits {low}..{high}; move it inside by hand (torque off); refusing to stream"
                )
            outside = np.flatnonzero((ticks[:, j] < low) | (ticks[:, j] > high))
            if len(outside):
                k = outside[0]
                goal = ticks[k, j]
                which, limit = ("Min", low) if goal < low else ("Max", high)
                raise BringUpError(
                    f"{names[j]} leaves its position limits {when(k)}: "
                    f"{math.degrees(q[k, j]):.1f} deg (tick {goal}) is past the {which} Position "
                    f"Limit {limit} ({_deg(joints, j, limit)}) of servo {servo.servo_id}; "
                    "change the plan, or change the limits with --set-limits; refusing to stream"
                )
        modes.append(mode)
        limits.append((low, high))
    present = joints.to_rad(np.array([s.present for s in installed]))
    check_start(present, q[0], max_approach_rad, names)
    return tuple(modes), np.array(limits, dtype=np.int64)


def configure(
    bus: ServoBus,
    joints: JointMap,
    installed: Sequence[Installed],
    *,
    operating_modes: Sequence[int],
    watchdog_s: float | None,
    set_limits: Mapping[int, tuple[int, int]] | None = None,
) -> None:
    """Write the streaming configuration (torque stays as it was; see ``bring_up``).

    Parameters
    ----------
    bus : ServoBus
        Open bus whose servos ``check_servos`` declared.
    joints : JointMap
    installed : sequence of Installed, shape (n,)
        From ``inspect``: EEPROM registers are written (torque off first) only
        where they must change.
    operating_modes : sequence of int, shape (n,)
        3 (position) or 4 (extended position) per servo.
    watchdog_s : float or None
        Checked here (the watchdog itself is set after torque on).
    set_limits : mapping of int to (int, int), optional
        Servo id -> (min, max) Position Limit (ticks) to write.

    Raises
    ------
    ValueError
        If an operating mode is not 3 or 4, or ``watchdog_s`` is out of range.
    ServoError
        If a servo reports a hardware error or refuses a write.
    CommError
        If a servo stops answering.
    """
    if any(m not in (POSITION_MODE, EXTENDED_POSITION_MODE) for m in operating_modes):
        raise ValueError(f"Expected `operating_modes` of 3 or 4, got {tuple(operating_modes)}.")
    if watchdog_s is not None:
        watchdog_units(watchdog_s)
    set_limits = dict(set_limits or {})
    for servo, mode in zip(installed, operating_modes, strict=True):
        servo_id = servo.servo_id
        limits = set_limits.get(servo_id)
        eeprom = {}
        if bus.read(servo_id, Register.RETURN_DELAY_TIME) != 0:
            eeprom[Register.RETURN_DELAY_TIME] = 0
        if servo.operating_mode != mode:
            eeprom[Register.OPERATING_MODE] = mode
        if limits is not None and limits != (servo.min_limit, servo.max_limit):
            eeprom[Register.MIN_POSITION_LIMIT], eeprom[Register.MAX_POSITION_LIMIT] = limits
        if eeprom and servo.torque_on:
            bus.write(servo_id, Register.TORQUE_ENABLE, 0)  # EEPROM is locked while torque is on
        for register, value in eeprom.items():
            bus.write(servo_id, register, value)
        bus.write(servo_id, Register.PROFILE_ACCELERATION, 0)
        bus.write(servo_id, Register.PROFILE_VELOCITY, 0)
        bus.write(servo_id, Register.BUS_WATCHDOG, 0)  # clears a tripped watchdog


def bring_up(
    bus: ServoBus,
    joints: JointMap,
    models: Sequence[Model | str],
    plan,
    *,
    watchdog_s: float | None = 0.1,
    joint_names: Sequence[str] | None = None,
    set_limits: Mapping[int, tuple[int, int]] | None = None,
    max_approach_rad: float = MAX_APPROACH_RAD,
) -> BringUp:
    """Check every servo and the plan, then configure the servos and turn torque on.

    Parameters
    ----------
    bus : ServoBus
        An open bus.
    joints : JointMap
    models : sequence of Model or str, shape (n,)
        Expected model per joint.
    plan : JointTrajectory or JointRange, or callable
        The plan (``t`` (M,) in s, ``q`` (M, n) in rad; or an online stream's
        ``JointRange``), or a function of the present joint angles (rad, shape
        (n,)) returning it: a session plans from where the servos are, so pan
        and roll take the nearest turn.
    watchdog_s : float or None, optional
        Bus Watchdog period (s); None leaves it off.
    joint_names : sequence of str, optional
        For messages (default pan, tilt, roll).
    set_limits : mapping of int to (int, int), optional
        Servo id -> (min, max) Position Limit (ticks), 0 <= min < max <= 4095,
        to write; the user's explicit choice. Without it, limits are only read.
    max_approach_rad : float, optional
        Largest distance (rad) of any joint from the plan's first frame.

    Returns
    -------
    BringUp

    Raises
    ------
    ValueError
        If ``set_limits`` is out of range.
    BringUpError
        If a servo is missing or of the wrong model, or the plan does not fit
        what is installed (nothing was changed on any servo).
    ServoError
        If a servo is in hardware error (nothing changed) or refuses a write.
    CommError
        If a servo stops answering or its replies are not sound.
    """
    for servo_id, (low, high) in (set_limits or {}).items():
        if servo_id not in joints.ids or not 0 <= low < high <= TICKS_PER_REV - 1:
            raise ValueError(
                f"Expected `set_limits` of servos {joints.ids} with 0 <= min < max <= 4095, "
                f"got {servo_id}: ({low}, {high})."
            )
    names = joint_names_for(joints, joint_names)
    check_servos(bus, joints, models)
    installed = inspect(bus, joints)
    if callable(plan):
        plan = plan(joints.to_rad(np.array([s.present for s in installed])))
    modes, limits = check_plan(
        installed,
        joints,
        plan,
        joint_names=names,
        set_limits=set_limits,
        max_approach_rad=max_approach_rad,
    )
    # Every servo checked, the plan fits: from here on, servos are changed.
    configure(
        bus, joints, installed, operating_modes=modes, watchdog_s=watchdog_s, set_limits=set_limits
    )
    present = np.array([bus.read(i, Register.PRESENT_POSITION) for i in joints.ids])
    for j, (mode, (low, high)) in enumerate(zip(modes, limits, strict=True)):
        if mode == POSITION_MODE and not low <= present[j] <= high:
            raise BringUpError(
                f"servo {joints.ids[j]} ({names[j]}) reads Present Position {present[j]}, "
                f"outside its limits {low}..{high}; torque stays off; refusing to stream"
            )
    check_start(joints.to_rad(present), _plan_rows(plan)[0][0], max_approach_rad, names)
    for servo_id, ticks in zip(joints.ids, present.tolist(), strict=True):
        # Goal Position = present position first, so torque on does not jump.
        bus.write(servo_id, Register.GOAL_POSITION, ticks)
        bus.write(servo_id, Register.TORQUE_ENABLE, 1)
    if watchdog_s is not None:
        for servo_id in joints.ids:
            bus.write(servo_id, Register.BUS_WATCHDOG, watchdog_units(watchdog_s))
    return BringUp(installed, modes, limits, present.astype(np.int64), plan)
