"""Comparison methods for benchmarks (docs/algorithm.md §7); not defaults.

Each is an :class:`~trajgen.path.OrientationPath` built from ``(quats, times)``
with exact derivatives, so the simulator can race them on equal terms:

- :class:`PiecewiseSlerp` (C0): the geodesic between consecutive keyframes.
- :class:`Squad` (C1 for uniform times): Shoemake's spherical quadrangle.
- :class:`SphericalBezier` (C1 for uniform times): Shoemake's cubic Bezier,
  de Casteljau with slerps.
- :class:`PiecewiseCircles` (C1): circular arcs joined with a common tangent,
  the "circle methods" the paper criticises for the torque jump at each joint.
- :class:`ScipyRotationSpline` (C2, global): scipy's ``RotationSpline``; needs scipy.

References
----------
K. Shoemake, "Animating rotation with quaternion curves", SIGGRAPH 1985.
K. Shoemake, "Quaternion calculus for animation", SIGGRAPH course notes, 1991.
"""

from __future__ import annotations

import numpy as np

from . import jet as J
from . import quat as Q
from .errors import BadArgument
from .path import FRAMES, OrientationPath, Samples, check_times
from .validate import check_choice

__all__ = ["PiecewiseSlerp", "Squad", "SphericalBezier", "PiecewiseCircles", "ScipyRotationSpline"]


def _signed_keys(quats, times) -> tuple[np.ndarray, np.ndarray]:
    """Validated keyframes, signs walked so neighbours are on one hemisphere (algorithm.md §1)."""
    q = Q.as_quats(quats, "quats")
    if len(q) < 2:
        raise BadArgument(f"Expected at least 2 keyframes, got {len(q)}.")
    t = check_times(times, len(q))
    for i in range(1, len(q)):
        if q[i] @ q[i - 1] < 0:
            q[i] = -q[i]
    return q, t


def _slerp(p, r, f: J.Jet) -> J.Jet:
    """Geodesic from ``p`` to ``r`` (jets (K+1, 4, M) or constants (4, M)) at fraction ``f``."""
    if isinstance(p, J.Jet) or isinstance(r, J.Jet):
        rel = J.qlog(J.qmul(r, _conj(p)))
    else:
        rel = Q.log(Q.mul(r.T, Q.conj(p.T))).T
    return J.qmul(J.qexp(J.scale(f, rel)), p)


def _conj(q):
    return J.qconj(q) if isinstance(q, J.Jet) else Q.conj(q.T).T


class _Keyed(OrientationPath):
    def __init__(self, quats, times):
        self.quats, self.times = _signed_keys(quats, times)

    def _u(self, t, seg, order) -> J.Jet:
        h = self.times[seg + 1] - self.times[seg]
        return (J.Jet.variable(t, order) - self.times[seg]) * (1.0 / h)


class PiecewiseSlerp(_Keyed):
    """Geodesic interpolation between consecutive keyframes (C0).

    Parameters
    ----------
    quats : array_like, shape (N, 4)
        Keyframes (w, x, y, z), N >= 2.
    times : array_like, shape (N,)
        Strictly increasing times (s).
    """

    def _jet(self, t, seg, order):
        q = self.quats
        return _slerp(q[seg].T, q[seg + 1].T, self._u(t, seg, order))


class Squad(_Keyed):
    """Shoemake's squad: ``slerp(slerp(q_i, q_i+1, u), slerp(s_i, s_i+1, u), 2u(1-u))``.

    Inner points ``s_i = q_i exp(-(log(q_i* q_i+1) + log(q_i* q_i-1)) / 4)``;
    ``s_0 = q_0``, ``s_N-1 = q_N-1``. C1 when the keyframes are evenly spaced in time.
    """

    def __init__(self, quats, times):
        super().__init__(quats, times)
        q = self.quats
        s = q.copy()
        for i in range(1, len(q) - 1):
            qi = Q.conj(q[i])
            tangent = Q.log(Q.mul(qi, q[i + 1])) + Q.log(Q.mul(qi, q[i - 1]))
            s[i] = Q.mul(q[i], Q.exp(-tangent / 4))
        self._inner = s

    def _jet(self, t, seg, order):
        q, s = self.quats, self._inner
        u = self._u(t, seg, order)
        outer = _slerp(q[seg].T, q[seg + 1].T, u)
        inner = _slerp(s[seg].T, s[seg + 1].T, u)
        return _slerp(outer, inner, 2.0 * u * (1.0 - u))


