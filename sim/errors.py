"""The simulator's domain errors."""

from __future__ import annotations


class SimError(RuntimeError):
    """Base class of the simulator's domain failures."""


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
