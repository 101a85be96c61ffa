"""One stream frame at a time, in Python floats: the per-frame path of the online stream.

:func:`trajgen.stream.stream_frames` hands out one frame per control cycle. Doing
that with numpy, a block of frames at a time, costs a fixed ~0.1 ms per block
whatever its length (call overhead of a few dozen small array operations), which
is over a 2 kHz budget of 50 us in whichever frame pays it. Here one frame is a
few hundred float operations with the :mod:`math` module, about the same cost in
every frame:

- :class:`FrameKinematics`: the inverse kinematics (pan and roll unwrapped), the
  lock and limit guard and the joint rates of one frame; the scalar counterpart
  of :meth:`trajgen.gimbal.GimbalKinematics.inverse` and
  :func:`trajgen.gimbal.joint_rates`, sharing their formulas
  (:func:`~trajgen.gimbal.angles_of`, :func:`~trajgen.gimbal.rates_of`); for any
  other axis sequence :class:`AxesFrameKinematics`, sharing those of
  :mod:`trajgen.axes` (:func:`~trajgen.axes.angles_of_matrix`,
  :func:`~trajgen.axes.rates_of_axes`).
- :class:`SmoothFrames`: a :class:`~trajgen.smooth.SmoothSpline`'s orientation,
  angular velocity and acceleration at one time, from its coefficient table
  (:attr:`~trajgen.smooth.SmoothSpline.tangent_coefficients`); the scalar
  counterpart of ``SmoothSpline._space_rates``.

The spline's closed forms are those of :mod:`trajgen.derivatives` and
``SmoothSpline._space_rates`` written out for one sample (a chain of calls on
lists of floats would cost more than the arithmetic); ``tests/test_frame_eval.py``
checks them against the numpy versions on both branches of the series.
"""

from __future__ import annotations

import math

import numpy as np

from . import quat as Q
from .axes import angles_of_matrix, matrix_entries, rates_of_axes
from .errors import BadArgument
from .gimbal import TWO_PI, GimbalKinematics, angles_of, joint_rates, rates_of
from .jet import _COS, _SINC, SERIES_BELOW
from .per_sample import hamilton


def _series_rows(coef: np.ndarray) -> tuple:
    """Coefficients of a power series in ``x`` and of its first two x-derivatives, each
    padded to the series' length (as :func:`trajgen.derivatives._series` builds them)."""
    n = len(coef)
    rows = [np.polynomial.polynomial.polyder(coef, k) for k in range(3)]
    return tuple(tuple(np.pad(r, (0, n - len(r))).tolist()) for r in rows)


_COS_ROWS = _series_rows(_COS)
_SINC_ROWS = _series_rows(_SINC)


def _series(rows: tuple, x: float) -> tuple[float, float, float]:
    """A 6-term power series (``rows`` from :func:`_series_rows`) and its first two
    x-derivatives at ``x``, by Horner."""
    (a0, a1, a2, a3, a4, a5), (b0, b1, b2, b3, b4, _), (c0, c1, c2, c3, _, _) = rows
    return (
        a0 + x * (a1 + x * (a2 + x * (a3 + x * (a4 + x * a5)))),
        b0 + x * (b1 + x * (b2 + x * (b3 + x * b4))),
        c0 + x * (c1 + x * (c2 + x * c3)),
    )


def cos_sinc_sqrt(x: float) -> tuple[float, float, float, float, float, float]:
    """``C = cos sqrt(x)``, ``S = sin sqrt(x) / sqrt(x)`` and their first two derivatives in x.

    The scalar form of :func:`trajgen.derivatives.cos_sinc_sqrt` (before the chain
    rule): a series below ``SERIES_BELOW``, else ``S' = (C - S) / 2x``,
    ``C' = -S / 2``, ``S'' = (C' - 3 S') / 2x``, ``C'' = -S' / 2``.

    Parameters
    ----------
    x : float
        A squared angle (rad^2), >= 0.

    Returns
    -------
    tuple of float
        ``(C, C', C'', S, S', S'')``.
    """
    if x < SERIES_BELOW:
        return _series(_COS_ROWS, x) + _series(_SINC_ROWS, x)
    a = math.sqrt(x)
    c0 = math.cos(a)
    s0 = math.sin(a) / a
    inv2x = 0.5 / x
    s1 = (c0 - s0) * inv2x
    c1 = -0.5 * s0
    s2 = (c1 - 3 * s1) * inv2x
    c2 = -0.5 * s1
    return c0, c1, c2, s0, s1, s2