class SphericalBezier(_Keyed):
    """Shoemake's spherical cubic Bezier (1985), evaluated by de Casteljau with slerps.

    Control points ``a_i = Bisect(Double(q_i-1, q_i), q_i+1)`` and
    ``b_i = Double(a_i, q_i)``, moved to a third of the way from ``q_i``; at the
    ends they point a third of the way to the neighbour. C1 for even spacing.
    """

    def __init__(self, quats, times):
        super().__init__(quats, times)
        q, n = self.quats, len(self.quats)

        def double(p, r):
            return 2 * (p @ r) * r - p

        def bisect(p, r):
            return (p + r) / np.linalg.norm(p + r)

        def third(p, r):
            return Q.slerp(p, r, 1.0 / 3.0)

        a, b = np.empty_like(q), np.empty_like(q)
        a[0], b[-1] = third(q[0], q[1]), third(q[-1], q[-2])
        for i in range(1, n - 1):
            ai = bisect(double(q[i - 1], q[i]), q[i + 1])
            bi = double(ai, q[i])
            ai, bi = ai * np.sign(ai @ q[i]), bi * np.sign(bi @ q[i])
            a[i], b[i] = third(q[i], ai), third(q[i], bi)
        self._a, self._b = a, b

    def _jet(self, t, seg, order):
        u = self._u(t, seg, order)
        p0, p1 = self.quats[seg].T, self._a[seg].T
        p2, p3 = self._b[seg + 1].T, self.quats[seg + 1].T
        p01, p12, p23 = _slerp(p0, p1, u), _slerp(p1, p2, u), _slerp(p2, p3, u)
        return _slerp(_slerp(p01, p12, u), _slerp(p12, p23, u), u)


class PiecewiseCircles(_Keyed):
    """Circular arcs on S^3 joined with a common tangent and speed (C1), no blending.

    The first arc leaves ``q_0`` along the tangent of the circle through the first
    three keyframes (the geodesic for two keyframes); each next arc starts along the
    previous arc's end tangent and is the circle through ``q_i`` and ``q_i+1`` with
    that tangent. The arc angle runs by a cubic Hermite polynomial whose end rates
    match the speed of the previous arc's end and the arc's mean speed. Each arc
    lies in its own 2-plane, so the angular acceleration jumps at every keyframe:
    the defect Kim & Nam's blending removes.
    """

    def __init__(self, quats, times):
        super().__init__(quats, times)
        q, t = self.quats, self.times
        n = len(q)
        if n >= 3 and np.linalg.norm(q[2] - q[0]) > 1e-9:
            from .local_curves import circle_through

            c, r, e1, e2, _, _ = circle_through(q[0], q[1], q[2])
            tangent = e2  # the circle at angle 0 (q_0) moves along e2
        else:
            tangent = q[1] - (q[1] @ q[0]) * q[0]
        tangent = tangent / np.linalg.norm(tangent)
        rows = []
        speed = None
        for i in range(n - 1):
            d = q[i + 1] - q[i]
            en = d - (d @ tangent) * tangent
            en = en / np.linalg.norm(en)
            rho = (d @ d) / (2 * (d @ en))
            angle = np.arctan2((d @ tangent) / rho, 1 - (d @ en) / rho) % (2 * np.pi)
            h = t[i + 1] - t[i]
            mean = rho * angle / h  # mean speed along the arc (1/s on S^3)
            start = mean if speed is None else speed
            # theta(u) cubic Hermite: 0 -> angle, rates start h / rho and angle.
            m0, m1 = start * h / rho, angle
            rows.append([rho, angle, m0, m1, *q[i], *tangent, *en])
            tangent = np.cos(angle) * tangent + np.sin(angle) * en
            speed = rho * m1 / h
        self._arcs = np.array(rows)

    def _jet(self, t, seg, order):
        arc = self._arcs[seg].T
        rho, angle, m0, m1 = arc[:4]
        start, et, en = arc[4:8], arc[8:12], arc[12:16]
        u = self._u(t, seg, order)
        # Hermite basis on [0, 1] with p(0) = 0, p(1) = angle, p'(0) = m0, p'(1) = m1.
        coef = np.stack([0 * rho, m0, 3 * angle - 2 * m0 - m1, -2 * angle + m0 + m1])
        sin, cos = J.sin_cos(J.polyval(coef, u))
        return J.scale(sin, rho * et) + J.scale(1.0 - cos, rho * en) + start


class ScipyRotationSpline(OrientationPath):
    """scipy's ``RotationSpline`` (C2, global) behind the path protocol.

    scipy's ``spline(t, 1)`` and ``spline(t, 2)`` are the body-frame angular
    velocity and acceleration (checked against finite differences); the space
    frame is the same vectors rotated by ``q``. It has no jerk. Needs scipy.
    """

    def __init__(self, quats, times):
        from scipy.spatial.transform import Rotation, RotationSpline

        q, self.times = _signed_keys(quats, times)
        self._spline = RotationSpline(self.times, Rotation.from_quat(q, scalar_first=True))

    def evaluate(self, t, *, max_order: int = 2, frame: str = "space") -> Samples:
        if max_order not in (0, 1, 2):
            raise BadArgument("scipy's RotationSpline gives no jerk: `max_order` must be 0..2.")
        check_choice("frame", frame, FRAMES)
        _, ta = self._segment(np.atleast_1d(np.asarray(t, dtype=float)))
        q = self._spline(ta).as_quat(scalar_first=True)
        rates = [self._spline(ta, n) for n in range(1, max_order + 1)]
        if frame == "space":
            rates = [Q.rotate(q, r) for r in rates]
        rates += [None] * (3 - len(rates))
        return Samples(ta, q, *rates)
