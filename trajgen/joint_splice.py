"""The orientation path of a joint motion: the segment that plays an untimed target.

Part of :mod:`trajgen.tracker`: :class:`JointSplice` is ``forward(x(t))`` of a
:class:`~trajgen.tracker_profile.JointProfile` through the gimbal's axis sequence,
played by :class:`~trajgen.online.OnlineSpline` as a splice (the interface of
:class:`~trajgen.online_splice.Splice`). Its orientation and exact angular rates come
from the joints' angles, speeds, accelerations and jerks (:func:`joint_frame`), the
same written-out arithmetic on floats (one frame) and on arrays (many). A stream
needs joint frames, and this segment knows them: :meth:`JointSplice.joints_at` hands
them out directly, without the orientation and its inverse kinematics
(:meth:`~trajgen.online_frames.PlanFrames.joints`).
"""

from __future__ import annotations

import math

import numpy as np

from . import jet as J
from . import quat as Q
from .path import OrientationPath


def joint_frame(indices, joints, sign: float = 1.0, order: int = 3):
    """Orientation and space-frame angular velocity, acceleration and jerk of the joint
    motion ``joints`` through the axis sequence ``indices`` (0 = x, 1 = y, 2 = z).

    ``q = R_1(x_1) R_2(x_2) ...``; joint ``i`` turns about ``e_i``, its axis carried by
    the joints before it, so ``omega = sum v_i e_i`` with ``e_i' = w_i x e_i`` (``w_i``
    the angular velocity of the joints before ``i``), and ``alpha``, ``jerk`` its
    derivatives: ``alpha = sum a_i e_i + v_i e_i'``, ``jerk = sum j_i e_i + 2 a_i e_i' +
    v_i e_i''``, ``e_i'' = alpha_i x e_i + w_i x e_i'``. Written out component by
    component, so that one frame in floats is a few microseconds.

    Parameters
    ----------
    indices : sequence of int
        Axis of each joint, from the base out.
    joints : sequence of (x, v, a, j)
        Each joint's angle (rad), speed, acceleration and jerk: floats, or arrays (M,)
        alike.
    sign : float
        +1 or -1: the quaternion's sign (the path's own, where it continues another).
    order : int
        2 or 3: the highest rate computed (the jerk is zeros at 2).

    Returns
    -------
    tuple
        ``q`` (4 components), ``omega``, ``alpha``, ``jerk`` (3 components each).
    """
    first = joints[0][0]
    cos, sin = (math.cos, math.sin) if isinstance(first, float) else (np.cos, np.sin)
    zero = 0.0 * first
    qw, qx, qy, qz = 1.0 + zero, zero, zero, zero
    wx = wy = wz = ax = ay = az = jx = jy = jz = zero
    for axis, (x, v, a, j) in zip(indices, joints, strict=True):
        # e: column `axis` of q's rotation matrix (trajgen.axes.matrix_entries)
        if axis == 0:
            ex, ey = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy + qw * qz)
            ez = 2 * (qx * qz - qw * qy)
        elif axis == 1:
            ex, ey = 2 * (qx * qy - qw * qz), 1 - 2 * (qx * qx + qz * qz)
            ez = 2 * (qy * qz + qw * qx)
        else:
            ex, ey = 2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx)
            ez = 1 - 2 * (qx * qx + qy * qy)
        dx, dy, dz = wy * ez - wz * ey, wz * ex - wx * ez, wx * ey - wy * ex  # e' = w x e
        if order > 2:  # e'' = alpha x e + w x e'
            fx = (ay * ez - az * ey) + (wy * dz - wz * dy)
            fy = (az * ex - ax * ez) + (wz * dx - wx * dz)
            fz = (ax * ey - ay * ex) + (wx * dy - wy * dx)
            a2 = 2.0 * a
            jx, jy, jz = (
                jx + j * ex + a2 * dx + v * fx,
                jy + j * ey + a2 * dy + v * fy,
                jz + j * ez + a2 * dz + v * fz,
            )
        ax, ay, az = ax + a * ex + v * dx, ay + a * ey + v * dy, az + a * ez + v * dz
        wx, wy, wz = wx + v * ex, wy + v * ey, wz + v * ez
        c, s = cos(x / 2.0), sin(x / 2.0)
        # q (c, s e_axis): the Hamilton product with a rotation about one axis
        if axis == 0:
            qw, qx, qy, qz = qw * c - qx * s, qw * s + qx * c, qy * c + qz * s, qz * c - qy * s
        elif axis == 1:
            qw, qx, qy, qz = qw * c - qy * s, qx * c - qz * s, qw * s + qy * c, qx * s + qz * c
        else:
            qw, qx, qy, qz = qw * c - qz * s, qx * c + qy * s, qy * c - qx * s, qw * s + qz * c
    q = (sign * qw, sign * qx, sign * qy, sign * qz)
    return q, (wx, wy, wz), (ax, ay, az), (jx, jy, jz)