def _poly7(c: list, u: float) -> float:
    """A degree-7 polynomial with coefficients ``c[0..7]`` (of ``u^0..u^7``) at ``u``."""
    c0, c1, c2, c3, c4, c5, c6, c7 = c
    return c0 + u * (c1 + u * (c2 + u * (c3 + u * (c4 + u * (c5 + u * (c6 + u * c7))))))


def exp_frame(rx, ry, rz, vx, vy, vz, ax, ay, az, base) -> tuple[tuple, tuple, tuple]:
    """Orientation, angular velocity and acceleration of ``q = exp(r) q_b`` at one time.

    ``E = exp(r) = (C(x), S(x) r)``, ``x = r . r``; ``omega = 2 vec(E' E*)`` and
    ``alpha = 2 vec(E'' E*)``, as ``SmoothSpline._space_rates`` (algorithm.md §8).

    Parameters
    ----------
    rx, ry, rz, vx, vy, vz, ax, ay, az : float
        ``r`` (rad) and its first two time derivatives (rad/s, rad/s^2).
    base : sequence of 4 floats
        The fixed quaternion ``q_b`` (w, x, y, z).

    Returns
    -------
    tuple of three tuples of floats
        ``q`` (4), ``omega`` (3, rad/s), ``alpha`` (3, rad/s^2), space frame.
    """
    # x = r . r and its time derivatives (derivatives.vdot).
    x0 = rx * rx + ry * ry + rz * rz
    x1 = 2.0 * (rx * vx + ry * vy + rz * vz)
    x2 = 2.0 * (vx * vx + vy * vy + vz * vz) + 2.0 * (rx * ax + ry * ay + rz * az)
    c0, c1, c2, s0, s1, s2 = cos_sinc_sqrt(x0)
    # Their time derivatives (Faa di Bruno, derivatives.chain).
    x11 = x1 * x1
    C1, C2 = c1 * x1, c1 * x2 + c2 * x11
    S1, S2 = s1 * x1, s1 * x2 + s2 * x11
    # E = (C, S r) and its time derivatives (Leibniz, derivatives.product).
    ew, ex, ey, ez = c0, s0 * rx, s0 * ry, s0 * rz
    dw, dx, dy, dz = C1, s0 * vx + S1 * rx, s0 * vy + S1 * ry, s0 * vz + S1 * rz
    S1x2 = 2.0 * S1
    fw = C2
    fx = s0 * ax + S2 * rx + S1x2 * vx
    fy = s0 * ay + S2 * ry + S1x2 * vy
    fz = s0 * az + S2 * rz + S1x2 * vz
    q = hamilton((ew, ex, ey, ez), base)
    # 2 vec(P E*) with E* = (ew, -ex, -ey, -ez) (derivatives.hamilton_vec).
    omega = (
        2.0 * (-dw * ex + dx * ew - dy * ez + dz * ey),
        2.0 * (-dw * ey + dx * ez + dy * ew - dz * ex),
        2.0 * (-dw * ez - dx * ey + dy * ex + dz * ew),
    )
    alpha = (
        2.0 * (-fw * ex + fx * ew - fy * ez + fz * ey),
        2.0 * (-fw * ey + fx * ez + fy * ew - fz * ex),
        2.0 * (-fw * ez - fx * ey + fy * ex + fz * ew),
    )
    return q, omega, alpha


