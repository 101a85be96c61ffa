"""Bring-up: check the servos on the bus, say what would change, then configure them.

Nothing is changed on any servo until every servo has been checked
(``inspect``), the plan checked against what is installed (``check_plan``)
and every change listed (``plan_changes``):

1. ping every id and check its model number against the configuration (a
   servo that answers ping but no read is named, with Status Return Level 0
   as the likely cause);
2. read, from every servo, Hardware Error Status (a latched error refuses the
   whole bus), Torque Enable, Drive Mode, Operating Mode, Secondary ID, Status
   Return Level, Return Delay Time, the profile, Max / Min Position Limit,
   voltage and temperature with their limits, and Present Position (read
   until two reads agree within what the servo could have moved between
   them: one glitched reply never becomes a goal);
3. refuse Drive Mode bit 2 (time-based profile), a Status Return Level below 2
   (writes would go unacknowledged), a Secondary ID equal to another streamed
   servo's id (that servo would execute every write meant for the other), a
   supply or temperature at the servo's own limits, a plan that leaves a
   joint's installed position limits, or that starts far from where the
   servos are. Drive Mode bit 0 (reverse) is kept: directions are a mapping
   in the keyframe file;
4. list the changes (``Change``): the profile to 0 and the Bus Watchdog (RAM,
   always: the stream is the profile); Operating Mode where the servo's mode
   cannot stream the plan, Return Delay Time 0 (EEPROM, only with
   ``configure=True``; without it a needed mode change is a refusal naming the
   servo, the register and the value, and Return Delay Time is kept with a
   warning); ``set_limits`` where given (the user's explicit option). Every
   change is said (``RuntimeWarning``) before it is made.

then (``configure``), servo by servo: a servo with torque on that is far
from its goal (a profile in progress) stops where it is first (before its
profile is set to 0, which would make the rest of its move a step); a servo
whose EEPROM must change and
whose torque is on is released only when it is not holding a load (Present
Current under ``LOADED_FRACTION`` of its stall current; else bring-up
refuses before any write), with a warning, and torque goes back on at once
at its position; a change of Operating Mode keeps the servo's gains (the
servo resets them: they are written back). Last, for every servo: a servo
holding torque keeps its Goal Position (checked against its position); the
others get Goal Position = their checked position, then torque on; then the
Bus Watchdog. ``restore_settings`` writes back what was changed, on exit.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from trajgen.drivers.bus import ServoBus
from trajgen.drivers.control_table import (
    CURRENT_BASED_POSITION_MODE,
    EEPROM_END,
    EXTENDED_POSITION_MODE,
    MODE_RESETS,
    OPERATING_MODE_NAMES,
    POSITION_MODE,
    RETURN_DELAY_UNIT_S,
    SECONDARY_ID_OFF,
    VOLTAGE_UNIT_V,
    WATCHDOG_UNIT_S,
    Model,
    Register,
    layout,
    model_named,
    model_numbered,
)
from trajgen.drivers.errors import BringUpError, CommError, DriverError
from trajgen.drivers.health import PowerLimits, health_problem
from trajgen.drivers.units import RAD_PER_TICK, TICKS_PER_REV, JointMap
from trajgen.gimbal import JOINT_NAMES
from trajgen.lift import sent_goals

from .errors import BadArgument

#: Drive Mode bits (e-Manual, "Drive Mode (10)").
DRIVE_MODE_REVERSE = 0x01
DRIVE_MODE_TIME_BASED = 0x04

#: Default largest distance (rad) of any joint from the plan's first frame at start.
MAX_APPROACH_RAD = math.radians(45.0)

#: Position limits as they leave the factory (the full single turn).
FACTORY_LIMITS = (0, TICKS_PER_REV - 1)

#: Operating Modes a position stream can run in as installed (the goal is Goal
#: Position; 4 and 5 take any goal in +-256 turns).
STREAMABLE_MODES = (POSITION_MODE, EXTENDED_POSITION_MODE, CURRENT_BASED_POSITION_MODE)
_MULTI_TURN_MODES = (EXTENDED_POSITION_MODE, CURRENT_BASED_POSITION_MODE)

#: A servo with torque on draws more than this fraction of its stall current
#: when it holds a load (gravity, a spring): bring-up never releases it.
LOADED_FRACTION = 0.05

#: Reading noise (ticks) allowed between two Present Position reads of a servo
#: at rest, on top of what its no-load speed allows in the time between them.
POSITION_NOISE_TICKS = 4

#: Largest distance (ticks, 5 deg) between a servo's Present Position and the
#: Goal Position it holds with torque on (a loaded servo lags its goal a little).
HOLD_TOLERANCE_TICKS = round(math.radians(5.0) / RAD_PER_TICK)

# Status Return Level (68) at which every instruction is answered.
_ANSWER_ALL = 2


def watchdog_units(watchdog_s: float) -> int:
    """Bus Watchdog register value (20 ms units, 1..127) for ``watchdog_s``.

    Raises
    ------
    ValueError
        If ``watchdog_s`` is outside 0.02..2.54 s.
    """
    units = math.ceil(watchdog_s / WATCHDOG_UNIT_S - 1e-9)
    if not 1 <= units <= 127:
        raise BadArgument(f"Expected `watchdog_s` in 0.02..2.54 s, got {watchdog_s}.")
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


def mode_name(mode: int) -> str:
    """``"1 (velocity control)"``: an Operating Mode value with its meaning."""
    return f"{mode} ({OPERATING_MODE_NAMES.get(mode, 'unknown mode')})"


def joint_names_for(joints: JointMap, joint_names: Sequence[str] | None = None) -> tuple[str, ...]:
    """Names for messages: ``joint_names``, else pan, tilt, roll for 3 joints, else joint k."""
    if joint_names is not None:
        if len(joint_names) != len(joints):
            raise BadArgument(f"Expected {len(joints)} `joint_names`, got {len(joint_names)}.")
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
        Present Position (132), ticks: two reads that agree.
    return_delay : int
        Return Delay Time (9), 2 us units.
    secondary_id : int
        Secondary ID (12); 253..255 is off.
    status_return_level : int
        Status Return Level (68): 2 answers every instruction.
    profile_acceleration, profile_velocity : int
        Profile Acceleration / Velocity (108 / 112).
    bus_watchdog : int
        Bus Watchdog (98).
    current_a : float
        Present Current (126), A, of a torque-on servo (what it holds); 0 with
        torque off.
    power_limits : PowerLimits or None
        Its voltage and temperature limits.
    voltage_v, temperature_c : float
        Present Input Voltage (144, V) and Present Temperature (146, deg C).
    """

    servo_id: int
    torque_on: bool
    drive_mode: int
    operating_mode: int
    min_limit: int
    max_limit: int
    present: int
    return_delay: int = 0
    secondary_id: int = SECONDARY_ID_OFF
    status_return_level: int = _ANSWER_ALL
    profile_acceleration: int = 0
    profile_velocity: int = 0
    bus_watchdog: int = 0
    current_a: float = 0.0
    power_limits: PowerLimits | None = None
    voltage_v: float = math.nan
    temperature_c: float = math.nan

    @property
    def factory_limits(self) -> bool:
        """Whether the limits are the factory 0..4095 (nobody restricted this joint)."""
        return (self.min_limit, self.max_limit) == FACTORY_LIMITS


