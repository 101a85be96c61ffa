"""A plan as ROS 2 messages in MCAP: the joint trajectory and the orientation.

``trajgen plan FILE --out plan.mcap`` writes, from the exact plan
(:func:`trajgen.stream.plan_joint_trajectory`: the joint velocities and
accelerations converted exactly from the spline's angular rates):

- ``/trajgen/joint_trajectory``: one ``trajectory_msgs/msg/JointTrajectory``
  with every sample as a point (positions rad, velocities rad/s,
  accelerations rad/s^2, ``time_from_start`` from the first sample), what
  ros2_control's joint trajectory controller takes (quintic segments);
- ``/trajgen/orientation``: one ``geometry_msgs/msg/QuaternionStamped`` per
  sample, the spline's orientation (x, y, z, w);
- ``/trajgen/plan``: one ``sensor_msgs/msg/JointState`` per sample (position,
  velocity; no effort), the same topic a run log's plan is on, for plots.

Stamps and log times count from the first sample (as ``time_from_start``;
keyframe times may be negative, MCAP log times may not). Needs the ``mcap``
extra.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trajgen.gimbal import JOINT_NAMES
from trajgen.ros2_messages import (
    JOINT_STATE,
    JOINT_TRAJECTORY,
    QUATERNION_STAMPED,
    header,
    mcap_writer,
    time_msg,
    to_ns,
)
from trajgen.stream import JointTrajectory, plan_joint_trajectory
from trajgen.telemetry_mcap import PLAN

TRAJECTORY, ORIENTATION = "/trajgen/joint_trajectory", "/trajgen/orientation"

#: Most samples of an MCAP plan: its one JointTrajectory message is built in
#: memory (about 1 kB of Python objects a point) and encoded in pure Python.
MAX_SAMPLES = 200_000


def write_plan_mcap(
    path: str | Path, spline, rate_hz: float, *, progress=None, **plan_options
) -> JointTrajectory:
    """Plan ``spline`` at ``rate_hz`` and write it to an MCAP file.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.
    spline : spline-like
        The orientation path (``t_start``, ``t_end``, ``evaluate``).
    rate_hz : float
        Sample rate (Hz).
    progress : callable, optional
        Called with the fraction written (0..1) every 1000 samples and at the end.
    **plan_options
        ``kinematics``, ``start``: as for ``plan_joint_trajectory``; the messages name
        the joints of ``kinematics`` (default pan, tilt, roll).

    Returns
    -------
    JointTrajectory
        The plan written.

    Raises
    ------
    KinematicsError
        If the path nears gimbal lock or leaves the joint limits.
    McapMissing
        If the ``mcap`` extra is not installed.
    OSError
        If the file cannot be written.
    """
    plan = plan_joint_trajectory(spline, rate_hz, **plan_options)
    quats = np.asarray(spline.evaluate(plan.t, max_order=0).q, float)
    kinematics = plan_options.get("kinematics")
    names = list(JOINT_NAMES if kinematics is None else kinematics.joints)
    t0 = float(plan.t[0])
    with open(path, "wb") as f:
        writer = mcap_writer(f)
        trajectory = writer.register_msgdef(*JOINT_TRAJECTORY)
        orientation = writer.register_msgdef(*QUATERNION_STAMPED)
        state = writer.register_msgdef(*JOINT_STATE)
        points = [
            {
                "positions": q,
                "velocities": qd,
                "accelerations": qdd,
                "effort": [],
                "time_from_start": time_msg(t - t0),
            }
            for t, q, qd, qdd in zip(
                plan.t.tolist(), plan.q.tolist(), plan.qd.tolist(), plan.qdd.tolist(), strict=True
            )
        ]
        message = {"header": header(0.0), "joint_names": names, "points": points}
        writer.write_message(TRAJECTORY, trajectory, message, log_time=0)
        for k, (t, (w, x, y, z), q, qd) in enumerate(
            zip(plan.t.tolist(), quats.tolist(), plan.q.tolist(), plan.qd.tolist(), strict=True)
        ):
            stamp, log_time = header(t - t0), to_ns(t - t0)
            message = {"header": stamp, "quaternion": {"x": x, "y": y, "z": z, "w": w}}
            writer.write_message(ORIENTATION, orientation, message, log_time, sequence=k)
            message = {"header": stamp, "name": names, "position": q, "velocity": qd}
            writer.write_message(PLAN, state, message | {"effort": []}, log_time, sequence=k)
            if progress is not None and k % 1000 == 999:
                progress((k + 1) / len(plan))
        writer.finish()
    if progress is not None:
        progress(1.0)
    return plan