class SmoothFrames:
    """A :class:`~trajgen.smooth.SmoothSpline` at one time per call, in floats.

    On segment i the path is ``q = E q_i``, ``E = exp(r_i(u)) = (C(x), S(x) r)``,
    ``x = r . r``; ``omega = 2 vec(E' E*)`` and ``alpha = 2 vec(E'' E*)`` (docs/
    algorithm.md §8). Times are expected mostly increasing, as in a stream: the segment
    is looked up only when the time leaves the current one, and its row of the
    coefficient table is converted to floats then.

    Parameters
    ----------
    spline : SmoothSpline
    """

    def __init__(self, spline):
        self._times = spline.times
        self._table = spline.tangent_coefficients
        self._quats = spline.quats
        self._t0, self._t1 = spline.t_start, spline.t_end
        self._periodic = spline.periodic
        self._eps = 1e-12 * max(1.0, abs(self._t0), abs(self._t1))  # as OrientationPath
        self._lo, self._hi = math.inf, -math.inf  # the current segment's [lo, hi)

    def _enter(self, t: float) -> None:
        """Make the segment holding ``t`` the current one (as ``OrientationPath._segment``)."""
        last = len(self._times) - 2
        seg = min(max(int(np.searchsorted(self._times, t, side="right")) - 1, 0), last)
        self._lo = float(self._times[seg])
        self._h = float(self._times[seg + 1]) - self._lo
        self._hi = float(self._times[seg + 1]) if seg < last else math.inf
        self._rows = self._table[seg, :9].tolist()  # r, r', r'' per axis
        self._base = self._quats[seg].tolist()

    def __call__(self, t: float) -> tuple[tuple, tuple, tuple]:
        """Orientation ``(w, x, y, z)``, space-frame angular velocity (rad/s) and
        acceleration (rad/s^2) at time ``t`` (s), each a tuple of floats.

        ``t`` is wrapped for a closed spline; otherwise a time outside
        ``[t_start, t_end]`` raises ValueError (as ``evaluate``).
        """
        if self._periodic:
            t = self._t0 + (t - self._t0) % (self._t1 - self._t0)
        elif not self._t0 <= t <= self._t1:
            if not self._t0 - self._eps <= t <= self._t1 + self._eps:
                raise BadArgument(
                    f"Time {t!r} s is outside the path's range [{self._t0}, {self._t1}] s."
                )
            t = min(max(t, self._t0), self._t1)
        if not self._lo <= t < self._hi:
            self._enter(t)
        u = (t - self._lo) / self._h
        return exp_frame(*[_poly7(c, u) for c in self._rows], self._base)


