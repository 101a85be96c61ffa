"""Unit quaternion algebra, vectorised over leading axes.

Every quaternion here is scalar first, ``(w, x, y, z)``, shape ``(..., 4)``,
Hamilton product, rotating a vector ``v`` as ``q v q*`` (as in MuJoCo and in
Kim & Nam 1995). ``q`` and ``-q`` are the same orientation.
"""

from __future__ import annotations

import numpy as np

from .errors import BadArgument

#: Below this rotation angle (rad) ``exp`` and ``log`` use their Taylor series.
SMALL_ANGLE = 1e-4


def as_quats(quats, name: str = "quats") -> np.ndarray:
    """Validate and normalise quaternions.

    Parameters
    ----------
    quats : array_like, shape (N, 4), or scipy.spatial.transform.Rotation
        Scalar-first quaternions of any sign and non-zero norm, or a scipy
        ``Rotation`` (converted from scipy's scalar-last order here; scipy is
        not imported).
    name : str
        Argument name used in error messages.

    Returns
    -------
    ndarray, shape (N, 4)
        Unit quaternions, float64.

    Raises
    ------
    TypeError
        If ``quats`` is not numeric.
    ValueError
        If the shape is not (N, 4), a value is not finite, or a row has zero norm.
    """
    if _is_scipy_rotation(quats):
        quats = np.roll(np.atleast_2d(quats.as_quat()), 1, axis=-1)  # (x, y, z, w) -> (w, x, y, z)
    try:
        q = np.asarray(quats, dtype=float)
    except (TypeError, ValueError) as e:
        raise TypeError(f"Expected `{name}` to be numeric, got {type(quats).__name__}.") from e
    if q.ndim != 2 or q.shape[1] != 4:
        raise BadArgument(f"Expected `{name}` to have shape (N, 4), got {q.shape}.")
    bad = ~np.isfinite(q).all(axis=1)
    if bad.any():
        raise BadArgument(f"`{name}` row {int(np.argmax(bad))} is not finite: {q[bad][0]}.")
    norm = np.hypot.reduce(q, axis=1)  # no overflow for rows of 1e300 (as their squares would)
    if (norm < 1e-12).any():
        raise BadArgument(f"`{name}` row {int(np.argmax(norm < 1e-12))} has zero norm.")
    return q / norm[:, None]


def _is_scipy_rotation(obj) -> bool:
    """True for a ``scipy.spatial.transform.Rotation``, without importing scipy."""
    cls = type(obj)
    return cls.__name__ == "Rotation" and cls.__module__.startswith("scipy.spatial.transform")


def mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p q``; shapes (..., 4) broadcast."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, dtype=float), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion); shape (..., 4)."""
    return np.asarray(q, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])


def exp(v: np.ndarray) -> np.ndarray:
    """Map a 3-vector ``a n`` (|n| = 1) to the unit quaternion ``(cos a, sin a n)``.

    Note the convention of the paper: the rotation angle of the result is ``2 a``.
    Shapes: (..., 3) -> (..., 4).
    """
    v = np.asarray(v, dtype=float)
    a = np.linalg.norm(v, axis=-1)
    small = a < SMALL_ANGLE
    a_safe = np.where(small, 1.0, a)
    sinc = np.where(small, 1.0 - a * a / 6.0, np.sin(a_safe) / a_safe)
    return np.concatenate([np.cos(a)[..., None], sinc[..., None] * v], axis=-1)


def log(q: np.ndarray) -> np.ndarray:
    """Inverse of :func:`exp` for unit quaternions: ``(cos a, sin a n) -> a n``.

    Uses ``atan2`` (stable at the identity). The result has ``|a| <= pi``; for
    ``w < 0`` it is the long way round, as the signed quaternion says.
    Shapes: (..., 4) -> (..., 3).
    """
    q = np.asarray(q, dtype=float)
    w = q[..., 0]
    xyz = q[..., 1:]
    s = np.linalg.norm(xyz, axis=-1)
    a = np.arctan2(s, w)
    # a / sin(a); near the identity its series 1 + s^2/6 (|q| = 1). Near -1
    # (a full turn) the direction is undefined and the result is finite but large.
    small = (s < SMALL_ANGLE) & (w > 0)
    scale = np.where(small, 1.0 + s * s / 6.0, a / np.where(small, 1.0, np.maximum(s, 1e-300)))
    return scale[..., None] * xyz


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4): ``q v q*``."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + q[..., :1] * t + np.cross(u, t)


def slerp(p: np.ndarray, q: np.ndarray, f) -> np.ndarray:
    """Point dividing the S^3 geodesic from ``p`` to ``q`` in ratio ``f : 1 - f``.

    Signed: no hemisphere flip, so ``slerp(p, -p, f)`` goes the long way.
    Shapes (..., 4), (..., 4), (...) broadcast.
    """
    f = np.asarray(f, dtype=float)
    return mul(exp(f[..., None] * log(mul(q, conj(p)))), p)


def from_axis_angle(axis, angle) -> np.ndarray:
    """Quaternion of a rotation by ``angle`` (rad) about unit ``axis`` (..., 3)."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    return exp(0.5 * angle[..., None] * axis)


def from_pan_tilt_roll(pan, tilt, roll) -> np.ndarray:
    """``q = Rz(pan) Ry(tilt) Rx(roll)`` (intrinsic z-y'-x''); angles in rad, shape (...)."""
    pan, tilt, roll = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (pan, tilt, roll)))
    cz, sz = np.cos(pan / 2), np.sin(pan / 2)
    cy, sy = np.cos(tilt / 2), np.sin(tilt / 2)
    cx, sx = np.cos(roll / 2), np.sin(roll / 2)
    return np.stack(
        [
            cz * cy * cx + sz * sy * sx,
            cz * cy * sx - sz * sy * cx,
            cz * sy * cx + sz * cy * sx,
            sz * cy * cx - cz * sy * sx,
        ],
        axis=-1,
    )


def distance(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, in [0, pi]) between orientations; ``q`` and ``-q`` equal."""
    d = mul(conj(p), q)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))
