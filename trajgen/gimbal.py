"""Gimbal kinematics: joint angles to orientation and back, with lock guard and unwrap.

The default gimbal is pan-tilt-roll, ``q = Rz(pan) Ry(tilt) Rx(roll)``: pan turns
about the base z axis, tilt about the panned y axis, roll about the tilted x axis,
and the camera looks along its x axis. Angles are in rad, in ``JOINT_NAMES`` order
``(pan, tilt, roll)``; quaternions are scalar first ``(w, x, y, z)``. The
module-level :func:`forward`, :func:`jacobian` and :func:`joint_rates` are this
gimbal's closed forms.

:class:`GimbalKinematics` also takes any other sequence of 2 or 3 axes
(``axes="zy"``, ``"yx"``, ``"xyz"``, ``"zxz"``..., :mod:`trajgen.axes`) with
joint names; for ``"zyx"`` its methods are the closed forms here, bit for bit.

At ``tilt = +-pi/2`` pan and roll turn about the same axis (gimbal lock): the
joint rates needed for a finite angular velocity grow as ``1 / cos(tilt)``, so
:meth:`GimbalKinematics.inverse` refuses paths that come closer than
``lock_margin_rad`` to it. Other sequences lock where their middle angle is
+-90 deg (Tait-Bryan, two axes) or 0 or 180 deg (proper Euler).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from trajgen import quat
from trajgen.axes import DEFAULT_SEQUENCE, AxisSequence
from trajgen.errors import BadArgument, KinematicsError
from trajgen.validate import check_number

TWO_PI = 2.0 * math.pi

#: The gimbal's joints, in the order of every (..., 3) joint array in trajgen,
#: ``trajgen.sim`` and ``trajgen.drivers``.
JOINT_NAMES = ("pan", "tilt", "roll")

#: Default joint limits (rad), rows pan, tilt, roll: one full turn of pan
#: either way, the whole tilt range (the lock margin narrows it), half a turn of roll.
DEFAULT_LIMITS_RAD = AxisSequence(DEFAULT_SEQUENCE).default_limits()


def as_angles(angles, name: str = "angles", *, single: bool = False, n: int = 3) -> np.ndarray:
    """Validate joint angles.

    Parameters
    ----------
    angles : array_like, shape (..., n)
        ``(pan, tilt, roll)`` (rad), or the ``n`` joints of an axis sequence.
    name : str
        Argument name used in error messages.
    single : bool
        Require shape (n,), one set of angles.
    n : int
        Number of joints (default 3).

    Returns
    -------
    ndarray, shape (..., n)
        The angles as float64.

    Raises
    ------
    TypeError
        If ``angles`` is not numeric.
    ValueError
        If the shape is wrong or a value is not finite.
    """
    try:
        a = np.asarray(angles, dtype=float)
    except (TypeError, ValueError) as e:
        raise TypeError(f"Expected `{name}` to be numeric, got {type(angles).__name__}.") from e
    if single and a.shape != (n,):
        raise BadArgument(f"Expected `{name}` to have shape ({n},), got {a.shape}.")
    if a.ndim == 0 or a.shape[-1] != n:
        raise BadArgument(f"Expected `{name}` to have shape (..., {n}), got {a.shape}.")
    if not np.isfinite(a).all():
        raise BadArgument(f"Expected `{name}` to be finite, got {a[~np.isfinite(a)][0]}.")
    return a


def _as_times(times, n: int, like: str) -> np.ndarray | None:
    """Validate optional sample times (used in messages only) as shape (n,) or None."""
    if times is None:
        return None
    try:
        t = np.asarray(times, dtype=float)
    except (TypeError, ValueError) as e:
        raise TypeError(f"Expected `times` to be numeric, got {type(times).__name__}.") from e
    if t.shape != (n,):
        raise BadArgument(f"Expected `times` to have shape ({n},) like `{like}`, got {t.shape}.")
    return t


def forward(angles) -> np.ndarray:
    """Orientation of the gimbal at the given joint angles.

    Parameters
    ----------
    angles : array_like, shape (..., 3)
        ``(pan, tilt, roll)`` in rad.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternions ``(w, x, y, z)`` of ``Rz(pan) Ry(tilt) Rx(roll)``.

    Raises
    ------
    TypeError
        If ``angles`` is not numeric.
    ValueError
        If the last axis is not of length 3 or a value is not finite.
    """
    a = as_angles(angles)
    return quat.from_pan_tilt_roll(a[..., 0], a[..., 1], a[..., 2])


def jacobian(angles) -> np.ndarray:
    """Space-frame Jacobian ``J`` with ``omega = J @ qd``.

    Its columns are the joint axes in the space frame: ``z``, ``Rz(pan) y`` and
    ``Rz(pan) Ry(tilt) x``. ``det J = -cos(tilt)``, so it is singular only at
    gimbal lock.

    Parameters
    ----------
    angles : array_like, shape (..., 3)
        ``(pan, tilt, roll)`` in rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Unitless (rad/s of rotation per rad/s of joint).

    Raises
    ------
    TypeError
        If ``angles`` is not numeric.
    ValueError
        If the last axis is not of length 3 or a value is not finite.
    """
    a = as_angles(angles)
    cp, sp = np.cos(a[..., 0]), np.sin(a[..., 0])
    ct, st = np.cos(a[..., 1]), np.sin(a[..., 1])
    zero, one = np.zeros_like(cp), np.ones_like(cp)
    pan_axis = np.stack([zero, zero, one], axis=-1)
    tilt_axis = np.stack([-sp, cp, zero], axis=-1)
    roll_axis = np.stack([cp * ct, sp * ct, -st], axis=-1)
    return np.stack([pan_axis, tilt_axis, roll_axis], axis=-1)


def _solve(cp, sp, ct, st, wx, wy, wz):
    """Closed-form ``J^-1 w``, componentwise, given cos/sin of pan and tilt."""
    roll_rate = (cp * wx + sp * wy) / ct
    tilt_rate = cp * wy - sp * wx
    return wz + st * roll_rate, tilt_rate, roll_rate


def rates_of(cp, sp, ct, st, omega, alpha):
    """Joint velocities and accelerations ``(vp, vt, vr), (ap, at, ar)`` from the cos/sin of
    pan and tilt and the components of omega and alpha: plain arithmetic, shared by
    :func:`joint_rates` (arrays) and the per-frame stream (floats, :mod:`trajgen.frame_eval`).
    """
    vp, vt, vr = _solve(cp, sp, ct, st, *omega)
    # Jdot qd = vp vt (z x y1) + vr (vp z + vt y1) x x2 with the joint axes
    # z, y1, x2 of `jacobian`: the tilt axis y1 turns with pan, the roll axis x2
    # with both. z x y1 = (-cp, -sp, 0), z x x2 = (-sp ct, cp ct, 0) and
    # y1 x x2 = -(cp st, sp st, ct).
    jx = -vp * vt * cp - vr * (vp * sp * ct + vt * cp * st)
    jy = -vp * vt * sp + vr * (vp * cp * ct - vt * sp * st)
    jz = -vr * vt * ct
    ax, ay, az = alpha
    return (vp, vt, vr), _solve(cp, sp, ct, st, ax - jx, ay - jy, az - jz)


def joint_rates(angles, omega, alpha) -> tuple[np.ndarray, np.ndarray]:
    """Joint velocities and accelerations, exactly, from the angular motion.

    Solves ``omega = J(q) qd`` and ``alpha = J(q) qdd + Jdot(q, qd) qd`` in
    closed form (see :func:`jacobian`); no differencing of samples.

    Parameters
    ----------
    angles : array_like, shape (..., 3)
        Joint angles ``(pan, tilt, roll)`` (rad), away from gimbal lock.
    omega : array_like, shape (..., 3)
        Space-frame angular velocity (rad/s), ``2 (dq/dt) q*``.
    alpha : array_like, shape (..., 3)
        Space-frame angular acceleration (rad/s^2), the time derivative of ``omega``.

    Returns
    -------
    qd : ndarray, shape (..., 3)
        Joint velocities (rad/s).
    qdd : ndarray, shape (..., 3)
        Joint accelerations (rad/s^2).

    Raises
    ------
    TypeError
        If an argument is not numeric.
    ValueError
        If the shapes differ or are not (..., 3), or a value is not finite.
    KinematicsError
        If ``|tilt|`` is pi/2 (gimbal lock, where ``J`` is singular).
    """
    a = as_angles(angles)
    w = as_angles(omega, "omega")
    dw = as_angles(alpha, "alpha")
    if not a.shape == w.shape == dw.shape:
        raise BadArgument(
            "Expected `angles`, `omega` and `alpha` to have the same shape, "
            f"got {a.shape}, {w.shape}, {dw.shape}."
        )
    locked = np.abs(np.cos(a[..., 1])) < 1e-12
    if locked.any():
        i = tuple(int(k) for k in np.argwhere(locked)[0])
        raise KinematicsError(
            f"joint rates are undefined at gimbal lock: |tilt| = 90 deg at index {i}"
        )
    cp, sp = np.cos(a[..., 0]), np.sin(a[..., 0])
    ct, st = np.cos(a[..., 1]), np.sin(a[..., 1])
    (vp, vt, vr), (ap, at, ar) = rates_of(
        cp, sp, ct, st, np.moveaxis(w, -1, 0), np.moveaxis(dw, -1, 0)
    )
    qd = np.stack([vp, vt, vr], axis=-1)
    qdd = np.stack([ap, at, ar], axis=-1)
    return qd, qdd


@dataclass(frozen=True)
class GimbalKinematics:
    """Axes, joint limits and lock margin of a gimbal, and its inverse kinematics.

    Parameters
    ----------
    limits_rad : array_like, shape (n, 2), optional
        ``(low, high)`` joint limits (rad), one row per joint; default
        :data:`DEFAULT_LIMITS_RAD` for ``"zyx"`` (pan +-2 pi, tilt +-pi/2, roll
        +-pi), else :meth:`trajgen.axes.AxisSequence.default_limits`. The middle
        joint's limits must lie within its range (``[-pi/2, pi/2]``, or ``[0, pi]``
        for a proper Euler sequence). Stored as a tuple of ``(low, high)`` float pairs.
    lock_margin_rad : float
        How close (rad) the middle angle may come to gimbal lock; default 10 deg.
        In (0, pi/2).
    axes : str
        The axis sequence (:mod:`trajgen.axes`): ``"zyx"`` (default, pan-tilt-roll
        ``Rz Ry Rx``), any 2 or 3 of x, y, z with neighbours different. Lock:
        Tait-Bryan (three different axes) and two-axis sequences at middle angle
        +-90 deg, proper Euler (``"zxz"``...) at 0 or 180 deg.
    joints : sequence of str, optional
        Joint names, one per axis (default ``pan, tilt, roll`` for ``"zyx"``,
        ``pan, tilt`` for ``"zy"``, else ``joint1, ...``).

    Raises
    ------
    TypeError
        If an argument is not numeric (or ``axes``, ``joints`` not strings).
    ValueError
        If ``limits_rad`` is not (n, 2), not finite, has ``low >= high``, middle
        limits outside the middle range, ``lock_margin_rad`` is outside (0, pi/2),
        or ``axes`` / ``joints`` are not a valid sequence and names.
    """

    limits_rad: tuple[tuple[float, float], ...] | None = None
    lock_margin_rad: float = math.radians(10.0)
    axes: str = DEFAULT_SEQUENCE
    joints: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        seq = AxisSequence(self.axes, self.joints)
        object.__setattr__(self, "axes", seq.sequence)
        object.__setattr__(self, "joints", seq.joints)
        object.__setattr__(self, "_seq", seq)  # derived, not a field
        limits = seq.default_limits() if self.limits_rad is None else self.limits_rad
        try:
            lim = np.array(limits, dtype=float)
        except (TypeError, ValueError) as e:
            raise TypeError(
                f"Expected `limits_rad` to be numeric, got {type(limits).__name__}."
            ) from e
        if lim.shape != (seq.n, 2):
            raise BadArgument(f"Expected `limits_rad` to have shape ({seq.n}, 2), got {lim.shape}.")
        if not np.isfinite(lim).all():
            raise BadArgument(f"Expected `limits_rad` to be finite, got {lim.tolist()}.")
        for name, (low, high) in zip(seq.joints, lim, strict=True):
            if not low < high:
                raise BadArgument(
                    f"Expected `limits_rad` {name} low < high, got [{low:.6g}, {high:.6g}] rad."
                )
        m_low, m_high = seq.middle_range
        if lim[1, 0] < m_low or lim[1, 1] > m_high:
            span = "[0, pi]" if seq.kind == "proper-euler" else "[-pi/2, pi/2]"
            raise BadArgument(
                f"Expected `limits_rad` {seq.joints[1]} within {span}, "
                f"got [{lim[1, 0]:.6g}, {lim[1, 1]:.6g}] rad."
            )
        margin = check_number(
            "lock_margin_rad",
            self.lock_margin_rad,
            low=0.0,
            high=math.pi / 2,
            low_open=True,
            high_open=True,
        )
        object.__setattr__(self, "limits_rad", tuple((float(lo), float(hi)) for lo, hi in lim))
        object.__setattr__(self, "lock_margin_rad", float(margin))

    @property
    def sequence(self) -> AxisSequence:
        """The parsed axis sequence (:class:`trajgen.axes.AxisSequence`)."""
        return self._seq

    @property
    def n_joints(self) -> int:
        """Number of joints, 2 or 3."""
        return self._seq.n

    @property
    def is_default(self) -> bool:
        """Whether the axes are ``"zyx"``, served by this module's closed forms."""
        return self.axes == DEFAULT_SEQUENCE

    def forward(self, angles) -> np.ndarray:
        """Orientations (..., 4) at joint angles (..., n) (rad); :func:`forward` for ``"zyx"``."""
        if self.is_default:
            return forward(angles)
        return self._seq.forward(as_angles(angles, n=self.n_joints))

    def look_direction(self, angles) -> np.ndarray:
        """Space-frame camera look direction (..., 3) at joint angles (..., n) (rad):
        the body x axis for three axes, :attr:`trajgen.axes.AxisSequence.look` for two."""
        return quat.rotate(self.forward(angles), self._seq.look)

    def jacobian(self, angles) -> np.ndarray:
        """Space-frame joint axes as columns (..., 3, n), ``omega = J qd`` of the
        gimbal's own motion; :func:`jacobian` for ``"zyx"``."""
        if self.is_default:
            return jacobian(angles)
        return self._seq.joint_axes(as_angles(angles, n=self.n_joints))

    def joint_rates(self, angles, omega, alpha) -> tuple[np.ndarray, np.ndarray]:
        """Joint velocities and accelerations (..., n), exactly; :func:`joint_rates` for
        ``"zyx"``, :meth:`trajgen.axes.AxisSequence.joint_rates` otherwise (for two
        axes: the rates that move the look direction as ``omega``, ``alpha`` do).

        Raises
        ------
        KinematicsError
            At gimbal lock (middle angle exactly at a lock), where the rates are undefined.
        """
        if self.is_default:
            return joint_rates(angles, omega, alpha)
        seq = self._seq
        a = as_angles(angles, n=seq.n)
        w = as_angles(omega, "omega")
        dw = as_angles(alpha, "alpha")
        if not a.shape[:-1] + (3,) == w.shape == dw.shape:
            raise BadArgument(
                "Expected `angles`, `omega` and `alpha` to have the same leading shape, "
                f"got {a.shape}, {w.shape}, {dw.shape}."
            )
        low, high = seq.locks
        locked = np.abs(np.sin(a[..., 1] - low)) < 1e-12
        if locked.any():
            i = tuple(int(k) for k in np.argwhere(locked)[0])
            lock = "0 or 180" if seq.kind == "proper-euler" else "90"
            raise KinematicsError(
                f"joint rates are undefined at gimbal lock: |{seq.joints[1]}| = {lock} deg "
                f"at index {i}"
            )
        return seq.joint_rates(a, w, dw)

    def angles(self, quats) -> np.ndarray:
        """Closed-form joint angles (N, n) of orientations (N, 4), before unwrapping:
        the middle angle in its range, the others in (-pi, pi]. For two axes the
        angles pointing the look axis along ``q look``, exactly."""
        q = quat.as_quats(quats)
        return _closed_form(q) if self.is_default else self._seq.angles(q)

    def inverse(self, quats, times=None, *, start=None) -> np.ndarray:
        """Continuous joint path through the given orientations.

        Closed form per sample (the middle angle in ``[-pi/2, pi/2]``, or ``[0, pi]``
        for proper Euler axes, the branch its limits allow; for two axes the
        angles that point the look axis along each orientation's, exactly), then
        the other joints (pan and roll for ``"zyx"``) are unwrapped sample to
        sample: each sample takes the 2 pi multiple nearest the one before, and
        the first the one nearest ``start``. ``q`` and ``-q`` give the same angles.

        Parameters
        ----------
        quats : array_like, shape (N, 4)
            Orientations ``(w, x, y, z)``, dense enough that the wrapped joints
            move less than pi between samples.
        times : array_like, shape (N,), optional
            Sample times (s), only for error messages (else sample numbers).
        start : array_like, shape (n,), optional
            Angles (rad), e.g. the servos' present position: the first sample's
            wrapped joints take the 2 pi multiples nearest these. Default: the
            first sample's in (-pi, pi].

        Returns
        -------
        ndarray, shape (N, n)
            Joint angles (rad), ``(pan, tilt, roll)`` for ``"zyx"``.

        Raises
        ------
        KinematicsError
            If a sample comes within ``lock_margin_rad`` of gimbal lock or
            leaves the joint limits. The message names the first such sample's
            time, the joint, its angle and the limit, e.g. "tilt reaches 84.2 deg
            at t = 3.140 s, within 10.0 deg of gimbal lock (limit 80.0 deg)".
        TypeError
            If an argument is not numeric.
        ValueError
            If a shape is wrong or a value is not finite.
        """
        q = quat.as_quats(quats)
        times = _as_times(times, len(q), "quats")
        angles = self.angles(q)
        # Whole turns added to the wrapped joints: integer counts, so the online
        # stream (one sample at a time, start = previous sample) agrees exactly.
        cols = list(self._seq.wrapped)
        wrapped = angles[:, cols]
        turns = np.zeros_like(wrapped)
        turns[1:] = np.round((wrapped[:-1] - wrapped[1:]) / TWO_PI)
        if start is not None:
            s = as_angles(start, "start", single=True, n=self.n_joints)
            turns[0] = np.round((s[cols] - wrapped[0]) / TWO_PI)
        angles[:, cols] = wrapped + TWO_PI * np.cumsum(turns, axis=0)
        self.check(angles, times)
        return angles

    def check(self, angles, times=None) -> None:
        """Raise if a joint path comes near gimbal lock or leaves the limits.

        Parameters
        ----------
        angles : array_like, shape (N, n)
            Joint angles (rad).
        times : array_like, shape (N,), optional
            Sample times (s) for the message (else sample numbers).

        Raises
        ------
        KinematicsError
            At the first offending sample; gimbal lock is reported before a
            limit, and joints in their order.
        TypeError
            If ``angles`` is not numeric.
        ValueError
            If ``angles`` is not (N, n) or not finite.
        """
        n, names = self.n_joints, self.joints
        a = as_angles(angles, n=n)
        if a.ndim != 2:
            raise BadArgument(f"Expected `angles` to have shape (N, {n}), got {a.shape}.")
        times = _as_times(times, len(a), "angles")
        margin = self.lock_margin_rad
        if self._seq.kind == "proper-euler":
            locked = (a[:, 1] < margin) | (a[:, 1] > math.pi - margin)
        else:
            locked = np.abs(a[:, 1]) > math.pi / 2 - margin
        lim = np.array(self.limits_rad)
        outside = (a < lim[:, 0]) | (a > lim[:, 1])
        bad = locked | outside.any(axis=1)
        if not bad.any():
            return
        i = int(np.argmax(bad))
        when = f"t = {times[i]:.3f} s" if times is not None else f"sample {i}"
        deg = np.degrees
        if locked[i]:
            if self._seq.kind == "proper-euler":
                limit = margin if a[i, 1] < math.pi / 2 else math.pi - margin
            else:
                limit = math.copysign(math.pi / 2 - margin, a[i, 1])
            raise KinematicsError(
                f"{names[1]} reaches {deg(a[i, 1]):.1f} deg at {when}, within "
                f"{deg(margin):.1f} deg of gimbal lock (limit {deg(limit):.1f} deg)"
            )
        j = int(np.argmax(outside[i]))
        low, high = deg(lim[j])
        raise KinematicsError(
            f"{names[j]} reaches {deg(a[i, j]):.1f} deg at {when}, "
            f"outside its limits [{low:.1f}, {high:.1f}] deg"
        )