class FrameKinematics:
    """Joint angles and rates of one frame at a time, in floats, unwrapped from the last.

    The scalar counterpart of :meth:`GimbalKinematics.inverse` followed by
    :func:`~trajgen.gimbal.joint_rates`: the same formulas, the same integer turn
    counts for pan and roll (so frame i equals row i of the arrays), the same
    guard. A frame near gimbal lock or outside a limit raises the same
    :class:`~trajgen.errors.KinematicsError`, with the same message (it is built
    by the numpy code from that one frame).

    For axes other than ``"zyx"`` the instance is an :class:`AxesFrameKinematics`.

    Parameters
    ----------
    kinematics : GimbalKinematics
    start : ndarray, shape (3,), or None
        The angles (rad) whose 2 pi branch the first frame's pan and roll take.
    """

    def __new__(cls, kinematics: GimbalKinematics, start=None):
        if cls is FrameKinematics and not kinematics.is_default:
            return super().__new__(AxesFrameKinematics)
        return super().__new__(cls)

    def __init__(self, kinematics: GimbalKinematics, start=None):
        self._kin = kinematics
        self._last = None  # the last frame's wrapped pan and roll (rad)
        self._pan_turns = self._roll_turns = 0  # whole turns added to pan and roll
        lock = math.pi / 2 - kinematics.lock_margin_rad
        (p_lo, p_hi), (t_lo, t_hi), (r_lo, r_hi) = kinematics.limits_rad
        # |tilt| <= lock and t_lo <= tilt <= t_hi, as one interval (NaN fails it).
        self._bounds = (p_lo, p_hi, max(t_lo, -lock), min(t_hi, lock), r_lo, r_hi)
        self._start = None if start is None else (float(start[0]), float(start[2]))
        #: The axis sequence (0 = x, 1 = y, 2 = z) of the joints, from the base out.
        self.indices = kinematics.sequence.indices

    @property
    def state(self) -> tuple:
        """What the next frame is unwrapped against: set it back to evaluate a frame again."""
        return self._last, self._pan_turns, self._roll_turns

    @state.setter
    def state(self, value: tuple) -> None:
        self._last, self._pan_turns, self._roll_turns = value

    def __call__(self, t: float, q, omega, alpha) -> tuple[tuple, tuple, tuple]:
        """Joint angles (rad), velocities (rad/s) and accelerations (rad/s^2) of one frame.

        Parameters
        ----------
        t : float
            The frame's time (s), for the error message.
        q : sequence of 4 floats
            Orientation ``(w, x, y, z)``, any non-zero norm.
        omega, alpha : sequence of 3 floats
            Space-frame angular velocity (rad/s) and acceleration (rad/s^2).

        Returns
        -------
        tuple of three tuples of 3 floats
            ``(pan, tilt, roll)``, their velocities and their accelerations.

        Raises
        ------
        KinematicsError
            Near gimbal lock or outside a joint limit (as ``GimbalKinematics.check``).
        ValueError
            If a value is not finite or ``q`` has zero norm.
        """
        w, x, y, z = q
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if not 1e-12 <= norm < math.inf:
            Q.as_quats([q])  # raises, naming what is wrong
        pan, tilt, roll = angles_of(w / norm, x / norm, y / norm, z / norm, math.atan2, math.hypot)
        angles = self._unwrap(pan, tilt, roll)
        if not self._inside(angles):
            self._kin.check(np.array([angles]), np.array([t]))  # raises with the message
        pan, tilt, roll = angles
        cp, sp, ct, st = math.cos(pan), math.sin(pan), math.cos(tilt), math.sin(tilt)
        qd, qdd = rates_of(cp, sp, ct, st, omega, alpha)
        total = sum(qd) + sum(qdd)
        if total - total != 0.0:  # inf or NaN: a rate of the path was not finite
            joint_rates(angles, omega, alpha)  # raises, naming it
        return angles, qd, qdd

    def joints(self, angles, qd, qdd) -> tuple[tuple, tuple, tuple] | None:
        """The frame of a joint motion known as such (angles on any 2 pi branch, their
        speeds and accelerations, each n floats), without its orientation: the angles
        unwrapped as :meth:`__call__` unwraps those of the orientation they make (the
        same turn counts, the same state), the same guard.

        Returns None, the state left as it was, where the guard refuses the frame:
        the caller then evaluates the orientation with :meth:`__call__`, which raises
        with the message (and which alone knows another branch of the middle joint).
        """
        state = self.state
        wrapped = [a - TWO_PI * round(a / TWO_PI) for a in angles]  # as atan2 gives them
        unwrapped = self._unwrap(*wrapped)
        if not self._inside(unwrapped):
            self.state = state
            return None
        return unwrapped, tuple(qd), tuple(qdd)

    def _unwrap(self, pan: float, tilt: float, roll: float) -> tuple:
        """``(pan, tilt, roll)`` (rad) with pan and roll (each in (-pi, pi], to rounding)
        on the branch of the frame before: integer turn counts, as
        GimbalKinematics.inverse (np.round and round both round half to even)."""
        if self._last is not None:
            self._pan_turns += round((self._last[0] - pan) / TWO_PI)
            self._roll_turns += round((self._last[1] - roll) / TWO_PI)
        elif self._start is not None:
            self._pan_turns = round((self._start[0] - pan) / TWO_PI)
            self._roll_turns = round((self._start[1] - roll) / TWO_PI)
        self._last = (pan, roll)
        return pan + TWO_PI * self._pan_turns, tilt, roll + TWO_PI * self._roll_turns

    def _inside(self, angles: tuple) -> bool:
        """Whether unwrapped angles keep the joint limits and the lock margin (NaN fails)."""
        pan, tilt, roll = angles
        p_lo, p_hi, t_lo, t_hi, r_lo, r_hi = self._bounds
        return p_lo <= pan <= p_hi and t_lo <= tilt <= t_hi and r_lo <= roll <= r_hi