class JointSplice(OrientationPath):
    """The orientation path of a :class:`~trajgen.tracker_profile.JointProfile` from
    time ``s``: a segment an :class:`~trajgen.online.OnlineSpline` plays as it plays a
    splice.

    Parameters
    ----------
    s : float
        Start time (s).
    profile : JointProfile
    indices : sequence of int
        The gimbal's axis sequence (0 = x, 1 = y, 2 = z), from the base out.
    near : ndarray, shape (4,)
        The orientation the path continues (its quaternion's sign is taken).
    """

    def __init__(self, s: float, profile, indices, near):
        self.s, self.profile, self.indices = float(s), profile, tuple(indices)
        self.h = profile.duration
        self.times = np.array([self.s, self.s + self.h])
        q0 = self._orientation(profile.x[:, 0])
        self.sign = 1.0 if q0 @ np.asarray(near, dtype=float) >= 0.0 else -1.0
        self.q_a = self.sign * q0
        self.q_end = self.sign * self._orientation(profile.goal)

    def _orientation(self, angles) -> np.ndarray:
        joints = [(float(x), 0.0, 0.0, 0.0) for x in angles]
        return np.array(joint_frame(self.indices, joints, order=2)[0])

    def _joints(self, t):
        st = self.profile.state(np.asarray(t, dtype=float) - self.s)  # (4, M, n)
        return [tuple(st[:, :, i]) for i in range(st.shape[2])]

    def _space_rates(self, t, seg, max_order):
        q, *rates = joint_frame(self.indices, self._joints(t), self.sign)
        return np.stack(q, axis=1), [np.stack(r, axis=1) for r in rates[:max_order]]

    def _jet(self, t, seg, order):
        """The orientation as a jet: each joint's half-angle rotation ``exp`` of its
        polynomial's Taylor series (exact within a phase), multiplied in order."""
        st = self.profile.state(np.asarray(t, dtype=float) - self.s)
        q = None
        for i, axis in enumerate(self.indices):
            c = np.zeros((order + 1, 3, st.shape[1]))
            for m in range(min(order, 3) + 1):
                c[m, axis] = st[m, :, i] / (2.0 * math.factorial(m))
            e = J.qexp(J.Jet(c))
            q = e if q is None else J.qmul(q, e)
        return J.Jet(self.sign * q.c)

    def taylor(self, t: float, order: int) -> tuple[np.ndarray, np.ndarray]:
        """``q(t)`` (4,) and the Taylor coefficients (order + 1, 4) of ``q(t + tau) q(t)*``."""
        jet = self._jet(np.array([t]), None, order)
        q = jet.value[:, 0] / np.linalg.norm(jet.value[:, 0])
        d = J.qmul(jet, Q.conj(q)).c[:, :, 0]
        d[0] = (1.0, 0.0, 0.0, 0.0)
        return q, d

    def frame(self, t: float) -> tuple[tuple, tuple, tuple]:
        """Orientation, angular velocity (rad/s) and acceleration (rad/s^2) at one time
        ``t`` (s), in floats: the per-frame counterpart of :meth:`_space_rates`."""
        q, w, al, _ = joint_frame(self.indices, self.profile.state_at(t - self.s), self.sign, 2)
        return q, w, al

    def joints_at(self, t: float) -> tuple[tuple, tuple, tuple]:
        """The joints' angles (rad), speeds (rad/s) and accelerations (rad/s^2) at one
        time ``t`` (s), each a tuple of n floats: the joint frame :meth:`frame`'s
        orientation and rates are made of."""
        x, v, a, _ = zip(*self.profile.state_at(t - self.s), strict=True)
        return x, v, a

    def rates(self, t: float) -> tuple[np.ndarray, list[np.ndarray]]:
        """``q`` (4,) and the space-frame angular velocity, acceleration and jerk (each
        (3,)) at one time ``t`` (s)."""
        q, *rates = joint_frame(self.indices, self.profile.state_at(t - self.s), self.sign)
        return np.array(q), [np.array(r) for r in rates]