@dataclass(frozen=True)
class Change:
    """One register bring-up changes on one servo, and why.

    Attributes
    ----------
    servo_id : int
    joint : str
    register : Register
    old, new : int
        The value found and the value written.
    why : str
        Why streaming needs it (for messages).
    eeprom : bool
        Whether the register is in EEPROM (written only with torque off, kept
        across power cycles).
    """

    servo_id: int
    joint: str
    register: Register
    old: int
    new: int
    why: str
    eeprom: bool

    def describe(self) -> str:
        """``"servo 1 (pan): Operating Mode 1 -> 3 (EEPROM): why"``."""
        area = "EEPROM" if self.eeprom else "RAM"
        return (
            f"servo {self.servo_id} ({self.joint}): {self.register.value} {self.old} -> "
            f"{self.new} ({area}): {self.why}"
        )


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
    # The goals that will be sent (led ahead of the plan, trajgen.lead; the lift before
    # it, trajgen.lift), not only the plan.
    t, goals = sent_goals(plan)
    return goals, lambda k: f"at t = {t[k]:.3f} s"


@dataclass(frozen=True)
class BringUp:
    """What bring-up found and set.

    Attributes
    ----------
    installed : tuple of Installed, shape (n,)
        Each servo as found, in joint order.
    operating_modes : tuple of int, shape (n,)
        Operating Mode streamed in per servo (3, 4 or 5).
    limits_ticks : ndarray of int64, shape (n, 2)
        Min and Max Position Limit per servo after bring-up (ticks).
    present_ticks : ndarray of int64, shape (n,)
        The Goal Position each servo holds at torque on: its checked position
        (or, for a servo found holding torque, the goal it held). The stream
        starts from it.
    trajectory : object
        The plan the checks were made against (a trajectory, or a ``JointRange``).
    changes : tuple of Change
        Every register written, with the value found (for ``restore_settings``).
    kept : tuple of str
        Settings a change was advised for but not made (no ``configure``).
    """

    installed: tuple[Installed, ...]
    operating_modes: tuple[int, ...]
    limits_ticks: np.ndarray
    present_ticks: np.ndarray
    trajectory: object
    changes: tuple[Change, ...] = ()
    kept: tuple[str, ...] = ()

    @property
    def goal_bounds_ticks(self) -> np.ndarray:
        """Lowest and highest goal (ticks) per servo, shape (n, 2), for ``Streamer``.

        The position limits, except for a servo in a multi-turn mode with the
        factory limits: the register's whole range (see ``check_plan``).
        """
        bounds = self.limits_ticks.copy()
        factory = np.all(bounds == FACTORY_LIMITS, axis=1)
        multi = np.isin(np.array(self.operating_modes), _MULTI_TURN_MODES) & factory
        bounds[multi] = (-(2**31), 2**31 - 1)
        return bounds

    @property
    def power_limits(self) -> tuple[PowerLimits | None, ...]:
        """Each servo's voltage and temperature limits, in joint order."""
        return tuple(s.power_limits for s in self.installed)


