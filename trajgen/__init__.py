"""trajgen: smooth orientation trajectories for pan-tilt-roll gimbals and robot wrists.

The circular blending quaternion spline of Kim & Nam (1995) with exact angular
velocity, acceleration and jerk; pan-tilt-roll kinematics; and the fixed-rate
joint stream that ``drivers`` (Dynamixel servos) and ``sim`` (MuJoCo) consume.
Needs numpy only. Quaternions are scalar first, ``(w, x, y, z)``.
"""

from . import quat
from .errors import KinematicsError, PlanTooLarge, TrajgenError
from .gimbal import JOINT_NAMES, GimbalKinematics
from .keyframes import BUILTIN_EXAMPLE, KeyframeFile, KeyframeFileError, load_keyframe_file
from .online import ChangeTooLate, OnlineSpline
from .path import OrientationPath, Samples
from .sampling import sample_times
from .smooth import SmoothSpline
from .spline import BlendingSpline
from .stream import JointFrame, JointTrajectory, plan_joint_trajectory, stream_frames

__version__ = "0.1.0"

__all__ = [
    "BUILTIN_EXAMPLE",
    "JOINT_NAMES",
    "BlendingSpline",
    "ChangeTooLate",
    "GimbalKinematics",
    "JointFrame",
    "JointTrajectory",
    "KeyframeFile",
    "KeyframeFileError",
    "KinematicsError",
    "OrientationPath",
    "OnlineSpline",
    "PlanTooLarge",
    "Samples",
    "SmoothSpline",
    "TrajgenError",
    "load_keyframe_file",
    "plan_joint_trajectory",
    "quat",
    "sample_times",
    "stream_frames",
]
