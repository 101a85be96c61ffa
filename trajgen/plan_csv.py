"""A plan as CSV rows: the spline sampled at a fixed rate and written block by block
(``trajgen plan``), so a plan of any length needs the memory of one block.

Each row: time (s), unit quaternion ``(w, x, y, z)``, space-frame angular
velocity (rad/s) and acceleration (rad/s^2); for a gimbal whose axes are not
pan-tilt-roll also the look direction and each joint's angle (rad), velocity
(rad/s) and acceleration (rad/s^2).
"""

from __future__ import annotations

import csv

import numpy as np

from trajgen.sampling import sample_time_blocks

CSV_HEADER = ["t_s", "qw", "qx", "qy", "qz", "wx", "wy", "wz", "ax", "ay", "az"]

#: Samples evaluated and written at a time.
BLOCK = 100_000


def write_plan_csv(
    out, spline, rate: float, max_samples: int, progress=None, joints=None
) -> tuple[int, float, float]:
    """Write a spline's plan as CSV, :data:`BLOCK` samples at a time.

    Parameters
    ----------
    out : file
        A text file opened with ``newline=""``.
    spline : OrientationPath
        The path, sampled from ``t_start`` to ``t_end`` inclusive.
    rate : float
        Sample rate (Hz).
    max_samples : int
        The most rows written (``trajgen.sampling.sample_time_blocks`` refuses more).
    progress : callable, optional
        ``progress(rows)`` after each block.
    joints : JointColumns, optional
        Adds the look direction and joint columns (:func:`joint_columns`).

    Returns
    -------
    rows : int
        Rows written, the header not counted.
    peak_omega, peak_alpha : float
        Peak |angular velocity| (rad/s) and |angular acceleration| (rad/s^2).
    """
    total = 0
    peak_w = peak_a = 0.0
    writer = csv.writer(out)
    writer.writerow(CSV_HEADER + ([] if joints is None else joints.header))
    blocks = sample_time_blocks(
        spline.t_start, spline.t_end, rate, block=BLOCK, max_samples=max_samples
    )
    for t in blocks:
        s = spline.evaluate(t, max_order=2)
        total += len(t)
        columns = [s.t, s.q, s.omega, s.alpha]
        if joints is not None:
            columns += joints(s)
        writer.writerows(np.column_stack(columns).round(12).tolist())
        peak_w = max(peak_w, float(np.linalg.norm(s.omega, axis=1).max()))
        peak_a = max(peak_a, float(np.linalg.norm(s.alpha, axis=1).max()))
        if progress is not None:
            progress(total)
    return total, peak_w, peak_a


class JointColumns:
    """The look direction and joint columns of a plan for axes other than pan-tilt-roll:
    the joint stream (``GimbalKinematics.inverse`` and ``joint_rates``), unwrapped
    from one block to the next; raises ``KinematicsError`` near lock or a limit."""

    def __init__(self, kf):
        from trajgen.gimbal import GimbalKinematics

        self.kin = GimbalKinematics(axes=kf.axes.sequence, joints=kf.axes.joints)
        names = self.kin.joints
        self.header = ["look_x", "look_y", "look_z"] + [
            f"{j}_{unit}" for unit in ("rad", "rad_s", "rad_s2") for j in names
        ]
        self.last = None

    def __call__(self, s) -> list:
        from trajgen import quat

        q = self.kin.inverse(s.q, s.t, start=self.last)
        qd, qdd = self.kin.joint_rates(q, s.omega, s.alpha)
        self.last = q[-1]
        return [quat.rotate(s.q, self.kin.sequence.look), q, qd, qdd]


def joint_columns(kf) -> JointColumns | None:
    """Joint columns for a file whose ``[gimbal] axes`` / ``joints`` are not pan-tilt-roll."""
    from trajgen.keyframe_axes import is_default

    return None if is_default(kf.axes) else JointColumns(kf)
