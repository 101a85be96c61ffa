"""The state each servo was left in, read back after a stream or a failed bring-up.

Never a blanket "the servos hold their last goal": after the safe stop each
servo is asked (one try) for Torque Enable and Goal Position, and what it
answers is put beside what the driver did to it (``ServoBus.torque_written`` and ``driven``).
A servo that does not answer is "unknown", with the likely cause where the
evidence points to one (it answers ping but no read: Status Return Level 0;
its replies are garbled: two servos on one id).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from trajgen.drivers.bringup import joint_names_for
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.control_table import Register
from trajgen.drivers.errors import CommError, DriverError
from trajgen.drivers.units import RAD_PER_TICK, JointMap

State = Literal["holding", "released", "never torqued", "untouched", "off by itself", "unknown"]


@dataclass(frozen=True)
class ServoOutcome:
    """What one servo was doing when the driver let go of the bus.

    Attributes
    ----------
    servo_id : int
    joint : str
    state : {"holding", "released", "never torqued", "untouched", "off by itself", "unknown"}
        holding: torque on, holding ``goal_rad`` (the driver sent it goals or
        torqued it); released: torque off, turned
        off by the driver; never torqued: torque off, as found; untouched:
        torque on as found, the driver never changed it; off by itself: torque
        off although the driver turned it on or sent it goals (a reboot, a
        power loss, a shutdown); unknown: no reply.
    goal_rad : float
        The Goal Position held (joint angle, rad), NaN unless holding.
    detail : str
        The cause, where known (a hardware error, a silent servo's likely cause).
    """

    servo_id: int
    joint: str
    state: State
    goal_rad: float = math.nan
    detail: str = ""

    def format(self) -> str:
        """One line: ``"pan (servo 1): torque on, holding 12.3 deg"``."""
        text = {
            "holding": f"torque on, holding its goal {math.degrees(self.goal_rad):.1f} deg",
            "released": "released (torque off)",
            "never torqued": "never torqued (torque off, as found)",
            "untouched": "torque on as found, never changed",
            "off by itself": "torque off by itself (it rebooted, lost power or shut down)",
            "unknown": "unknown: no reply",
        }[self.state]
        return f"{self.joint} (servo {self.servo_id}): {text}" + (
            f"; {self.detail}" if self.detail else ""
        )

    def to_json_dict(self) -> dict:
        """Plain values for JSON (degrees and radians named in the keys; NaN as None)."""
        held = not math.isnan(self.goal_rad)
        return {
            "servo": self.servo_id,
            "state": self.state,
            "goal_rad": self.goal_rad if held else None,
            "goal_deg": math.degrees(self.goal_rad) if held else None,
            "detail": self.detail,
        }


def silence_cause(bus: ServoBus, servo_id: int, error: Exception) -> str:
    """The likely cause of a servo's silence, from what evidence there is ('' if none).

    Pings it once: a servo that answers ping but not reads or writes has
    Status Return Level 0 (it answers ping only); garbled replies are what two
    servos answering one id look like.
    """
    text = str(error)
    if "Incorrect status packet" in text or "corrupt" in text:
        return (
            f"its replies are garbled ({text}): two servos may share id {servo_id} (connect them "
            "one at a time to check)"
        )
    try:
        bus.ping(servo_id)
    except DriverError:
        return f"no reply to ping either (unplugged, unpowered, or another id or baud): {text}"
    return (
        f"it answers ping but not reads: its Status Return Level (register 68) is probably 0; "
        f"{text}"
    )


def servo_outcomes(
    bus: ServoBus, joints: JointMap, joint_names: Sequence[str] | None = None
) -> tuple[ServoOutcome, ...]:
    """Ask every servo what state it is in, one try each; never raises a ``DriverError``.

    Parameters
    ----------
    bus : ServoBus
        The bus, still open, after the safe stop (its ``torque_written`` says
        what the driver did to each servo's torque).
    joints : JointMap
    joint_names : sequence of str, optional

    Returns
    -------
    tuple of ServoOutcome, shape (n,)
    """
    names = joint_names_for(joints, joint_names)
    out = []
    retries, bus.retries = bus.retries, 0
    try:
        for j, servo_id in enumerate(joints.ids):
            written = bus.torque_written.get(servo_id)
            driven = servo_id in bus.driven
            if not bus.is_open or servo_id not in bus.models:
                state = "never torqued" if written is None else "unknown"
                detail = "" if written is None else "the port is closed"
                out.append(ServoOutcome(servo_id, names[j], state, detail=detail))
                continue
            try:
                torque = bus.read(servo_id, Register.TORQUE_ENABLE)
                goal = bus.read(servo_id, Register.GOAL_POSITION) if torque else None
            except CommError as e:
                detail = silence_cause(bus, servo_id, e)
                out.append(ServoOutcome(servo_id, names[j], "unknown", detail=detail))
                continue
            except DriverError as e:  # it answers, with an error (a hardware error)
                detail = str(e)
                out.append(ServoOutcome(servo_id, names[j], "unknown", detail=detail))
                continue
            if torque:
                state = "holding" if driven or written is not None else "untouched"
                goal_rad = joints.directions[j] * (goal - joints.zeros[j]) * RAD_PER_TICK
                out.append(ServoOutcome(servo_id, names[j], state, goal_rad))
            elif written is None and not driven:
                out.append(ServoOutcome(servo_id, names[j], "never torqued"))
            elif written == 0:
                out.append(ServoOutcome(servo_id, names[j], "released"))
            else:
                out.append(ServoOutcome(servo_id, names[j], "off by itself"))
    finally:
        bus.retries = retries
    return tuple(out)