class AxesFrameKinematics(FrameKinematics):
    """:class:`FrameKinematics` for any axis sequence (:mod:`trajgen.axes`), in floats.

    The formulas of :class:`GimbalKinematics` (:func:`~trajgen.axes.angles_of_matrix`,
    :func:`~trajgen.axes.rates_of_axes`) on the floats of one frame, with the same
    integer turn counts for the wrapped joints as :meth:`GimbalKinematics.inverse`
    and the same guard: a frame near gimbal lock or outside a limit raises the
    message of :meth:`GimbalKinematics.check`.

    Parameters
    ----------
    kinematics : GimbalKinematics
    start : ndarray, shape (n,), or None
        The angles (rad) whose 2 pi branch the first frame's wrapped joints take.
    """

    def __init__(self, kinematics: GimbalKinematics, start=None):
        self._kin = kinematics
        seq = kinematics.sequence
        self._seq = seq
        self._cols = seq.wrapped
        self._start = None if start is None else tuple(float(start[c]) for c in self._cols)
        self._last = None  # the last frame's wrapped joints (rad)
        self._turns = (0,) * len(self._cols)  # whole turns added to them
        margin = kinematics.lock_margin_rad
        bounds = [list(b) for b in kinematics.limits_rad]
        if seq.kind == "proper-euler":
            low, high = margin, math.pi - margin
        else:
            low, high = -math.pi / 2 + margin, math.pi / 2 - margin
        # Lock and limits of the middle joint as one interval (NaN fails it).
        bounds[1] = [max(bounds[1][0], low), min(bounds[1][1], high)]
        self._bounds = tuple(tuple(b) for b in bounds)
        self._units = tuple(_UNITS[i] for i in seq.indices)
        self._look = tuple(float(v) for v in seq.look)
        self.indices = seq.indices

    @property
    def state(self) -> tuple:
        """What the next frame is unwrapped against: set it back to evaluate a frame again."""
        return self._last, self._turns

    @state.setter
    def state(self, value: tuple) -> None:
        self._last, self._turns = value

    def __call__(self, t: float, q, omega, alpha) -> tuple[tuple, tuple, tuple]:
        """Joint angles (rad), velocities (rad/s) and accelerations (rad/s^2) of one
        frame, each a tuple of n floats; arguments and errors as
        :meth:`FrameKinematics.__call__`."""
        w, x, y, z = q
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if not 1e-12 <= norm < math.inf:
            Q.as_quats([q])  # raises, naming what is wrong
        r = matrix_entries(w / norm, x / norm, y / norm, z / norm)
        angles = self._unwrap(*angles_of_matrix(self._seq, r, math.atan2, math.hypot))
        if not self._inside(angles):
            self._kin.check(np.array([angles]), np.array([t]))  # raises with the message
        qd, qdd = rates_of_axes(*self._axes(angles), tuple(omega), tuple(alpha))
        total = sum(qd) + sum(qdd)
        if total - total != 0.0:  # inf or NaN: the numpy formulas raise, naming it
            qd, qdd = self._kin.joint_rates(np.array([angles]), [omega], [alpha])
            return angles, tuple(qd[0].tolist()), tuple(qdd[0].tolist())
        return angles, qd, qdd

    def _unwrap(self, *angles: float) -> tuple:
        """The angles (rad; the wrapped joints' each in (-pi, pi], to rounding) with the
        wrapped joints on the branch of the frame before: integer turn counts, as
        GimbalKinematics.inverse (np.round and round both round half to even)."""
        angles = list(angles)
        wrapped = tuple(angles[c] for c in self._cols)
        if self._last is not None:
            self._turns = tuple(
                n + round((last - a) / TWO_PI)
                for n, last, a in zip(self._turns, self._last, wrapped, strict=True)
            )
        elif self._start is not None:
            self._turns = tuple(
                round((s - a) / TWO_PI) for s, a in zip(self._start, wrapped, strict=True)
            )
        self._last = wrapped
        for c, n in zip(self._cols, self._turns, strict=True):
            angles[c] += TWO_PI * n
        return tuple(angles)

    def _inside(self, angles: tuple) -> bool:
        """Whether unwrapped angles keep the joint limits and the lock margin (NaN fails)."""
        return all(lo <= a <= hi for a, (lo, hi) in zip(angles, self._bounds, strict=True))

    def _axes(self, angles: tuple) -> tuple[tuple, tuple | None]:
        """The space-frame joint axes of one frame and (two axes) the look direction."""
        u = self._units
        c1, s1 = math.cos(angles[0]), math.sin(angles[0])
        first = self._seq.indices[0]
        e1 = _rotate(first, c1, s1, u[1])
        if len(angles) == 2:
            c2, s2 = math.cos(angles[1]), math.sin(angles[1])
            carried = _rotate(self._seq.indices[1], c2, s2, self._look)
            return (u[0], e1), _rotate(first, c1, s1, carried)
        c2, s2 = math.cos(angles[1]), math.sin(angles[1])
        e2 = _rotate(first, c1, s1, _rotate(self._seq.indices[1], c2, s2, u[2]))
        return (u[0], e1, e2), None


_UNITS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def _rotate(axis: int, c: float, s: float, v: tuple) -> tuple:
    """``R_axis(angle) v`` for ``c, s`` the angle's cosine and sine (0 = x, 1 = y, 2 = z)."""
    x, y, z = v
    if axis == 0:
        return x, c * y - s * z, s * y + c * z
    if axis == 1:
        return c * x + s * z, y, c * z - s * x
    return c * x - s * y, s * x + c * y, z
