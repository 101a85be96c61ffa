"""The simulator's domain errors: every one a :class:`SimError`.

Those that are bad input (a telemetry log that cannot be used) are also
``ValueError``s. ``FitError`` (``sim.fit``) and ``UnsupportedServoSetting``
(``sim.firmware``) are ``SimError``s defined beside their code.
"""

from __future__ import annotations

from trajgen.errors import BadArgument as _CoreBadArgument


class SimError(RuntimeError):
    """Base class of the simulator's domain failures."""


class BadArgument(SimError, _CoreBadArgument):
    """A simulator call's argument with a wrong value or shape; also a ``trajgen.BadArgument``."""


class IdentifyError(SimError, ValueError):
    """A telemetry log that cannot be used, or a missing ``mujoco[sysid]``."""


class SimulationError(SimError):
    """MuJoCo raised a warning or found a contact inside the gimbal during a run."""


class TorqueLimitExceeded(SimError):
    """A trajectory needs more torque than the servos' envelope allows.

    Attributes
    ----------
    report : sim.check.TorqueReport
        The full report; ``report.reasons`` says which joint failed and why.

    The message has one reason per line, for pytest's failure summary.
    """

    def __init__(self, report):
        self.report = report
        super().__init__(
            f"torque check failed ({len(report.reasons)} reasons):\n"
            + "\n".join(f"  - {r}" for r in report.reasons)
        )