def check_servos(bus: ServoBus, joints: JointMap, models: Sequence[Model | str]) -> None:
    """Ping every servo, check its model, and declare it to the bus.

    Raises
    ------
    BringUpError
        If a servo does not answer or is another model.
    """
    if len(models) != len(joints):
        raise BadArgument(f"Expected {len(joints)} `models`, got {len(models)}.")
    for servo_id, model in zip(joints.ids, models, strict=True):
        model = model_named(model) if isinstance(model, str) else model
        try:
            number = bus.ping(servo_id)
        except CommError as e:
            raise BringUpError(
                f"servo {servo_id}: no reply to ping at {bus.baud} baud on {bus.port_name} "
                f"(check id, baud rate, power{_shared_id_hint(e)}): {e}"
            ) from e
        if number != model.number:
            found = model_numbered(number)
            name = found.name if isinstance(found, Model) else found
            raise BringUpError(
                f"servo {servo_id}: model number {number} ({name}), expected {model.number} "
                f"({model.name}); refusing to stream"
            )
        bus.add_servo(servo_id, model)


def _shared_id_hint(error: CommError) -> str:
    """A hint when replies arrive but are garbled: what two servos on one id look like."""
    text = str(error)
    if "Incorrect status packet" in text or "corrupt" in text or "CRC" in text:
        return (
            "; replies arrive but are garbled on every try, as when two servos share this "
            "id and answer at once: connect them one at a time to check"
        )
    return ""