def _closed_form(q: np.ndarray) -> np.ndarray:
    """``(pan, tilt, roll)`` of unit quaternions (N, 4); pan, roll in (-pi, pi].

    Uses the rotation-matrix entries, which are quadratic in ``q``, so ``q`` and
    ``-q`` agree.
    """
    w, x, y, z = q.T
    return np.stack(angles_of(w, x, y, z, np.arctan2, np.hypot), axis=-1)


def angles_of(w, x, y, z, atan2, hypot) -> tuple:
    """``(pan, tilt, roll)`` of a unit quaternion's components; pan, roll in (-pi, pi].

    Plain arithmetic on the rotation-matrix entries (quadratic in ``q``, so ``q``
    and ``-q`` agree), with ``atan2`` and ``hypot`` given: ``np.arctan2``,
    ``np.hypot`` for arrays (:func:`_closed_form`), ``math.atan2``, ``math.hypot``
    for the floats of one frame (:mod:`trajgen.frame_eval`).
    """
    r00 = 1.0 - 2.0 * (y * y + z * z)
    r10 = 2.0 * (x * y + w * z)
    r20 = 2.0 * (x * z - w * y)
    r21 = 2.0 * (y * z + w * x)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    return atan2(r10, r00), atan2(-r20, hypot(r21, r22)), atan2(r21, r22)
