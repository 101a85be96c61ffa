"""Local curves through three keyframes (Kim & Nam 1995, docs/algorithm.md §2).

Each interior keyframe ``i`` gets a curve ``C_i(t)`` on S^3 through
``q_{i-1}, q_i, q_{i+1}`` at ``t_{i-1}, t_i, t_{i+1}``. The curves of one spline
are stored as a :class:`LocalCurves` table (one row a curve, numpy arrays a
column) so that any mix of curves is evaluated in one vectorised pass.

Kinds:

- ``POINT``: a held keyframe (the end curves of ``boundary="rest"``).
- ``CIRCLE``: the circle on S^3 through the three points (algorithm.md §2a), with the
  time-to-angle map ``theta = a3 g(s)``.
- ``PARABOLA``: ``exp(v(t)) q_i``, ``v`` the quadratic through the logs (algorithm.md §2b).
- ``GEODESIC``: a repeated keyframe (algorithm.md §2c): the geodesic between the two
  distinct points, flat on the repeated part.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import derivatives as D
from . import jet as J
from . import quat as Q
from .errors import NoCircleError
from .path import run_steps

POINT, CIRCLE, PARABOLA, GEODESIC = range(4)
KIND_NAMES = ("point", "circle", "parabola", "geodesic")

# Angle maps g(s) for circles.
G_POLY, G_POWER, G_RATIONAL = range(3)

#: Keyframes closer than this on S^3 (chord) count as the same.
SAME_POINT = 1e-9


@dataclass
class CurveRow:
    """Parameters of one local curve (see module docstring); unused fields stay zero."""

    kind: int
    t: tuple[float, float, float]  # (t_{i-1}, t_i, t_{i+1})
    q: np.ndarray  # (4,) the POINT, the PARABOLA's q_i, the GEODESIC's start
    # CIRCLE
    centre: np.ndarray | None = None
    radius: float = 0.0
    e1: np.ndarray | None = None
    e2: np.ndarray | None = None
    a3: float = 0.0
    g_kind: int = G_POLY
    g_coef: np.ndarray | None = None  # (4,) cubic coefficients, or (alpha,), or (b,)
    # PARABOLA: v(tau) = A tau + B tau^2, tau = t - t_i;  GEODESIC: L = log(q_end q_start*)
    A: np.ndarray | None = None
    B: np.ndarray | None = None
    # GEODESIC: +1 rises after s_i, -1 settles before s_i; exponent k + 1
    rise: int = 0
    power: int = 0


def _same(p: np.ndarray, q: np.ndarray) -> bool:
    return bool(np.linalg.norm(p - q) < SAME_POINT)


def circle_through(p1, p2, p3):
    """The oriented circle through three distinct points of S^3 (docs/algorithm.md §2a).

    Returns
    -------
    centre : ndarray, shape (4,)
    radius : float
    e1, e2 : ndarray, shape (4,)
        In-plane orthonormal basis, ``e1`` towards ``p1``, oriented so that the arc
        from ``p1`` through ``p2`` to ``p3`` runs at increasing angle.
    a2, a3 : float
        Angles of ``p2`` and ``p3``, ``0 < a2 < a3 < 2 pi``.
    """
    A, B = p2 - p1, p3 - p1
    G = np.array([[A @ A, A @ B], [A @ B, B @ B]])
    a, b = np.linalg.solve(G, [A @ A / 2, B @ B / 2])
    c = p1 + a * A + b * B
    r = np.linalg.norm(p1 - c)
    e1 = (p1 - c) / r
    # e2 from p2; if p2 is diametrically opposite p1 on the circle, use p3.
    for p in (p2, p3):
        w = (p - c) - ((p - c) @ e1) * e1
        if np.linalg.norm(w) > 1e-9 * r:
            e2 = w / np.linalg.norm(w)
            break

    def angle(p):
        return np.arctan2((p - c) @ e2, (p - c) @ e1) % (2 * np.pi)

    a2, a3 = angle(p2), angle(p3)
    if a3 < a2:
        e2, a2, a3 = -e2, 2 * np.pi - a2, 2 * np.pi - a3
    return c, r, e1, e2, a2, a3


def angle_map(s_i: float, phi: float, reparam: str) -> tuple[int, np.ndarray]:
    """``g: [0, 1] -> [0, 1]``, increasing, ``g(s_i) = phi`` (docs/algorithm.md §2a).

    Returns the kind and coefficients: ``G_POLY`` with cubic coefficients
    ``(c0, c1, c2, c3)`` in s, ``G_POWER`` with ``(alpha,)`` for ``s ** alpha``,
    ``G_RATIONAL`` with ``(b,)`` for ``(1 + b) s / (1 + b s)``.
    """
    if reparam == "rational":
        return G_RATIONAL, np.array([(phi - s_i) / (s_i * (1 - phi))])
    if abs(phi - s_i) < 1e-12:
        return G_POLY, np.array([0.0, 1.0, 0.0, 0.0])
    if s_i**2 <= phi <= 2 * s_i - s_i**2:
        a = (phi - s_i) / (s_i**2 - s_i)
        return G_POLY, np.array([0.0, 1 - a, a, 0.0])
    if s_i**3 <= phi < s_i**2:
        a = (phi - s_i**2) / (s_i**3 - s_i**2)
        return G_POLY, np.array([0.0, 0.0, 1 - a, a])
    r, p = 1 - s_i, 1 - phi
    if r**3 <= p < r**2:
        a = (p - r**2) / (r**3 - r**2)
        # 1 - (a (1-s)^3 + (1-a) (1-s)^2), expanded in powers of s.
        return G_POLY, np.array([0.0, 2 + a, -1 - 2 * a, a])
    return G_POWER, np.array([np.log(phi) / np.log(s_i)])


def build_curve(qs: np.ndarray, ts, *, k: int, local: str, reparam: str) -> CurveRow:
    """The local curve through keyframes ``qs`` (3, 4) at times ``ts`` (3,)."""
    p1, p2, p3 = qs
    ts = tuple(float(x) for x in ts)
    same12, same23 = _same(p1, p2), _same(p2, p3)
    if same12 and same23:
        return CurveRow(POINT, ts, p2)
    if same12 or same23:
        start, end = (p2, p3) if same12 else (p1, p2)
        return CurveRow(
            GEODESIC,
            ts,
            start,
            A=Q.log(Q.mul(end, Q.conj(start))),
            rise=1 if same12 else -1,
            power=k + 1,
        )
    if local == "auto":
        local = "circle" if circle_behaves(p1, p2, p3) else "parabola"
    if local == "parabola":
        tm, tp = ts[0] - ts[1], ts[2] - ts[1]
        Lm = Q.log(Q.mul(p1, Q.conj(p2)))
        Lp = Q.log(Q.mul(p3, Q.conj(p2)))
        # v(tau) = A tau + B tau^2 through (tm, Lm) and (tp, Lp).
        det = tm * tp * (tp - tm)
        A = (Lm * tp**2 - Lp * tm**2) / det
        B = (Lp * tm - Lm * tp) / det
        return CurveRow(PARABOLA, ts, p2, A=A, B=B)
    if _same(p1, p3):
        raise NoCircleError("reversal")
    c, r, e1, e2, a2, a3 = circle_through(p1, p2, p3)
    s_i = (ts[1] - ts[0]) / (ts[2] - ts[0])
    g_kind, g_coef = angle_map(s_i, a2 / a3, reparam)
    return CurveRow(
        CIRCLE, ts, p2, centre=c, radius=r, e1=e1, e2=e2, a3=a3, g_kind=g_kind, g_coef=g_coef
    )


def circle_behaves(p1, p2, p3) -> bool:
    """The rule of ``local="auto"``: is the circle through the triple usable?

    True when the arc from ``p1`` through ``p2`` to ``p3`` spans at most half its
    circle (``a3 <= pi``). By the inscribed angle theorem that is the same as the
    triangle ``p1 p2 p3`` having an angle of at least 90 degrees at ``p2``, i.e.
    ``(p1 - p2) . (p3 - p2) <= 0``: the path turns by at most a right angle at
    the keyframe. Reversals and sharp turns, where the arc would loop most of the
    way round, fail it.
    """
    return bool((p1 - p2) @ (p3 - p2) <= 0.0)


def build_curves(qs: np.ndarray, ts: np.ndarray, *, k: int, local: str, reparam: str):
    """The local curves through many triples at once: :func:`build_curve` vectorised.

    Parameters
    ----------
    qs : ndarray, shape (C, 3, 4)
        Keyframe triples ``(q_{i-1}, q_i, q_{i+1})``, unit, signs walked (docs/algorithm.md §1).
    ts : ndarray, shape (C, 3)
        Their times (s). A triple of one repeated keyframe gives a held ``POINT``.
    k, local, reparam
        As for :func:`build_curve`.

    Returns
    -------
    LocalCurves
        The same table as ``LocalCurves.from_rows([build_curve(...) for each triple])``
        (to rounding: the 2x2 solve is written out).

    Raises
    ------
    NoCircleError
        For a reversal with ``local="circle"``; its ``index`` is the first such triple.
    """
    C = len(qs)
    p1, p2, p3 = qs[:, 0], qs[:, 1], qs[:, 2]
    same12 = np.linalg.norm(p1 - p2, axis=1) < SAME_POINT
    same23 = np.linalg.norm(p2 - p3, axis=1) < SAME_POINT
    kind = np.empty(C, dtype=int)
    point, geodesic = same12 & same23, same12 ^ same23
    distinct = ~(same12 | same23)
    if local == "auto":
        circle = distinct & (np.einsum("ij,ij->i", p1 - p2, p3 - p2) <= 0.0)
    else:
        circle = distinct if local == "circle" else np.zeros(C, dtype=bool)
    parabola = distinct & ~circle
    kind[point], kind[geodesic], kind[circle], kind[parabola] = POINT, GEODESIC, CIRCLE, PARABOLA
    reversal = circle & (np.linalg.norm(p1 - p3, axis=1) < SAME_POINT)
    if reversal.any():
        error = NoCircleError("reversal")
        error.index = int(np.argmax(reversal))
        raise error

    q = p2.copy()
    A, B = np.zeros((C, 3)), np.zeros((C, 3))
    rise, power = np.zeros(C, dtype=int), np.zeros(C)
    # Each kind's block runs only if the kind is present (a few keyframes, as an online
    # change builds, pay for no empty quaternion products).
    if geodesic.any():  # algorithm.md §2c: from the repeated keyframe to the other one, or back.
        start = np.where(same12[:, None], p2, p1)
        end = np.where(same12[:, None], p3, p2)
        A[geodesic] = Q.log(Q.mul(end[geodesic], Q.conj(start[geodesic])))
        q[geodesic] = start[geodesic]
        rise[geodesic] = np.where(same12[geodesic], 1, -1)
        power[geodesic] = k + 1
    m = parabola
    if m.any():  # algorithm.md §2b: v(tau) = A tau + B tau^2 through (tm, Lm), (0, 0), (tp, Lp).
        tm, tp = (ts[m, 0] - ts[m, 1])[:, None], (ts[m, 2] - ts[m, 1])[:, None]
        Lm, Lp = Q.log(Q.mul(np.stack([p1[m], p3[m]]), Q.conj(p2[m])))
        det = tm * tp * (tp - tm)
        A[m] = (Lm * tp**2 - Lp * tm**2) / det
        B[m] = (Lp * tm - Lm * tp) / det
    # CIRCLE (docs/algorithm.md §2a).
    centre, e1, e2 = np.zeros((C, 4)), np.zeros((C, 4)), np.zeros((C, 4))
    radius, a3 = np.zeros(C), np.zeros(C)
    g_kind, g_coef = np.full(C, G_POLY), np.zeros((C, 4))
    m = circle
    if m.any():
        c, r, e1[m], e2[m], a2, a3[m] = _circles_through(p1[m], p2[m], p3[m])
        centre[m], radius[m] = c, r
        s_i = (ts[m, 1] - ts[m, 0]) / (ts[m, 2] - ts[m, 0])
        g_kind[m], g_coef[m] = _angle_maps(s_i, a2 / a3[m], reparam)
    return LocalCurves(
        kind=kind,
        t=ts,
        q=q,
        centre=centre.T.copy(),
        radius=radius,
        e1=e1.T.copy(),
        e2=e2.T.copy(),
        a3=a3,
        g_kind=g_kind,
        g_coef=g_coef,
        A=A.T.copy(),
        B=B.T.copy(),
        rise=rise,
        power=power,
    )


def _circles_through(p1, p2, p3):
    """:func:`circle_through` for (C, 4) stacks of distinct, non-reversing triples."""

    def dot(a, b):
        return np.einsum("ij,ij->i", a, b)

    A, B = p2 - p1, p3 - p1
    AA, AB, BB = dot(A, A), dot(A, B), dot(B, B)
    det = AA * BB - AB * AB
    # [[AA, AB], [AB, BB]] [a, b] = [AA / 2, BB / 2] by Cramer's rule.
    a = BB * (AA - AB) / (2.0 * det)
    b = AA * (BB - AB) / (2.0 * det)
    c = p1 + a[:, None] * A + b[:, None] * B
    r = np.linalg.norm(p1 - c, axis=1)
    e1 = (p1 - c) / r[:, None]
    # e2 from p2; if p2 is diametrically opposite p1 on the circle, from p3.
    w = (p2 - c) - dot(p2 - c, e1)[:, None] * e1
    w3 = (p3 - c) - dot(p3 - c, e1)[:, None] * e1
    use3 = np.linalg.norm(w, axis=1) <= 1e-9 * r
    w[use3] = w3[use3]
    e2 = w / np.linalg.norm(w, axis=1)[:, None]
    a2 = np.arctan2(dot(p2 - c, e2), dot(p2 - c, e1)) % (2 * np.pi)
    a3 = np.arctan2(dot(p3 - c, e2), dot(p3 - c, e1)) % (2 * np.pi)
    flip = a3 < a2
    e2[flip] *= -1.0
    a2 = np.where(flip, 2 * np.pi - a2, a2)
    a3 = np.where(flip, 2 * np.pi - a3, a3)
    return c, r, e1, e2, a2, a3


def _angle_maps(s_i: np.ndarray, phi: np.ndarray, reparam: str):
    """:func:`angle_map` for arrays (C,): kinds (C,) and coefficients (C, 4)."""
    coef = np.zeros((len(s_i), 4))
    if reparam == "rational":
        coef[:, 0] = (phi - s_i) / (s_i * (1 - phi))
        return np.full(len(s_i), G_RATIONAL), coef
    with np.errstate(divide="ignore", invalid="ignore"):
        r, p = 1 - s_i, 1 - phi
        a_quad = (phi - s_i) / (s_i**2 - s_i)
        a_cub = (phi - s_i**2) / (s_i**3 - s_i**2)
        a_mir = (p - r**2) / (r**3 - r**2)
        alpha = np.log(phi) / np.log(s_i)
    cases = [  # the paper's cases, in order (see angle_map)
        (np.abs(phi - s_i) < 1e-12, [0 * s_i, 1 + 0 * s_i, 0 * s_i, 0 * s_i]),
        ((s_i**2 <= phi) & (phi <= 2 * s_i - s_i**2), [0 * s_i, 1 - a_quad, a_quad, 0 * s_i]),
        ((s_i**3 <= phi) & (phi < s_i**2), [0 * s_i, 0 * s_i, 1 - a_cub, a_cub]),
        ((r**3 <= p) & (p < r**2), [0 * s_i, 2 + a_mir, -1 - 2 * a_mir, a_mir]),
    ]
    kind = np.full(len(s_i), G_POWER)
    coef[:, 0] = alpha
    done = np.zeros(len(s_i), dtype=bool)
    for cond, values in cases:
        m = cond & ~done
        kind[m] = G_POLY
        coef[m] = np.stack(values, axis=1)[m]
        done |= m
    return kind, coef


class LocalCurves:
    """A table of local curves, evaluated with their derivatives in one vectorised pass."""

    def __init__(
        self, *, kind, t, q, centre, radius, e1, e2, a3, g_kind, g_coef, A, B, rise, power
    ):
        """Columns, one entry per curve (C of them): ``kind``, ``radius``, ``a3``,
        ``g_kind``, ``rise``, ``power`` (C,); ``t`` (C, 3); ``q`` (C, 4); ``g_coef``
        (C, 4); ``centre``, ``e1``, ``e2`` (4, C) and ``A``, ``B`` (3, C), component
        first so that gathers by curve id are contiguous. Fields a kind does not
        use are zero. See :class:`CurveRow` for their meaning."""
        self.kind = np.asarray(kind)
        self.t, self.q = np.asarray(t, dtype=float), np.asarray(q, dtype=float)
        self.qT = self.q.T.copy()
        self.centre, self.radius, self.e1, self.e2 = centre, radius, e1, e2
        self.a3, self.g_kind, self.g_coef = a3, g_kind, g_coef
        self.A, self.B = A, B
        self.rise, self.power = rise, np.asarray(power, dtype=float)
        # Derived columns for evaluation.
        self.kinds_present = set(self.kind.tolist())
        window = self.t[:, 2] - self.t[:, 0]  # zero for held points
        self.inv_window = 1.0 / np.where(window > 0, window, 1.0)
        self.basis = _basis(self).reshape(12, -1)
        self.ab_gram = np.stack(
            [(self.A * self.A).sum(0), (self.A * self.B).sum(0), (self.B * self.B).sum(0)]
        )
        self.axis_len = np.sqrt(self.ab_gram[0])

    @classmethod
    def from_rows(cls, rows: list[CurveRow]) -> LocalCurves:
        """The table of curves built one at a time (:func:`build_curve`)."""

        def col(name, width):
            zero = np.zeros(width)
            values = [zero if getattr(r, name) is None else getattr(r, name) for r in rows]
            return np.array(values, dtype=float).reshape(len(rows), width).T.copy()

        return cls(
            kind=np.array([r.kind for r in rows]),
            t=np.array([r.t for r in rows], dtype=float),
            q=np.array([r.q for r in rows], dtype=float),
            centre=col("centre", 4),
            radius=np.array([r.radius for r in rows]),
            e1=col("e1", 4),
            e2=col("e2", 4),
            a3=np.array([r.a3 for r in rows]),
            g_kind=np.array([r.g_kind for r in rows]),
            g_coef=np.array(
                [np.pad(r.g_coef if r.g_coef is not None else [], (0, 4))[:4] for r in rows]
            ),
            A=col("A", 3),
            B=col("B", 3),
            rise=np.array([r.rise for r in rows]),
            power=np.array([r.power for r in rows], dtype=float),
        )

    def __len__(self) -> int:
        return len(self.kind)

    @cached_property
    def kernel_table(self) -> np.ndarray:
        """The columns :mod:`trajgen.per_sample` reads, one row per curve (C, 29): kind,
        t (3), 1 / window, a3, g_kind, g_coef (4), A.A, A.B, B.B, rise, power, |A|,
        basis (12). One contiguous row per curve, one array to hand over."""
        return np.column_stack(
            [
                self.kind,
                self.t,
                self.inv_window,
                self.a3,
                self.g_kind,
                self.g_coef,
                self.ab_gram.T,
                self.rise,
                self.power,
                self.axis_len,
                self.basis.T,
            ]
        ).astype(float)

    def derivatives(self, ids: np.ndarray, t: np.ndarray, order: int) -> list[np.ndarray]:
        """Curves ``ids`` (M,) at times ``t`` (M,) and their time derivatives up to ``order`` <= 3.

        See :meth:`derivative_steps`.
        """
        return run_steps(self.derivative_steps(ids, t, order))

    def derivative_steps(self, ids: np.ndarray, t: np.ndarray, order: int):
        """:meth:`derivatives` as a generator of steps (one per kind of curve, then the sum);
        its return value is the result.

        Every curve is a combination ``C = a_0 K_0 + a_1 K_1 + a_2 K_2`` of three
        constant quaternions ``K`` (its ``basis``) with scalar coefficients
        ``a(t)``; only the coefficients depend on the kind.

        Returns a derivative list (see :mod:`trajgen.derivatives`): ``order + 1``
        quaternion arrays (4, M).
        """
        coef = np.zeros((order + 1, 3, len(t)))
        kinds = self.kind[ids]
        for kind, fn in (
            (CIRCLE, self._circle),
            (PARABOLA, self._parabola),
            (GEODESIC, self._geodesic),
            (POINT, self._point),
        ):
            if kind not in self.kinds_present:
                continue
            m = kinds == kind
            if m.all():
                coef = fn(ids, t, order)
                break
            m = np.flatnonzero(m)
            if len(m):
                coef[:, :, m] = fn(ids[m], t[m], order)
                yield
        yield
        # np.take along axis 1 keeps the result component-first in memory (fancy indexing on
        # the last axis would not).
        basis = np.take(self.basis, ids, axis=1).reshape(3, 4, len(ids))
        out = []
        for n in range(order + 1):
            a = coef[n]
            c = basis[0] * a[0]
            c += basis[1] * a[1]
            c += basis[2] * a[2]
            out.append(c)
        return out

    def _s(self, ids, t) -> tuple[np.ndarray, np.ndarray]:
        """Normalised time ``s = (t - t_{i-1}) / (t_{i+1} - t_{i-1})`` and ``ds/dt``."""
        rate = self.inv_window[ids]
        return (t - self.t[ids, 0]) * rate, rate

    @staticmethod
    def _point(ids, t, order):
        coef = np.zeros((order + 1, 3, len(t)))
        coef[0, 0] = 1.0
        return coef

    def _circle(self, ids, t, order):
        """``C = centre + r cos(theta) e1 + r sin(theta) e2``, ``theta = a3 g(s)``."""
        s, rate = self._s(ids, t)
        g = [np.empty_like(s) for _ in range(order + 1)]  # g and its s-derivatives
        gk, gc = self.g_kind[ids], self.g_coef[ids]
        for kind, fn in ((G_RATIONAL, _g_rational), (G_POLY, _g_poly), (G_POWER, _g_power)):
            m = gk == kind
            if m.all():
                g = fn(s, gc, order)
            elif m.any():
                for o, x in zip(g, fn(s[m], gc[m], order), strict=True):
                    o[m] = x
        # theta^(n) = a3 g^(n) (ds/dt)^n.
        scale = self.a3[ids]
        theta = [scale * g[0]]
        for n in range(1, order + 1):
            scale = scale * rate
            theta.append(scale * g[n])
        coef = np.zeros((order + 1, 3, len(t)))
        coef[0, 0] = 1.0
        coef[:, 1], coef[:, 2] = D.cos_sin(theta)
        return coef

    def _parabola(self, ids, t, order):
        """``C = exp(v) q_i`` with ``v = A tau + B tau^2`` (``tau = t - t_i``): in the plane of
        A and B, ``C = cos|v| q_i + (sin|v| / |v|) (tau A q_i + tau^2 B q_i)``."""
        tau = t - self.t[ids, 1]
        aa, ab, bb = np.take(self.ab_gram, ids, axis=1)
        # |v|^2 = aa tau^2 + 2 ab tau^3 + bb tau^4 and its tau-derivatives (d tau / dt = 1).
        x = [tau * tau * (aa + tau * (2.0 * ab + tau * bb))]
        if order >= 1:
            x.append(tau * (2.0 * aa + tau * (6.0 * ab + 4.0 * bb * tau)))
        if order >= 2:
            x.append(2.0 * aa + tau * (12.0 * ab + 12.0 * bb * tau))
        if order >= 3:
            x.append(12.0 * ab + 24.0 * bb * tau)
        cos_a, sinc = D.cos_sinc_sqrt(x)
        coef = np.empty((order + 1, 3, len(t)))
        coef[:, 0] = cos_a
        coef[:, 1] = D.product(sinc, [tau, 1.0, 0.0, 0.0])
        coef[:, 2] = D.product(sinc, [tau * tau, 2.0 * tau, 2.0, 0.0])
        return coef

    def _geodesic(self, ids, t, order):
        """``C = exp(h A) q = cos(h |A|) q + sin(h |A|) (A / |A|) q`` with ``h`` flat on the
        repeated part (docs/algorithm.md §2c)."""
        s, rate = self._s(ids, t)
        s_i = (self.t[ids, 1] - self.t[ids, 0]) * rate
        rise = self.rise[ids] > 0
        # Rising: h = x^(k+1), x = (s - s_i) / (1 - s_i) on s > s_i, else 0.
        # Settling: h = 1 - x^(k+1), x = (s_i - s) / s_i on s < s_i, else 1.
        x = np.where(rise, (s - s_i) / (1 - s_i), (s_i - s) / s_i)
        dx = np.where(rise, rate / (1 - s_i), -rate / s_i)
        active = x > 0
        x = np.maximum(x, 0.0)
        p = self.power[ids]
        angle = self.axis_len[ids]
        phi, falling, dxn = [], np.ones_like(p), np.ones_like(p)
        for j in range(order + 1):
            # d^j/dt^j x^p = p (p-1) ... (p-j+1) x^(p-j) x'^j (x is linear in t).
            xp = np.where(active, falling * x ** np.where(falling == 0, 0.0, p - j) * dxn, 0.0)
            phi.append(angle * np.where(rise, xp, (1.0 if j == 0 else 0.0) - xp))
            falling, dxn = falling * (p - j), dxn * dx
        coef = np.zeros((order + 1, 3, len(t)))
        coef[:, 0], coef[:, 1] = D.cos_sin(phi)
        return coef

    def evaluate(self, ids: np.ndarray, t: np.ndarray, order: int) -> J.Jet:
        """Curves ``ids`` (M,) at times ``t`` (M,): a quaternion jet (order + 1, 4, M), any order.

        The reference, written with :mod:`trajgen.jet`; :meth:`derivatives` computes the
        same in closed form for orders up to 3 (tests check that they agree).
        """
        out = np.zeros((order + 1, 4, len(t)))
        kinds = self.kind[ids]
        for kind, fn in (
            (POINT, self._jet_point),
            (CIRCLE, self._jet_circle),
            (PARABOLA, self._jet_parabola),
            (GEODESIC, self._jet_geodesic),
        ):
            m = kinds == kind
            if m.any():
                out[:, :, m] = fn(ids[m], J.Jet.variable(t[m], order)).c
        return J.Jet(out)

    def _jet_s(self, ids, tj: J.Jet) -> J.Jet:
        """Normalised time ``s = (t - t_{i-1}) / (t_{i+1} - t_{i-1})`` over the curve's window."""
        t0, t2 = self.t[ids, 0], self.t[ids, 2]
        return (tj - t0) * (1.0 / (t2 - t0))

    def _jet_point(self, ids, tj: J.Jet) -> J.Jet:
        return J.Jet.constant(self.qT[:, ids], tj.order)

    def _jet_circle(self, ids, tj: J.Jet) -> J.Jet:
        s = self._jet_s(ids, tj)
        g = J.Jet(np.zeros_like(s.c))
        gk, coef = self.g_kind[ids], self.g_coef[ids]
        m = gk == G_POLY
        if m.any():
            g.c[:, m] = J.polyval(coef[m].T, s[m]).c
        m = gk == G_POWER
        if m.any():
            # s ** alpha has infinite derivatives at s = 0 when alpha < 1 (the paper's
            # power law): there they are taken at s = 1e-12, large but finite.
            sm = J.Jet(s[m].c.copy())
            at_zero = sm.c[0] < 1e-12
            sm.c[0] = np.maximum(sm.c[0], 1e-12)
            gp = J.power(sm, coef[m, 0])
            gp.c[0] = np.where(at_zero, 0.0, gp.c[0])
            g.c[:, m] = gp.c
        m = gk == G_RATIONAL
        if m.any():
            b = coef[m, 0]
            g.c[:, m] = ((1.0 + b) * s[m] / (b * s[m] + 1.0)).c
        sin, cos = J.sin_cos(g * self.a3[ids])
        r = self.radius[ids]
        e1, e2 = r * self.e1[:, ids], r * self.e2[:, ids]
        return J.scale(cos, e1) + J.scale(sin, e2) + self.centre[:, ids]

    def _jet_parabola(self, ids, tj: J.Jet) -> J.Jet:
        tau = tj - self.t[ids, 1]
        v = J.scale(tau, self.A[:, ids]) + J.scale(tau * tau, self.B[:, ids])
        return J.qmul(J.qexp(v), self.qT[:, ids])

    def _jet_geodesic(self, ids, tj: J.Jet) -> J.Jet:
        s = self._jet_s(ids, tj)
        s_i = (self.t[ids, 1] - self.t[ids, 0]) / (self.t[ids, 2] - self.t[ids, 0])
        rise = self.rise[ids] > 0
        # Rising: h = x^(k+1), x = (s - s_i) / (1 - s_i) on s > s_i, else 0.
        # Settling: h = 1 - x^(k+1), x = (s_i - s) / s_i on s < s_i, else 1.
        x = J.Jet(np.where(rise, (s - s_i).c / (1 - s_i), (s_i - s).c / s_i))
        active = x.value > 0
        x.c[0] = np.maximum(x.c[0], 0.0)
        xp = J.power(x, self.power[ids])
        xp = J.Jet(np.where(active, xp.c, 0.0))
        h = J.Jet(np.where(rise, xp.c, (1.0 - xp).c))
        return J.qmul(J.qexp(J.scale(h, self.A[:, ids])), self.qT[:, ids])


