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
    """

    def __init__(self, report):
        self.report = report
        super().__init__("torque check failed: " + "; ".join(report.reasons))
