"""MuJoCo simulation of a Dynamixel gimbal and its torque check: 2 or 3 joints in any
axis order (``trajgen.axes``), a servo per joint, built in or the user's own MJCF/URDF
model (``sim.user_model``).

The simulator consumes trajgen's joint stream (``trajgen.stream.JointTrajectory``)
and nothing else from trajgen. MuJoCo is imported only when a model is built.
"""

from trajgen.sim.check import (
    JointReport,
    TorqueReport,
    assert_torque_ok,
    build_report,
    check_torque,
)
from trajgen.sim.dynamics import inverse_dynamics
from trajgen.sim.errors import SimError, SimulationError, TorqueLimitExceeded
from trajgen.sim.firmware import PositionLoop, UnsupportedServoSetting
from trajgen.sim.fit import FitError, FitResult, SegmentFit, fit_timing
from trajgen.sim.lead import lead_trajectory
from trajgen.sim.limits import JointLimits, check_limits
from trajgen.sim.model import (
    GimbalConfig,
    JointParams,
    build_model,
    gimbal_config_from_tables,
    gimbal_mjcf,
)
from trajgen.sim.plant import GimbalPlant
from trajgen.sim.run import SimRecord, simulate
from trajgen.sim.servos import SERVOS, ServoModel, servo_by_name

__all__ = [
    "SERVOS",
    "FitError",
    "FitResult",
    "GimbalConfig",
    "GimbalPlant",
    "JointLimits",
    "JointParams",
    "JointReport",
    "PositionLoop",
    "SegmentFit",
    "ServoModel",
    "SimError",
    "SimRecord",
    "SimulationError",
    "TorqueLimitExceeded",
    "TorqueReport",
    "UnsupportedServoSetting",
    "assert_torque_ok",
    "build_model",
    "build_report",
    "check_limits",
    "check_torque",
    "fit_timing",
    "gimbal_config_from_tables",
    "gimbal_mjcf",
    "inverse_dynamics",
    "lead_trajectory",
    "servo_by_name",
    "simulate",
]