def _basis(c: LocalCurves) -> np.ndarray:
    """The constant quaternions (3, 4, C) each curve combines (see :meth:`LocalCurves.evaluate`)."""
    basis = np.zeros((3, 4, len(c.kind)))
    basis[0] = c.qT
    pure = np.zeros((4, len(c.kind)))
    m = c.kind == CIRCLE
    basis[0, :, m] = c.centre[:, m].T
    basis[1, :, m] = (c.radius * c.e1)[:, m].T
    basis[2, :, m] = (c.radius * c.e2)[:, m].T
    m = c.kind == PARABOLA
    if m.any():  # A q and B q, in one product
        pure_ab = np.zeros((4, 2, len(c.kind)))
        pure_ab[1:, 0], pure_ab[1:, 1] = c.A, c.B
        basis[1:, :, m] = D.hamilton(pure_ab, c.qT[:, None])[:, :, m].transpose(1, 0, 2)
    m = c.kind == GEODESIC
    if m.any():
        length = np.sqrt((c.A * c.A).sum(0))
        pure[1:] = c.A / np.where(length > 0, length, 1.0)
        basis[1, :, m] = D.hamilton(pure, c.qT)[:, m].T
    return basis


def _g_rational(s, coef, order):
    """``g = (1 + b) s / (1 + b s)`` and its s-derivatives,
    ``g^(n) = (-b)^(n-1) n! (1 + b) / (1 + b s)^(n+1)``."""
    b = coef[:, 0]
    inv = 1.0 / (1.0 + b * s)
    g = [(1.0 + b) * s * inv]
    if order >= 1:
        g.append((1.0 + b) * inv * inv)
    for n in range(2, order + 1):
        g.append(-n * b * g[n - 1] * inv)
    return g


def _g_poly(s, coef, order):
    """Cubic ``c0 + c1 s + c2 s^2 + c3 s^3`` and its s-derivatives."""
    c0, c1, c2, c3 = coef.T
    return [
        c0 + s * (c1 + s * (c2 + s * c3)),
        c1 + s * (2.0 * c2 + 3.0 * c3 * s),
        2.0 * c2 + 6.0 * c3 * s,
        6.0 * c3 + 0.0 * s,
    ][: order + 1]


def _g_power(s, coef, order):
    """``s ** alpha``; its derivatives at ``s = 0`` are infinite when alpha < 1 (the paper's
    power law): there they are taken at ``s = 1e-12``, large but finite."""
    alpha = coef[:, 0]
    x = np.maximum(s, 1e-12)
    g, falling = [], np.ones_like(alpha)
    for j in range(order + 1):
        g.append(falling * x ** (alpha - j))
        falling = falling * (alpha - j)
    g[0] = np.where(s < 1e-12, 0.0, g[0])
    return g