def read_position_checked(bus: ServoBus, servo_id: int, *, tries: int = 4) -> int:
    """Present Position (ticks) from two consecutive reads that agree.

    Two reads agree when they differ by less than the servo could move
    between them (its no-load speed times the time between the reads) plus
    ``POSITION_NOISE_TICKS``: one glitched reply is never used.

    Raises
    ------
    BringUpError
        If no two consecutive reads of ``tries`` agree.
    CommError, ServoError
        If a read fails.
    """
    speed_ticks_s = bus.models[servo_id].no_load_speed_rad_s / RAD_PER_TICK
    reads = [(time.monotonic(), bus.read(servo_id, Register.PRESENT_POSITION))]
    for _ in range(tries - 1):
        reads.append((time.monotonic(), bus.read(servo_id, Register.PRESENT_POSITION)))
        (t0, a), (t1, b) = reads[-2:]
        if abs(b - a) <= speed_ticks_s * (t1 - t0) + POSITION_NOISE_TICKS:
            return b
    values = ", ".join(str(v) for _, v in reads)
    raise BringUpError(
        f"servo {servo_id}: Present Position reads {values}: no two reads in a row agree "
        "(a glitching encoder or a noisy bus); refusing to use it as a goal"
    )


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
    BringUpError
        If a servo answers ping but no read (Status Return Level 0), or its
        position reads do not agree.
    CommError
        If a servo stops answering or its replies are not sound.
    """
    found = []
    for servo_id in joints.ids:
        try:
            bus.read(servo_id, Register.HARDWARE_ERROR_STATUS)  # raises on the Alert bit
        except CommError as e:
            hint = _shared_id_hint(e)
            if hint:
                raise BringUpError(f"servo {servo_id}: {e}{hint}; refusing to stream") from e
            raise BringUpError(
                f"servo {servo_id} answers ping but not a read ({e}): its Status Return Level "
                "(register 68) is probably 0 (it then answers ping only); set it to 2, e.g. "
                "in Dynamixel Wizard (trajgen never writes it); refusing to stream"
            ) from e
        try:
            found.append(_installed(bus, servo_id))
        except CommError as e:
            hint = _shared_id_hint(e)
            if not hint:
                raise
            raise BringUpError(f"servo {servo_id}: {e}{hint}; refusing to stream") from e
    return tuple(found)


def _installed(bus: ServoBus, servo_id: int) -> Installed:
    """One servo's ``Installed`` (see ``inspect``)."""
    model = bus.models[servo_id]

    def read(register):
        return bus.read(servo_id, register)

    torque_on = read(Register.TORQUE_ENABLE) == 1
    return Installed(
        servo_id=servo_id,
        torque_on=torque_on,
        drive_mode=read(Register.DRIVE_MODE),
        operating_mode=read(Register.OPERATING_MODE),
        min_limit=read(Register.MIN_POSITION_LIMIT),
        max_limit=read(Register.MAX_POSITION_LIMIT),
        present=read_position_checked(bus, servo_id),
        return_delay=read(Register.RETURN_DELAY_TIME),
        secondary_id=read(Register.SECONDARY_ID),
        status_return_level=read(Register.STATUS_RETURN_LEVEL),
        profile_acceleration=read(Register.PROFILE_ACCELERATION),
        profile_velocity=read(Register.PROFILE_VELOCITY),
        bus_watchdog=read(Register.BUS_WATCHDOG),
        # What it holds: read only where torque is on (else no load on it).
        current_a=model.current_a(read(Register.PRESENT_CURRENT)) if torque_on else 0.0,
        power_limits=PowerLimits.from_registers(
            read(Register.MIN_VOLTAGE_LIMIT),
            read(Register.MAX_VOLTAGE_LIMIT),
            read(Register.TEMPERATURE_LIMIT),
        ),
        voltage_v=read(Register.PRESENT_INPUT_VOLTAGE) * VOLTAGE_UNIT_V,
        temperature_c=float(read(Register.PRESENT_TEMPERATURE)),
    )


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


def check_servo_settings(
    installed: Sequence[Installed], joints: JointMap, joint_names: Sequence[str] | None = None
) -> None:
    """Refuse settings no stream can run with: Status Return Level, Secondary ID, power.

    Raises
    ------
    BringUpError
        If a servo does not acknowledge writes (Status Return Level < 2), has
        a Secondary ID that is another streamed servo's id, or its supply or
        temperature is at its own limits.
    """
    names = joint_names_for(joints, joint_names)
    by_id = dict(zip(joints.ids, names, strict=True))
    for j, servo in enumerate(installed):
        who = f"servo {servo.servo_id} ({names[j]})"
        if servo.status_return_level < _ANSWER_ALL:
            raise BringUpError(
                f"{who}: Status Return Level (register 68) is {servo.status_return_level}: it "
                "does not acknowledge writes, so no write could be checked; set it to 2, e.g. "
                "in Dynamixel Wizard (trajgen never writes it); refusing to stream"
            )
        other = servo.secondary_id
        if other in by_id and other != servo.servo_id:
            raise BringUpError(
                f"{who}: Secondary ID (register 12) is {other}, the id of servo {other} "
                f"({by_id[other]}): it would execute every write meant for servo {other}; set "
                f"its Secondary ID to {SECONDARY_ID_OFF} (off), e.g. in Dynamixel Wizard; "
                "refusing to stream"
            )
        if servo.power_limits is not None:
            problem = health_problem(who, servo.power_limits, servo.voltage_v, servo.temperature_c)
            if problem is not None and problem[0] == "stop":
                raise BringUpError(f"{problem[1]}; refusing to stream")
            if problem is not None:
                warnings.warn(problem[1], RuntimeWarning, stacklevel=3)


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

    A servo streams in the mode it is in where that mode can stream the plan
    (3 for a plan within one turn; 4 or 5 for any); else the mode it needs
    (3, or 4 for more than one turn), which ``plan_changes`` turns into a
    change (or a refusal without ``configure``).

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
        3, 4 or 5 per servo.
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
        needed = operating_mode_for(ticks[:, j])
        mode = servo.operating_mode
        if mode not in STREAMABLE_MODES or (mode == POSITION_MODE and needed != POSITION_MODE):
            mode = needed
        if mode in _MULTI_TURN_MODES and needed != POSITION_MODE and (low, high) != FACTORY_LIMITS:
            # The servo ignores its limits in a multi-turn mode: refuse rather
            # than drop the protection whoever installed them wanted.
            raise BringUpError(
                f"{names[j]} needs more than one turn (ticks {ticks[:, j].min()}..."
                f"{ticks[:, j].max()}, extended position mode, where the servo ignores its "
                f"position limits) but servo {servo.servo_id} has limits {low}..{high} "
                "installed; refusing to stream"
            )
        if mode == POSITION_MODE or (low, high) != FACTORY_LIMITS:
            # Position Mode enforces the limits; installed ones guard a multi-turn
            # mode too (in software: the servo itself ignores them there).
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


