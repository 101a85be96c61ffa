"""Gimbal axis sequences: 2 or 3 rotation axes from x, y, z, in any order.

A sequence such as ``"zyx"`` names the joint axes from the base out: the
orientation is ``q = R_a(theta_1) R_b(theta_2) [R_c(theta_3)]``, each joint turning
about its axis as carried by the joints before it (intrinsic rotations, so
``"zyx"`` is today's pan-tilt-roll ``Rz(pan) Ry(tilt) Rx(roll)``). Neighbouring
axes must differ. Three kinds, each with its lock (singularity) condition, where
the joint rates for a finite angular velocity grow without bound:

- **Tait-Bryan** (three different axes, ``"zyx"``, ``"xyz"``, ...): the middle
  angle is kept in ``[-pi/2, pi/2]``; lock at ``theta_2 = +-pi/2`` (first and last
  axes line up).
- **Proper Euler** (first axis = last, ``"zxz"``, ``"zyz"``, ...): the middle angle
  is kept in ``[0, pi]``; lock at ``theta_2 = 0`` or ``pi``.
- **Two axes** (``"zy"`` pan-tilt, ``"yx"`` flex-roll, ...): cannot hold every
  orientation, only point. The camera looks along the body axis perpendicular to
  both joint axes (:attr:`AxisSequence.look`, the positive third axis: ``x`` for
  ``"zy"``, ``z`` for ``"yx"``). The look direction ``d = q look`` reaches the whole
  sphere; the second angle is kept in ``[-pi/2, pi/2]``; lock at ``theta_2 = +-pi/2``
  (looking along the first axis). The inverse kinematics of an orientation is that
  of its look direction, exactly; the turn about the look axis an orientation may
  have besides is not a joint and is left out (it does not change the pointing).

Angles in rad; quaternions scalar first ``(w, x, y, z)``; vectors in the space
(base) frame unless named body. First (and for three axes last) angles come out
of the closed forms in ``(-pi, pi]``; unwrapping is
:meth:`trajgen.gimbal.GimbalKinematics.inverse`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import quat
from .errors import BadArgument

AXIS_LETTERS = "xyz"

#: Joint names given when a file names none: the default pan-tilt-roll, else
#: ``joint1``, ``joint2``, ...
DEFAULT_SEQUENCE = "zyx"
DEFAULT_JOINTS = {"zyx": ("pan", "tilt", "roll"), "zy": ("pan", "tilt")}

TWO_PI = 2.0 * math.pi


def _unit(i: int) -> np.ndarray:
    e = np.zeros(3)
    e[i] = 1.0
    return e


@dataclass(frozen=True)
class AxisSequence:
    """A parsed axis sequence and its joint names.

    Parameters
    ----------
    sequence : str
        2 or 3 letters from ``x``, ``y``, ``z`` (case-insensitive), neighbours
        different; default ``"zyx"``.
    joints : sequence of str, optional
        One distinct, non-empty name per axis; default :data:`DEFAULT_JOINTS` or
        ``("joint1", ...)``.

    Raises
    ------
    TypeError
        If ``sequence`` is not a string or a joint name is not.
    ValueError
        If the sequence is not 2 or 3 axes from x, y, z with neighbours
        different, or the names are not one distinct non-empty name per axis.
    """

    sequence: str = DEFAULT_SEQUENCE
    joints: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        s = self.sequence
        if not isinstance(s, str):
            raise TypeError(f"Expected `axes` to be a string like 'zyx', got {type(s).__name__}.")
        s = s.lower()
        if not (2 <= len(s) <= 3 and all(c in AXIS_LETTERS for c in s)):
            raise BadArgument(
                f"Expected `axes` to be 2 or 3 letters from x, y, z (e.g. 'zyx', 'zy'), got {s!r}."
            )
        for a, b in zip(s, s[1:], strict=False):
            if a == b:
                raise BadArgument(
                    f"Expected `axes` {s!r} to turn about different axes in neighbouring "
                    f"joints, got {a}{b}."
                )
        names = self.joints
        if names is None:
            names = DEFAULT_JOINTS.get(s, tuple(f"joint{i + 1}" for i in range(len(s))))
        if isinstance(names, str) or not all(isinstance(n, str) for n in names):
            raise TypeError(f"Expected `joints` to be a list of names, got {names!r}.")
        names = tuple(names)
        if len(names) != len(s):
            raise BadArgument(
                f"Expected `joints` to name the {len(s)} axes of {s!r}, got {len(names)}: "
                f"{list(names)}."
            )
        if len(set(names)) != len(names) or not all(names):
            raise BadArgument(
                f"Expected `joints` to be distinct non-empty names, got {list(names)}."
            )
        object.__setattr__(self, "sequence", s)
        object.__setattr__(self, "joints", names)

    # ---------------------------------------------------------------- facts
    @property
    def indices(self) -> tuple[int, ...]:
        """Axis indices (0 = x, 1 = y, 2 = z) from the base out."""
        return tuple(AXIS_LETTERS.index(c) for c in self.sequence)

    @property
    def n(self) -> int:
        """Number of joints, 2 or 3."""
        return len(self.sequence)

    @property
    def kind(self) -> str:
        """``"tait-bryan"``, ``"proper-euler"`` or ``"two-axis"``."""
        if self.n == 2:
            return "two-axis"
        return "proper-euler" if self.sequence[0] == self.sequence[2] else "tait-bryan"

    @property
    def middle_range(self) -> tuple[float, float]:
        """The range (rad) the inverse kinematics keeps the middle (second) angle in."""
        return (0.0, math.pi) if self.kind == "proper-euler" else (-math.pi / 2, math.pi / 2)

    @property
    def locks(self) -> tuple[float, float]:
        """Middle (second) angles (rad) at gimbal lock: the ends of :attr:`middle_range`."""
        return self.middle_range

    @property
    def wrapped(self) -> tuple[int, ...]:
        """Joints whose angle is free modulo 2 pi (unwrapped): all but the middle one."""
        return (0, 2) if self.n == 3 else (0,)

    @property
    def look(self) -> np.ndarray:
        """Body look axis of a two-axis gimbal: the positive axis perpendicular to both,
        shape (3,). (A three-axis gimbal's camera looks along its body x.)"""
        if self.n == 3:
            return _unit(0)
        (third,) = set(range(3)) - set(self.indices)
        return _unit(third)

    def default_limits(self) -> tuple[tuple[float, float], ...]:
        """Joint limits (rad): wrapped joints one turn either way for the first, half a
        turn for the last (three axes); the middle joint its whole :attr:`middle_range`."""
        first = (-TWO_PI, TWO_PI)
        if self.n == 2:
            return (first, self.middle_range)
        return (first, self.middle_range, (-math.pi, math.pi))

    # ---------------------------------------------------------------- kinematics
    def _check(self, angles, name: str = "angles") -> np.ndarray:
        a = np.asarray(angles, dtype=float)
        if a.ndim == 0 or a.shape[-1] != self.n:
            raise BadArgument(f"Expected `{name}` to have shape (..., {self.n}), got {a.shape}.")
        return a

    def partial(self, angles, k: int) -> np.ndarray:
        """Orientation (..., 4) of the first ``k`` joints, ``R_a(theta_1) ... `` (k factors)."""
        a = self._check(angles)
        q = np.zeros((*a.shape[:-1], 4))
        q[..., 0] = 1.0
        for j, axis in enumerate(self.indices[:k]):
            q = quat.mul(q, quat.from_axis_angle(_unit(axis), a[..., j]))
        return q

    def forward(self, angles) -> np.ndarray:
        """Orientation of the gimbal at the given joint angles.

        Parameters
        ----------
        angles : array_like, shape (..., n)
            Joint angles (rad), ``n`` = 2 or 3.

        Returns
        -------
        ndarray, shape (..., 4)
            Unit quaternions ``(w, x, y, z)`` of the product of the axis rotations.
        """
        return self.partial(angles, self.n)

    def look_direction(self, angles) -> np.ndarray:
        """Space-frame look direction ``q look`` (..., 3), unit, at the joint angles."""
        return quat.rotate(self.forward(angles), self.look)

    def joint_axes(self, angles) -> np.ndarray:
        """Space-frame joint axes as columns, shape (..., 3, n): ``omega = J @ qd``."""
        a = self._check(angles)
        cols = []
        for k, axis in enumerate(self.indices):
            e = np.broadcast_to(_unit(axis), (*a.shape[:-1], 3))
            cols.append(quat.rotate(self.partial(a, k), e) if k else e.copy())
        return np.stack(cols, axis=-1)

    def angles(self, q: np.ndarray) -> np.ndarray:
        """Closed-form joint angles (N, n) of unit quaternions (N, 4), ``q`` and ``-q``
        alike; the middle angle in :attr:`middle_range`, the others in (-pi, pi].

        For two axes: the angles that point :attr:`look` along ``q look`` (exact).
        """
        w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
        r = matrix_entries(w, x, y, z)
        return np.stack(angles_of_matrix(self, r, np.arctan2, np.hypot), axis=-1)

    def lock_distance(self, angles: np.ndarray) -> np.ndarray:
        """How far (rad) the middle angle of each row of ``angles`` (N, n) is from lock."""
        low, high = self.locks
        m = angles[..., 1]
        return np.minimum(m - low, high - m)

    def joint_rates(self, angles, omega, alpha) -> tuple[np.ndarray, np.ndarray]:
        """Joint velocities and accelerations (..., n), exactly, from the angular motion.

        Three axes: ``omega = J qd``, ``alpha = J qdd + Jdot qd`` with ``J`` the
        :meth:`joint_axes`, solved by cross products (``J^-1`` rows ``e2 x e3``,
        ``e3 x e1``, ``e1 x e2`` over ``det J``). Two axes: the rates that move the
        look direction ``d`` as ``omega`` and ``alpha`` move it, ``dd = omega x d``,
        ``ddd = alpha x d + omega x dd``; the part of ``omega`` about ``d`` is no
        joint's and drops out. Singular only at lock (``det J`` or ``|e1 x d|`` zero).

        Parameters
        ----------
        angles : ndarray, shape (..., n)
            Joint angles (rad), as :meth:`angles` gives them for the path's orientation.
        omega, alpha : ndarray, shape (..., 3)
            Space-frame angular velocity (rad/s) and acceleration (rad/s^2).
        """
        a = self._check(angles)
        e = [_components(col) for col in np.moveaxis(self.joint_axes(a), -1, 0)]
        d = _components(self.look_direction(a)) if self.n == 2 else None
        w = np.asarray(omega, dtype=float)
        al = np.asarray(alpha, dtype=float)
        qd, qdd = rates_of_axes(e, d, _components(w), _components(al))
        return np.stack(np.broadcast_arrays(*qd), axis=-1), np.stack(
            np.broadcast_arrays(*qdd), axis=-1
        )


def _components(v: np.ndarray) -> tuple:
    """The three components of vectors (..., 3), each (...)."""
    return v[..., 0], v[..., 1], v[..., 2]


def _cross(u, v) -> tuple:
    """``u x v`` of vectors given as three components (floats or arrays alike)."""
    u0, u1, u2 = u
    v0, v1, v2 = v
    return u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _combine(*terms) -> tuple:
    """``sum(c * v)`` of ``(c, v)`` pairs, vectors as three components."""
    return tuple(sum(c * v[k] for c, v in terms) for k in range(3))


def rates_of_axes(e, d, omega, alpha) -> tuple[tuple, tuple]:
    """Joint velocities and accelerations from the space-frame joint axes, exactly.

    The formulas of :meth:`AxisSequence.joint_rates`, on vectors given as three
    components: floats for one frame (:mod:`trajgen.frame_eval`) or arrays.

    Parameters
    ----------
    e : sequence of n vectors
        The joint axes ``e_1 .. e_n`` (space frame, unit), n = 2 or 3.
    d : vector or None
        Two axes: the look direction (unit); three axes: unused.
    omega, alpha : vector
        Angular velocity (rad/s) and acceleration (rad/s^2), space frame.

    Returns
    -------
    (tuple, tuple)
        ``qd`` (rad/s) and ``qdd`` (rad/s^2), n components each.
    """
    if len(e) == 2:
        e0, e1 = e
        g1, g2 = _cross(e0, d), _cross(e1, d)  # orthogonal; |g2| = 1
        n1 = _dot(g1, g1)
        dd = _cross(omega, d)
        v1, v2 = _dot(g1, dd) / n1, _dot(g2, dd)
        ddd = _combine((1.0, _cross(alpha, d)), (1.0, _cross(omega, dd)))
        de2 = _combine((v1, _cross(e0, e1)))
        turn = _combine((1.0, _cross(de2, d)), (1.0, _cross(e1, dd)))
        rest = _combine((1.0, ddd), (-v1, _cross(e0, dd)), (-v2, turn))
        return (v1, v2), (_dot(g1, rest) / n1, _dot(g2, rest))
    e0, e1, e2 = e
    rows = (_cross(e1, e2), _cross(e2, e0), _cross(e0, e1))
    det = _dot(e0, rows[0])
    v0, v1, v2 = (_dot(r, omega) / det for r in rows)
    carried = _combine((v0, e0), (v1, e1))
    jdot = _combine((v0 * v1, _cross(e0, e1)), (v2, _cross(carried, e2)))
    rest = _combine((1.0, alpha), (-1.0, jdot))
    return (v0, v1, v2), tuple(_dot(r, rest) / det for r in rows)


def angles_of_matrix(seq: AxisSequence, r, atan2, hypot) -> tuple:
    """Closed-form joint angles of a rotation matrix, as :meth:`AxisSequence.angles`.

    Parameters
    ----------
    seq : AxisSequence
    r : nested sequence, 3 x 3
        ``r[i][j]``, floats for one frame or arrays alike (:func:`matrix_entries`).
    atan2, hypot : callable
        ``math.atan2``, ``math.hypot`` for floats; ``np.arctan2``, ``np.hypot`` for arrays.

    Returns
    -------
    tuple
        The n angles (rad).
    """
    if seq.n == 2:
        a, b = seq.indices
        (c,) = set(range(3)) - {a, b}
        return _direction_angles(a, b, c, (r[0][c], r[1][c], r[2][c]), atan2, hypot)
    i, j, k = seq.indices
    if seq.kind == "tait-bryan":
        e = _parity(i, j, k)
        return (
            atan2(-e * r[j][k], r[k][k]),
            atan2(e * r[i][k], hypot(r[i][i], r[i][j])),
            atan2(-e * r[i][j], r[i][i]),
        )
    (k,) = set(range(3)) - {i, j}
    e = _parity(i, j, k)
    return (
        atan2(r[j][i], -e * r[k][i]),
        atan2(hypot(r[j][i], r[k][i]), r[i][i]),
        atan2(r[i][j], e * r[i][k]),
    )


def _parity(i: int, j: int, k: int) -> float:
    """+1 if ``(i, j, k)`` is a cyclic order of (0, 1, 2), else -1."""
    return 1.0 if (j - i) % 3 == 1 and (k - j) % 3 == 1 else -1.0


def matrix_entries(w, x, y, z) -> tuple:
    """Rotation matrix ``r[i][j]`` (nested tuples) of a unit quaternion's components,
    floats or arrays alike (quadratic in ``q``, so ``q`` and ``-q`` agree)."""
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def direction_angles(indices: tuple[int, int], d: np.ndarray) -> np.ndarray:
    """Joint angles (N, 2) of a two-axis gimbal ``(a, b)`` that point its look axis
    ``c`` (the third axis) along the unit directions ``d`` (N, 3), exactly.

    With ``s`` the parity of ``(a, b, c)``, ``R_a(t1) R_b(t2) c = s sin t2 a +
    cos t2 (cos t1 c - s sin t1 b)``, so ``t2 = atan2(s d_a, hypot(d_b, d_c))`` in
    ``[-pi/2, pi/2]`` and ``t1 = atan2(-s d_b, d_c)``.
    """
    a, b = indices
    (c,) = set(range(3)) - {a, b}
    d = np.asarray(d, dtype=float)
    return np.stack(_direction_angles(a, b, c, _components(d), np.arctan2, np.hypot), axis=-1)


def _direction_angles(a: int, b: int, c: int, d, atan2, hypot) -> tuple:
    """:func:`direction_angles` on a direction given as three components."""
    s = _parity(a, b, c)
    da, db, dc = d[a], d[b], d[c]
    return atan2(-s * db, dc), atan2(s * da, hypot(db, dc))