def _is_eeprom(bus: ServoBus, servo_id: int, register: Register) -> bool:
    return layout(bus.models[servo_id])[register][0] < EEPROM_END


def plan_changes(
    bus: ServoBus,
    joints: JointMap,
    installed: Sequence[Installed],
    operating_modes: Sequence[int],
    *,
    configure: bool = False,
    set_limits: Mapping[int, tuple[int, int]] | None = None,
    joint_names: Sequence[str] | None = None,
) -> tuple[list[Change], list[str]]:
    """Every register bring-up would write, and the advised changes it will not make.

    Parameters
    ----------
    bus : ServoBus
        The bus whose servos ``check_servos`` declared (for register areas).
    joints : JointMap
    installed : sequence of Installed, shape (n,)
    operating_modes : sequence of int, shape (n,)
        From ``check_plan``.
    configure : bool, optional
        Whether EEPROM settings may be changed (the user asked for it).
    set_limits : mapping of int to (int, int), optional
        Position limits the user asked for (written whatever ``configure``).
    joint_names : sequence of str, optional

    Returns
    -------
    changes : list of Change
    kept : list of str
        Messages for the advised EEPROM changes not made (Return Delay Time).

    Raises
    ------
    BringUpError
        Without ``configure``, if a servo's Operating Mode cannot stream the
        plan (naming the servo, the register and the value); with it, if a
        servo that must be released for an EEPROM write holds a load.
    """
    names = joint_names_for(joints, joint_names)
    set_limits = dict(set_limits or {})
    changes: list[Change] = []
    kept: list[str] = []
    slow: list[str] = []  # Return Delay Time kept, per servo
    for j, (servo, mode) in enumerate(zip(installed, operating_modes, strict=True)):
        i, who = servo.servo_id, f"servo {servo.servo_id} ({names[j]})"

        def change(register, old, new, why, j=j, i=i):
            changes.append(
                Change(i, names[j], register, old, new, why, _is_eeprom(bus, i, register))
            )

        if servo.operating_mode != mode:
            why = (
                "the plan needs more than one turn"
                if mode == EXTENDED_POSITION_MODE
                else "a position stream needs a position mode"
            )
            if not configure:
                raise BringUpError(
                    f"{who}: Operating Mode (register 11) is {mode_name(servo.operating_mode)}, "
                    f"which cannot stream this plan ({why}: mode {mode_name(mode)}); trajgen "
                    "changes EEPROM only when asked: pass --configure (or [bus] configure = "
                    "true), or set the mode yourself; refusing to stream"
                )
            change(Register.OPERATING_MODE, servo.operating_mode, mode, why)
        limits = set_limits.get(i)
        if limits is not None and limits != (servo.min_limit, servo.max_limit):
            change(Register.MIN_POSITION_LIMIT, servo.min_limit, limits[0], "--set-limits")
            change(Register.MAX_POSITION_LIMIT, servo.max_limit, limits[1], "--set-limits")
        if servo.return_delay:
            if configure:
                why = f"every reply waits {_return_delay_us(servo)} us first; 0 answers at once"
                change(Register.RETURN_DELAY_TIME, servo.return_delay, 0, why)
            else:
                slow.append(f"{i}: {servo.return_delay} ({_return_delay_us(servo)} us)")
        for register, old in (
            (Register.PROFILE_ACCELERATION, servo.profile_acceleration),
            (Register.PROFILE_VELOCITY, servo.profile_velocity),
        ):
            if old:
                change(register, old, 0, "the stream is the profile: a servo profile lags it")
        if any(c.eeprom and c.servo_id == i for c in changes) and servo.torque_on:
            model = bus.models[i]
            if abs(servo.current_a) > LOADED_FRACTION * model.stall_current_a:
                mine = [c.register.value for c in changes if c.eeprom and c.servo_id == i]
                eeprom = ", ".join(mine)
                raise BringUpError(
                    f"{who} holds a load (torque on, Present Current {servo.current_a:.2f} A): "
                    f"writing {eeprom} (EEPROM) needs torque off, which would let it drop; "
                    "support the joint and turn its torque off first, or leave the setting as "
                    "it is; refusing to stream"
                )
    if slow:
        kept.append(
            f"Return Delay Time (register 9) kept on servo {', '.join(slow)}: every reply "
            "waits that long first (--configure sets 0: replies at once)"
        )
    return changes, kept


def _write_keeping_gains(bus: ServoBus, servo_id: int, register: Register, value: int) -> None:
    """Write ``register``; where it is Operating Mode, write back what the change resets."""
    if register is not Register.OPERATING_MODE:
        bus.write(servo_id, register, value)
        return
    kept = {r: bus.read(servo_id, r) for r in MODE_RESETS}
    bus.write(servo_id, register, value)
    for r, old in kept.items():
        if bus.read(servo_id, r) != old:
            bus.write(servo_id, r, old)


def configure(
    bus: ServoBus,
    joints: JointMap,
    installed: Sequence[Installed],
    *,
    operating_modes: Sequence[int],
    watchdog_s: float | None,
    set_limits: Mapping[int, tuple[int, int]] | None = None,
    changes: Sequence[Change] | None = None,
) -> None:
    """Write the streaming configuration (see ``bring_up``).

    Parameters
    ----------
    bus : ServoBus
        Open bus whose servos ``check_servos`` declared.
    joints : JointMap
    installed : sequence of Installed, shape (n,)
        From ``inspect``.
    operating_modes : sequence of int, shape (n,)
        3, 4 or 5 per servo.
    watchdog_s : float or None
        Checked here (the watchdog itself is set after torque on).
    set_limits : mapping of int to (int, int), optional
        Servo id -> (min, max) Position Limit (ticks) to write.
    changes : sequence of Change, optional
        From ``plan_changes`` (default: planned here with ``configure=True``).
        A servo with torque on whose EEPROM changes is released for the writes
        (said with a ``RuntimeWarning``) and torque goes back on at once.

    Raises
    ------
    ValueError
        If an operating mode is not 3, 4 or 5, or ``watchdog_s`` is out of range.
    ServoError
        If a servo reports a hardware error or refuses a write.
    CommError
        If a servo stops answering.
    """
    if any(m not in STREAMABLE_MODES for m in operating_modes):
        raise BadArgument(f"Expected `operating_modes` of 3, 4 or 5, got {tuple(operating_modes)}.")
    if watchdog_s is not None:
        watchdog_units(watchdog_s)
    if changes is None:
        changes, _ = plan_changes(
            bus, joints, installed, operating_modes, configure=True, set_limits=set_limits
        )
    for servo in installed:
        servo_id = servo.servo_id
        mine = [c for c in changes if c.servo_id == servo_id]
        if servo.torque_on:
            _stop_where_it_is(bus, servo_id)
        for c in mine:
            if not c.eeprom:
                bus.write(servo_id, c.register, c.new)
        eeprom = [c for c in mine if c.eeprom]
        if eeprom and servo.torque_on:
            warnings.warn(
                f"servo {servo_id} ({eeprom[0].joint}): torque off for the EEPROM write of "
                f"{', '.join(c.register.value for c in eeprom)} (it holds no load: Present "
                f"Current {servo.current_a:.2f} A); torque back on at once at its position",
                RuntimeWarning,
                stacklevel=3,
            )
            bus.write(servo_id, Register.TORQUE_ENABLE, 0)  # EEPROM is locked while torque is on
        for c in eeprom:
            _write_keeping_gains(bus, servo_id, c.register, c.new)
        if eeprom and servo.torque_on:
            try:
                after = read_position_checked(bus, servo_id)
            except BringUpError:  # moving (falling?): catch it where it is now
                after = bus.read(servo_id, Register.PRESENT_POSITION)
            bus.write(servo_id, Register.GOAL_POSITION, after)
            bus.write(servo_id, Register.TORQUE_ENABLE, 1)
            if abs(after - servo.present) > HOLD_TOLERANCE_TICKS:
                warnings.warn(
                    f"servo {servo_id} ({eeprom[0].joint}) moved {after - servo.present:+d} "
                    "ticks while released for the EEPROM write: it was holding more than its "
                    "current showed; it holds where it is now",
                    RuntimeWarning,
                    stacklevel=3,
                )
        bus.write(servo_id, Register.BUS_WATCHDOG, 0)  # clears a tripped watchdog


def _stop_where_it_is(bus: ServoBus, servo_id: int) -> None:
    """A torque-on servo far from its goal (a profile in progress) stops where it is.

    Written before the profile is set to 0, which would otherwise turn the
    rest of its move into a full-speed step.
    """
    present = read_position_checked(bus, servo_id)
    goal = bus.read(servo_id, Register.GOAL_POSITION)
    if abs(goal - present) > HOLD_TOLERANCE_TICKS:
        warnings.warn(
            f"servo {servo_id}: moving to Goal Position {goal} (a profile in progress, or "
            f"blocked) at {present}: stopped where it is (Goal Position {present}) before its "
            "profile is set to 0",
            RuntimeWarning,
            stacklevel=4,
        )
        bus.write(servo_id, Register.GOAL_POSITION, present)


#: ``configure`` under another name, for ``bring_up`` (whose flag is called configure).
_configure = configure


def start_goal(bus: ServoBus, servo_id: int, joint: str) -> tuple[int, bool]:
    """The Goal Position a servo will start the stream from, and whether to torque it on.

    A servo holding torque keeps the goal it holds (no step), once a position
    read agrees with that goal within ``HOLD_TOLERANCE_TICKS`` (up to 3 reads:
    it may still be settling); a servo with torque off starts from its checked
    position (``read_position_checked``).

    Raises
    ------
    BringUpError
        If a torque-on servo stays far from the goal it holds.
    """
    if bus.read(servo_id, Register.TORQUE_ENABLE) != 1:
        return read_position_checked(bus, servo_id), True
    goal = bus.read(servo_id, Register.GOAL_POSITION)
    reads = []
    for _ in range(3):
        reads.append(bus.read(servo_id, Register.PRESENT_POSITION))
        if abs(goal - reads[-1]) <= HOLD_TOLERANCE_TICKS:
            return goal, False
    raise BringUpError(
        f"servo {servo_id} ({joint}) holds Goal Position {goal} with torque on but reads "
        f"Present Position {', '.join(map(str, reads))}, more than {HOLD_TOLERANCE_TICKS} "
        "ticks away: it is blocked, overloaded or its encoder is glitching; refusing to stream"
    )


@dataclass
class BringUpLog:
    """What a bring-up has done so far (kept when it fails half way).

    Attributes
    ----------
    changes : list of Change
        Registers written so far, with the values found.
    """

    changes: list[Change] = field(default_factory=list)


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
    configure: bool = False,
    log: BringUpLog | None = None,
) -> BringUp:
    """Check every servo and the plan, say what changes, configure, and turn torque on.

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
    configure : bool, optional
        Let bring-up change EEPROM settings streaming needs (Operating Mode)
        or is advised (Return Delay Time 0). Without it, a needed change is a
        refusal and an advised one a warning.
    log : BringUpLog, optional
        Filled with the changes as they are made (for ``restore_settings``
        when bring-up fails half way).

    Returns
    -------
    BringUp

    Raises
    ------
    ValueError
        If ``set_limits`` is out of range.
    BringUpError
        If a servo is missing, of the wrong model, set up so it cannot stream,
        or the plan does not fit what is installed (nothing was changed).
    ServoError
        If a servo is in hardware error (nothing changed) or refuses a write.
    CommError
        If a servo stops answering or its replies are not sound.
    """
    for servo_id, (low, high) in (set_limits or {}).items():
        if servo_id not in joints.ids or not 0 <= low < high <= TICKS_PER_REV - 1:
            raise BadArgument(
                f"Expected `set_limits` of servos {joints.ids} with 0 <= min < max <= 4095, "
                f"got {servo_id}: ({low}, {high})."
            )
    names = joint_names_for(joints, joint_names)
    check_servos(bus, joints, models)
    installed = inspect(bus, joints)
    check_servo_settings(installed, joints, names)
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
    changes, kept = plan_changes(
        bus, joints, installed, modes, configure=configure, set_limits=set_limits, joint_names=names
    )
    for message in kept:
        warnings.warn(message, RuntimeWarning, stacklevel=2)
    for c in changes:
        warnings.warn(f"bring-up changes {c.describe()}", RuntimeWarning, stacklevel=2)
    # Every servo checked, the plan fits: from here on, servos are changed.
    if log is not None:
        log.changes.extend(changes)
    _configure(
        bus,
        joints,
        installed,
        operating_modes=modes,
        watchdog_s=watchdog_s,
        set_limits=set_limits,
        changes=changes,
    )
    start = []
    for j, servo_id in enumerate(joints.ids):
        goal, torque_on = start_goal(bus, servo_id, names[j])
        low, high = limits[j]
        if modes[j] == POSITION_MODE and not low <= goal <= high:
            raise BringUpError(
                f"servo {servo_id} ({names[j]}) reads Present Position {goal}, "
                f"outside its limits {low}..{high}; torque stays off; refusing to stream"
            )
        start.append((goal, torque_on))
    present = np.array([goal for goal, _ in start])
    check_start(joints.to_rad(present), _plan_rows(plan)[0][0], max_approach_rad, names)
    for servo_id, (goal, torque_on) in zip(joints.ids, start, strict=True):
        if torque_on:
            # Goal Position = the checked position first, so torque on does not jump.
            bus.write(servo_id, Register.GOAL_POSITION, goal)
            bus.write(servo_id, Register.TORQUE_ENABLE, 1)
    if watchdog_s is not None:
        units = watchdog_units(watchdog_s)
        for servo, servo_id, name in zip(installed, joints.ids, names, strict=True):
            if servo.bus_watchdog != units:
                c = Change(
                    servo_id,
                    name,
                    Register.BUS_WATCHDOG,
                    servo.bus_watchdog,
                    units,
                    "stops the servo when the host goes quiet",
                    False,
                )
                changes.append(c)
                if log is not None:
                    log.changes.append(c)
            bus.write(servo_id, Register.BUS_WATCHDOG, units)
    return BringUp(
        installed, modes, limits, present.astype(np.int64), plan, tuple(changes), tuple(kept)
    )


def restore_settings(bus: ServoBus, changes: Sequence[Change]) -> list[str]:
    """Write back the values bring-up found, in reverse order; best effort.

    RAM settings (profile, Bus Watchdog) are written back on every servo.
    EEPROM settings only on a servo whose torque is off now (EEPROM is locked
    while torque is on, and releasing a holding servo here could drop its
    load): stop with torque off (``on_stop="torque_off"``) to restore them.

    Parameters
    ----------
    bus : ServoBus
    changes : sequence of Change
        ``BringUp.changes`` (or a ``BringUpLog``'s).

    Returns
    -------
    list of str
        What was not restored, and why, per servo and register.
    """
    problems = []
    torque: dict[int, int | None] = {}
    for c in reversed(changes):
        where = f"servo {c.servo_id} ({c.joint}): {c.register.value} not restored to {c.old}"
        try:
            if c.eeprom:
                if c.servo_id not in torque:
                    torque[c.servo_id] = bus.read(c.servo_id, Register.TORQUE_ENABLE)
                if torque[c.servo_id] != 0:
                    problems.append(
                        f"{where} (left at {c.new}): EEPROM is written only with torque off, and "
                        "the servo holds its goal (stop with torque off to restore it)"
                    )
                    continue
            _write_keeping_gains(bus, c.servo_id, c.register, c.old)
        except DriverError as e:
            problems.append(f"{where}: {e}")
    return problems


def _return_delay_us(servo) -> int:
    """A servo's Return Delay Time as read, in us."""
    return round(servo.return_delay * RETURN_DELAY_UNIT_S * 1e6)
