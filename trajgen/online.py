"""Changing the plan while moving: an orientation path that takes new keyframes online.

:class:`OnlineSpline` starts at rest at one orientation; :meth:`~OnlineSpline.extend`
adds keyframes after the ones it already has and :meth:`~OnlineSpline.retarget`
replaces the ones still ahead, both "at" a time ``at``. After each change the
path up to ``at`` is what it was, bit for bit; the path is C^k across ``at``;
every keyframe after ``at`` is passed at its time; after the last keyframe the
path comes to rest and holds it.

How: the path is a short list of pieces, piece ``j`` used on ``(s_j, s_{j+1}]``.
A change never edits a piece; it appends one (dropping those that lie wholly
before ``at``, so memory stays bounded on a stream that runs for hours). Each
piece is a rest :class:`~trajgen.spline.BlendingSpline` through keyframes,
optionally with its first segment replaced by a splice:

- *Extend* with two or more keyframes still ahead: the new piece starts at the
  second-to-last of them and is the rest spline through (the keyframe before it,
  the last two, the new ones). By the locality of the blend (a segment depends
  on two keyframes either side) this is, from there on, exactly what the spline
  through all the keyframes gives; it is C^k where it starts because both sides
  there equal the same local curve to order k.
- *Retarget*, or an extend with one keyframe ahead: a splice at ``s = at``. With
  ``q_a = q(s)``, ``P_j`` the Taylor coefficients at ``s`` of
  ``log(q_old(t) q_a*)`` (orders 0..k+1) and ``R_j`` those at ``T_1`` of
  ``log(C_1(t) q_a*)`` (orders 0..k; ``C_1`` the local curve through
  ``(q_a, q_1, q_2)``, or the rest point ``q_1`` when it is the only keyframe),
  the first segment ``[s, T_1]`` is ``exp(r(u)) q_a``, ``u = (t - s) / h``,
  ``h = T_1 - s``, where ``r`` is the polynomial of degree 2k + 2 with Taylor
  coefficients ``h^j P_j`` at ``u = 0`` and ``h^j R_j`` at ``u = 1``. That is
  C^(k+1) at ``s`` (one order more than promised: matching only k lets repeated
  splices drift), C^k at ``T_1``, and the rest spline's blends after it (with
  one new keyframe, rest at ``T_1``: no spline is built).
- From rest (``at`` after the last keyframe, or an extend whose only keyframe
  ahead is closer than the minimum lead): a plain rest spline from the resting
  orientation; both sides have zero rates up to order k there, so it is C^k.
  With one new keyframe, its one segment ``exp(f_(k+1)(u) log(q_1 q_0*)) q_0``
  is kept as a splice (``r`` = the blend polynomial times a constant).

Cost: a change is small fixed-size arithmetic, so what counts is the number of
numpy calls. The old path's jet at ``s`` comes from its closed-form rates
(``omega, alpha, jerk``: ``d' = omega d / 2`` differentiated) or, inside a
splice, from one series of ``exp``; ``log`` near the identity is two terms of
a series; the polynomial's top coefficients take a (k + 1)-square matrix inverted
once per spline. A rest spline is built only for two or more new keyframes (or
an extend with two ahead).
Measured in ``bench/online_cost.py``.

Changes are safe to make from another thread while a stream evaluates the path:
a change builds its new piece list aside and swaps it in whole; a streamer that
reports the frames it has used (:meth:`OnlineSpline.commit`) makes changes
before them fail with :class:`ChangeTooLate` instead of rewriting sent frames.
A change may also be built in steps (:meth:`OnlineSpline.prepare_steps`), checked,
then made (:meth:`OnlineSpline.apply`): ``trajgen follow`` runs those steps on the
streaming thread between frames, so that no other thread competes with the stream
for the interpreter. A stream evaluates each frame on its own
(:class:`PlanFrames`): spliced segments in Python floats, blended ones with numpy.

References
----------
M.-S. Kim, K.-W. Nam, "Interpolating solid orientations with circular blending
quaternion curves", Computer-Aided Design 27(5), 1995 (the blending spline).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from functools import cached_property
from math import comb, factorial

import numpy as np

from . import derivatives as D
from . import jet as J
from . import per_sample as P
from . import quat as Q
from .errors import TrajgenError
from .frame_eval import exp_frame
from .path import OrientationPath, Steps, check_times, run_steps
from .spline import CONJ, LOCALS, REPARAMS, BlendingSpline, blend_polynomial
from .validate import check_choice, check_number

#: Shortest time (s) from ``at`` to the first new keyframe. Peaks of the spliced
#: piece grow like 1 / lead^2 (acceleration) and 1 / lead^3 (jerk); measured after
#: random mid-motion retargets (k = 2, median [90th percentile] relative to the old
#: plan's peak, bench/online_cost.py): 0.2 s gives 8.3x [16x] the acceleration and
#: 36x [95x] the jerk, 0.5 s 1.9x [3.2x] and 3.5x [7.4x], 1 s 0.9x [1.6x] and 0.8x [1.8x].
MIN_LEAD_S = 0.2

MODES = ("extend", "retarget")

#: ``C(j, n)`` for the Taylor shift of a splice's polynomial (degree 2k + 2 <= 8), (9, 9).
_BINOMIAL = np.array([[comb(j, n) for j in range(9)] for n in range(9)], float)


class ChangeTooLate(TrajgenError):
    """A change at a time that a stream has already used (see :meth:`OnlineSpline.commit`)."""


class _Splice(OrientationPath):
    """A spliced segment: ``exp(r(u)) q_a``, ``u = (t - s) / h``, ``r`` a polynomial in ``u``."""

    def __init__(self, s: float, h: float, q_a: np.ndarray, coef: np.ndarray):
        self.s, self.h = s, h
        self.q_a = q_a  # (4,)
        self.coef = coef  # (2k + 3, 3), power basis in u
        self.times = np.array([s, s + h])

    def _jet(self, t: np.ndarray, seg, order: int) -> J.Jet:
        u = (J.Jet.variable(t, order) - self.s) * (1.0 / self.h)
        r = J.Jet(np.stack([J.polyval(self.coef[:, i], u).c for i in range(3)], axis=1))
        return J.qmul(J.qexp(r), self.q_a)

    def taylor(self, t: float, order: int) -> tuple[np.ndarray, np.ndarray]:
        """``q(t)`` (4,) and the Taylor coefficients (order + 1, 4) of ``q(t + tau) q(t)*``:
        ``r`` shifted to ``t`` and ``exp`` as one series (no array of samples)."""
        # r^(n)(t) / n! = h^-n sum_j C(j, n) u^(j - n) coef_j: the polynomial shifted to u.
        u = (t - self.s) / self.h
        n, j = np.ogrid[: order + 1, : len(self.coef)]
        shift = _BINOMIAL[: order + 1, : len(self.coef)] * u ** np.maximum(j - n, 0)
        r = (shift @ self.coef) * (1.0 / self.h) ** n  # (order + 1, 3)
        e = _qexp_series(J.Jet(r))  # (order + 1, 4)
        e0 = e[:1].T  # (4, 1)
        return D.hamilton(e0, self.q_a[:, None])[:, 0], D.hamilton(e.T, e0 * CONJ).T

    def _space_rates(self, t, seg, max_order):
        """The same path as :meth:`_jet`, in closed form (as the spline's blends): ``r`` and
        its time derivatives from the powers of ``u``, ``exp`` by the rules of
        :mod:`trajgen.derivatives`; the rates are those of ``exp(r)`` (``q_a`` is fixed)."""
        u = (t - self.s) * (1.0 / self.h)
        powers = u[:, None] ** np.arange(len(self.coef))  # (M, 2k + 3)
        r = [(powers[:, : len(c)] @ c).T for c in self._derivative_coefs[: max_order + 1]]
        cos_a, sinc = D.cos_sinc_sqrt(D.vdot(r, r))
        e = [np.concatenate([ca[None], v]) for ca, v in zip(cos_a, D.product(sinc, r), strict=True)]
        _, rates = _rates_of(e)
        q = D.hamilton(e[0], self.q_a[:, None])
        return (q / np.sqrt(D.vdot([q], [q])[0])).T, rates

    def frame(self, t: float) -> tuple[tuple, tuple, tuple]:
        """Orientation, angular velocity (rad/s) and acceleration (rad/s^2) at one time
        ``t`` (s), in floats (:func:`~trajgen.frame_eval.exp_frame`): the per-frame
        counterpart of :meth:`_space_rates`."""
        return exp_frame(*self._r_values(t, 3), self._q_a_floats)

    def rates(self, t: float) -> tuple[np.ndarray, list[np.ndarray]]:
        """``q`` (4,) and the space-frame angular velocity, acceleration and jerk (each
        (3,)) at one time ``t`` (s), in floats (:mod:`trajgen.per_sample`)."""
        v = self._r_values(t, 4)
        E = P.exp_of(*(tuple(v[3 * n + i] for n in range(4)) for i in range(3)))
        out = np.empty((3, 1, 3))
        P.space_rates(E, 0, out)
        q = P.hamilton(tuple(e[0] for e in E), self._q_a_floats)
        return np.array(q), list(out[:, 0])

    def _r_values(self, t: float, orders: int) -> list[float]:
        """``r`` and its first ``orders - 1`` time derivatives per axis at ``t`` (s), by
        Horner, order-major (``r_x, r_y, r_z, r'_x, ...``)."""
        u = (t - self.s) * (1.0 / self.h)
        values = []
        for row in self._rows[: 3 * orders]:
            acc = 0.0
            for c in row:
                acc = acc * u + c
            values.append(acc)
        return values

    @cached_property
    def _rows(self) -> list[list[float]]:
        """Power-basis coefficients of ``r`` and its time derivatives up to order 3 per
        axis (12 rows, order-major), highest power first."""
        return [c[::-1, i].tolist() for c in self._derivative_coefs for i in range(3)]

    @cached_property
    def _q_a_floats(self) -> list[float]:
        return self.q_a.tolist()

    @cached_property
    def _derivative_coefs(self) -> list[np.ndarray]:
        """Power-basis coefficients in ``u`` of ``d^n r / dt^n``, n = 0..3, each (D - n, 3)."""
        out, c = [self.coef], self.coef
        for _ in range(3):
            c = c[1:] * (np.arange(1.0, len(c))[:, None] / self.h)
            out.append(c)
        return out


def _rates_of(derivs: list) -> tuple[np.ndarray, list[np.ndarray]]:
    """Unit quaternions (M, 4) and space-frame rates of orders 1..K, each (M, 3), from the
    derivative list ``[Q, Q', ...]`` (each (4, M)) of a unit quaternion path, K <= 3:
    ``omega = 2 vec(Q' Q*)``, ``alpha = 2 vec(Q'' Q*)``, ``jerk = 2 vec(Q''' Q* + Q'' Q'*)``."""
    q = derivs[0] / np.sqrt(D.vdot(derivs[:1], derivs[:1])[0])
    q_conj = q * CONJ
    rates = [2.0 * D.hamilton_vec(d, q_conj) for d in derivs[1:]]
    if len(rates) >= 3:
        rates[2] += 2.0 * D.hamilton_vec(derivs[2], derivs[1] * CONJ)
    return q.T, [x.T for x in rates]


def _taylor_from_rates(rates: list) -> np.ndarray:
    """Taylor coefficients (K + 1, 4) of ``d(tau) = q(t + tau) q(t)*`` from the space-frame
    rates ``omega, alpha, jerk`` at ``t`` (each (3,), K = len(rates) <= 3), using
    ``d' = omega d / 2`` (``omega`` as a pure quaternion) differentiated: ``d(0) = 1``,
    ``d^(n+1) = 1/2 sum_j C(n, j) omega^(j) d^(n-j)``. Plain floats: a handful of
    quaternion products, each far cheaper than a numpy call."""
    w = [(0.0, *map(float, x)) for x in rates]
    d = [(1.0, 0.0, 0.0, 0.0)]
    for n in range(len(rates)):
        acc = [0.0, 0.0, 0.0, 0.0]
        for j in range(n + 1):
            c = 0.5 * comb(n, j)
            for i, x in enumerate(P.hamilton(w[j], d[n - j])):
                acc[i] += c * x
        d.append(tuple(acc))
    return np.array(d) / np.array([factorial(n) for n in range(len(d))])[:, None]


@dataclass(frozen=True)
class _Piece:
    """One piece of the plan, used on ``(start, next piece's start]``.

    ``spline`` is a rest BlendingSpline, ``splice`` a spliced segment that replaces
    its first segment (or, without a spline, leads to ``q_end`` on its own); with
    neither, the piece holds ``q_end`` from ``start``. After ``t_end`` the piece
    holds ``q_end``.
    """

    start: float
    spline: BlendingSpline | None
    splice: _Splice | None
    q_end: np.ndarray  # (4,)

    @property
    def key_times(self) -> np.ndarray:
        if self.spline is not None:
            return self.spline.times
        return self.splice.times if self.splice is not None else np.array([self.start])

    @property
    def key_quats(self) -> np.ndarray:
        if self.spline is not None:
            return self.spline.quats
        if self.splice is not None:
            return np.stack([self.splice.q_a, self.q_end])
        return self.q_end[None]

    @property
    def t_end(self) -> float:
        return float(self.key_times[-1])

    def _parts(self, t: np.ndarray):
        """Masks (M,) of the held, spliced and blended times; the blended ones' segments."""
        hold = t >= self.t_end
        spliced = np.zeros(len(t), bool)
        if self.splice is not None:
            spliced = ~hold & (t < self.splice.times[1])
        blended = ~hold & ~spliced
        times = self.spline.times if self.spline is not None else t[:0]
        seg = np.clip(np.searchsorted(times, t[blended], side="right") - 1, 0, len(times) - 2)
        return hold, spliced, blended, seg

    def jet(self, t: np.ndarray, order: int) -> J.Jet:
        """The piece as a quaternion jet (order + 1, 4, M): exact, for splicing."""
        out = np.zeros((order + 1, 4, len(t)))
        hold, spliced, blended, seg = self._parts(t)
        out[0, :, hold] = self.q_end
        if spliced.any():
            out[:, :, spliced] = self.splice._jet(t[spliced], None, order).c
        if blended.any():
            out[:, :, blended] = self.spline._jet(t[blended], seg, order).c
        return J.Jet(out)

    def taylor_steps(self, t: float, order: int):
        """``q(t)`` (4,) and the Taylor coefficients (order + 1, 4) of ``q(t + tau) q(t)*``
        (``d(0) = 1``), order <= 4: what a splice at ``t`` starts from. A generator of
        steps (those of the spline's evaluation, in a blended segment); its return
        value is the pair."""
        hold, spliced, blended, seg = self._parts(np.array([t]))
        if hold[0]:
            d = np.zeros((order + 1, 4))
            d[0, 0] = 1.0
            return self.q_end, d
        if order <= 3:  # the closed-form rates (in floats, or the compiled kernel)
            if spliced[0]:
                q, rates = self.splice.rates(t)
            else:
                q, rates = yield from self.spline._space_rate_steps(np.array([t]), seg, order)
                q, rates = q[0], [x[0] for x in rates]
            return q, _taylor_from_rates(rates[:order])
        if spliced[0]:  # order 4: only the jets go that far
            return self.splice.taylor(t, order)
        old = self.spline._jet(np.array([t]), seg, order)  # order 4: only the jets go that far
        q = old.value[:, 0] / np.linalg.norm(old.value[:, 0])
        d = J.qmul(old, Q.conj(q)).c[:, :, 0]
        d[0] = (1.0, 0.0, 0.0, 0.0)
        return q, d

    def space_rates(self, t: np.ndarray, max_order: int):
        """Unit quaternions (M, 4) and space-frame rates of orders 1..max_order (M, 3),
        the blended part by the spline's own (compiled, where enabled) evaluation."""
        hold, spliced, blended, seg = self._parts(t)
        for mask, path, s in ((spliced, self.splice, None), (blended, self.spline, seg)):
            if len(t) and mask.all():  # one part (the usual case): no masks
                return path._space_rates(t, s, max_order)
        q = np.empty((len(t), 4))
        rates = [np.zeros((len(t), 3)) for _ in range(max_order)]
        q[hold] = self.q_end
        for mask, path, s in ((spliced, self.splice, None), (blended, self.spline, seg)):
            if mask.any():
                q[mask], part = path._space_rates(t[mask], s, max_order)
                for r, p in zip(rates, part, strict=True):
                    r[mask] = p
        return q, rates


class _Plan(OrientationPath):
    """An immutable list of pieces: the path at one moment, from ``t_start`` on."""

    def __init__(self, pieces: tuple[_Piece, ...]):
        self.pieces = pieces
        self.starts = np.array([p.start for p in pieces])
        self.times = np.unique(np.concatenate([[pieces[0].start], pieces[-1].key_times]))

    @property
    def t_start(self) -> float:
        return float(self.starts[0])

    @property
    def t_end(self) -> float:
        return self.pieces[-1].t_end

    def _segment(self, t):
        t0 = self.t_start
        if (t < t0 - 1e-12 * max(1.0, abs(t0))).any():
            raise ValueError(
                f"Time {float(t[t < t0][0])!r} s is before the path's kept range, which "
                f"starts at {t0} s (changes drop what lies before them)."
            )
        piece = np.searchsorted(self.starts, t, side="left") - 1
        return np.clip(piece, 0, len(self.pieces) - 1), np.maximum(t, t0)

    def frames(self, t0: float, rate_hz: float, previous=None) -> PlanFrames:
        """This path at one stream time per call, in floats (see :class:`PlanFrames`)."""
        return PlanFrames(self, t0, rate_hz, previous)

    def _jet(self, t, seg, order):
        out = np.empty((order + 1, 4, len(t)))
        for j in np.unique(seg):
            m = seg == j
            out[:, :, m] = self.pieces[j].jet(t[m], order).c
        return J.Jet(out)

    def _space_rates(self, t, seg, max_order):
        if len(t) and (seg == seg[0]).all():  # one piece (the usual case): no masks
            return self.pieces[seg[0]].space_rates(t, max_order)
        q = np.empty((len(t), 4))
        rates = [np.empty((len(t), 3)) for _ in range(max_order)]
        for j in np.unique(seg):
            m = seg == j
            q[m], part = self.pieces[j].space_rates(t[m], max_order)
            for r, p in zip(rates, part, strict=True):
                r[m] = p
        return q, rates


class PlanFrames:
    """One snapshot of an :class:`OnlineSpline` at one stream time per call, in floats.

    What :func:`trajgen.stream.stream_frames` evaluates per frame: a spliced segment
    in floats (:meth:`_Splice.frame`, a few microseconds), a hold as its constant,
    and a blended segment (a BlendingSpline's, which has no per-frame form) with
    numpy, ``BLOCK_FRAMES`` stream times at a time, the next block's evaluation
    spread in steps over the frames of the one before (as ``stream_frames`` does
    for an offline BlendingSpline). The part holding a time is
    looked up with the numpy evaluation's own rules, only when the time leaves the
    current part (or lies on its boundary), so every frame equals ``evaluate``'s.

    Parameters
    ----------
    plan : the path from :meth:`OnlineSpline.snapshot`
    t0 : float
        The stream's first time (s); its times are ``t0 + i / rate_hz``.
    rate_hz : float
        The stream's rate (Hz), > 0.
    previous : PlanFrames, optional
        The same stream's evaluator of an earlier snapshot: its blocks of the pieces
        this plan keeps are used, not evaluated again.
    """

    #: Stream times evaluated at once in a blended segment.
    BLOCK_FRAMES = 16

    def __init__(self, plan: _Plan, t0: float, rate_hz: float, previous: PlanFrames | None = None):
        self._plan, self._t0, self._rate = plan, t0, rate_hz
        self._lo, self._hi = math.inf, -math.inf  # the current part's open interval
        self._part = None
        # The current block, (piece, first frame, times (B,), q (B, 4), omega, alpha), and
        # the next, (piece, first frame, Steps evaluating it). Blocks are a piece's, and
        # pieces are immutable and shared by the plans before and after a change: an
        # earlier snapshot's blocks stay valid where their piece is kept.
        self._block = previous._block if previous else None
        self._ahead = previous._ahead if previous else None

    def __call__(self, t: float) -> tuple[tuple, tuple, tuple]:
        """Orientation (w, x, y, z), space-frame angular velocity (rad/s) and
        acceleration (rad/s^2) at stream time ``t`` (s), each a tuple of floats."""
        if not self._lo < t < self._hi:
            self._enter(t)
        return self._part(t)

    def _enter(self, t: float) -> None:
        plan = self._plan
        j = int(plan._segment(np.array([t]))[0][0])  # raises before the kept range
        piece = plan.pieces[j]
        lo = float(plan.starts[j]) if j else plan.t_start
        hi = float(plan.starts[j + 1]) if j + 1 < len(plan.pieces) else math.inf
        hold, spliced, _, seg = piece._parts(np.array([t]))
        if hold[0]:
            q, zero = tuple(piece.q_end.tolist()), (0.0, 0.0, 0.0)
            lo, self._part = max(lo, piece.t_end), lambda _: (q, zero, zero)
        elif spliced[0]:
            hi, self._part = min(hi, float(piece.splice.times[1])), piece.splice.frame
        else:
            times = piece.spline.times
            lo = max(lo, float(times[seg[0]]))
            hi = min(hi, float(times[seg[0] + 1]))
            self._part = lambda x: self._blended(piece, x)
        self._lo, self._hi = lo, hi

    def _blended(self, piece: _Piece, t: float) -> tuple[tuple, tuple, tuple]:
        i = round((t - self._t0) * self._rate)
        block = self._block
        if block is None or block[0] is not piece or not 0 <= i - block[1] < self.BLOCK_FRAMES:
            ahead = self._ahead
            if ahead is not None and ahead[0] is piece and ahead[1] == i:
                samples = ahead[2].finish()
                q, omega, alpha = samples.q, samples.omega, samples.alpha
            else:  # the first block of this segment: at once
                q, (omega, alpha) = piece.space_rates(self._block_times(i), 2)
            block = self._block = (piece, i, self._block_times(i), q, omega, alpha)
            # The next block, a step per frame of this one.
            times = np.clip(self._block_times(i + self.BLOCK_FRAMES), *piece.spline.times[[0, -1]])
            steps = piece.spline.evaluation_steps(times, max_order=2)
            self._ahead = (piece, i + self.BLOCK_FRAMES, Steps(steps))
        else:
            self._ahead[2].step()
        _, first, times, q, omega, alpha = block
        k = i - first
        if times[k] != t:  # not on the stream's grid: this time alone
            q1, (w1, a1) = piece.space_rates(np.array([t]), 2)
            return tuple(q1[0].tolist()), tuple(w1[0].tolist()), tuple(a1[0].tolist())
        return tuple(q[k].tolist()), tuple(omega[k].tolist()), tuple(alpha[k].tolist())

    def _block_times(self, i: int) -> np.ndarray:
        """Stream times (s) of frames ``i .. i + BLOCK_FRAMES - 1``."""
        return self._t0 + np.arange(i, i + self.BLOCK_FRAMES) / self._rate


def _qexp_series(r: J.Jet) -> np.ndarray:
    """:func:`trajgen.jet.qexp` for one vector series ``r`` (K + 1, 3), K <= 4: Taylor
    coefficients (K + 1, 4) of ``(cos |r|, sin|r| r / |r|)``, with only the branch
    (series or closed form in ``x = |r|^2``) that its value needs."""
    x = J.dot(r, r)
    K = x.order
    x0 = np.atleast_1d(x.value)
    both = (D._cos_sinc_series if x0[0] < J.SERIES_BELOW else D._cos_sinc_closed)([x0], K)
    cos_a = J.compose(x, [v[0] for v in both[: K + 1]])
    sinc = J.compose(x, [v[0] for v in both[K + 1 :]])
    return np.concatenate([cos_a.c[:, None], J.scale(sinc, r).c], axis=1)


def _log_near_identity(d: np.ndarray) -> np.ndarray:
    """Taylor coefficients (K + 1, 3) of ``log d(tau)`` from those (K + 1, 4) of a unit
    quaternion ``d`` with ``d(0) = 1``, K <= 4.

    ``log d = atan(|y|) y / |y|`` with ``y = vec(d) / w(d)``, and ``atan(x) / x =
    1 - x^2 / 3 + O(x^4)``: as ``y = O(tau)``, the ``x^4`` term is ``O(tau^5)``.
    """
    if len(d) > 5:
        raise ValueError(f"Expected at most 5 Taylor coefficients, got {len(d)}.")
    y = J.scale(J.reciprocal(J.Jet(d[:, 0])), J.Jet(d[:, 1:]))
    return (y - J.scale(J.dot(y, y), y) * (1.0 / 3.0)).c


def _log_of_curve(tab: np.ndarray, c: int, t: float, q_a: np.ndarray) -> np.ndarray:
    """Taylor coefficients (4, 3) at ``t`` (s) of ``log(C(t) q_a*)``, ``C`` curve ``c`` of
    a local-curve table (:attr:`~trajgen.local_curves.LocalCurves.kernel_table`) with
    ``C(t) . q_a >= 0``, in floats: the curve by :func:`trajgen.per_sample.curve`, the
    ``log`` as :func:`trajgen.jet.qlog` writes it, ``atan(z) / (z w)`` with
    ``z^2 = |xyz|^2 / w^2`` (a series in ``z^2`` near the identity)."""
    curve = P.curve(c, t, tab)  # w, x, y, z, each (value, d/dt, d2/dt2, d3/dt3)
    a = (float(q_a[0]), -float(q_a[1]), -float(q_a[2]), -float(q_a[3]))
    d = list(zip(*(P.hamilton(tuple(x[n] for x in curve), a) for n in range(4)), strict=True))
    w, xyz = d[0], d[1:]
    s2 = P.add(P.add(P.prod(xyz[0], xyz[0]), P.prod(xyz[1], xyz[1])), P.prod(xyz[2], xyz[2]))
    z2 = P.quot(s2, P.prod(w, w))
    if z2[0] < J.SERIES_BELOW:
        atanc = P.series(J._ATANC, z2[0])
    else:  # atan(sqrt y) / sqrt y = H(y): 2 y H' = 1 / (1 + y) - H, differentiated
        y = z2[0]
        c0, inv2y = 1.0 / (1.0 + y), 0.5 / y
        h0 = math.atan(math.sqrt(y)) / math.sqrt(y)
        h1 = (c0 - h0) * inv2y
        h2 = (-c0 * c0 - 3.0 * h1) * inv2y
        atanc = (h0, h1, h2, (2.0 * c0**3 - 5.0 * h2) * inv2y)
    g = P.quot(P.chain(*atanc, z2), w)
    taylor = np.array([P.prod(g, v) for v in xyz]).T  # (4, 3) time derivatives
    return taylor / np.array([1.0, 1.0, 2.0, 6.0])[:, None]


def _hermite_matrix(k: int) -> np.ndarray:
    """Inverse of the map from the top coefficients ``a_{k+2..2k+2}`` of ``r(u)`` to its
    Taylor coefficients of orders 0..k at ``u = 1``."""
    m = np.array([[comb(k + 2 + i, j) for i in range(k + 1)] for j in range(k + 1)], float)
    return np.linalg.inv(m)


@dataclass(frozen=True)
class Change:
    """A change built by :meth:`OnlineSpline.prepare`, not made yet.

    Attributes
    ----------
    version : int
        The spline's :attr:`~OnlineSpline.version` it was built on.
    at : float
        Time (s) of the change.
    path : OrientationPath
        The path it makes, from the oldest time it keeps (at or before ``at``).
    """

    version: int
    at: float
    path: _Plan


class OnlineSpline:
    """An orientation path that takes new keyframes while it is being followed.

    Starts at rest at ``q0`` from ``t0``. Evaluate it like a
    :class:`~trajgen.spline.BlendingSpline`: ``s(t, order)``, ``s.evaluate(t)``.
    It is defined from ``t_start`` (the start of the oldest piece kept, which
    moves forward as changes drop the past) to any later time: after the last
    keyframe (``t_end``) it holds that keyframe at rest.

    Parameters
    ----------
    q0 : array_like, shape (4,) or (1, 4), or scipy Rotation
        Starting orientation, scalar first (w, x, y, z), any norm and sign.
    t0 : float, optional
        Start time (s). Default 0.
    k : int, optional
        Continuity order kept across every change, 1..3. Default 2.
    min_lead_s : float, optional
        Shortest time (s) from ``at`` to the first new keyframe, >= ``MIN_LEAD_S``
        (0.2 s). 0.5 s keeps a mid-motion retarget's peaks within a few times
        the plan's (see :data:`MIN_LEAD_S`).
    local, reparam : str, optional
        Local curves and circle time map, as for
        :class:`~trajgen.spline.BlendingSpline`.

    Raises
    ------
    ValueError, TypeError
        For bad shapes or values, naming the argument and what arrived.

    Notes
    -----
    Thread safety: :meth:`extend`, :meth:`retarget`, :meth:`close` and the
    evaluation methods may be called from different threads. A change is built
    aside and swapped in whole; an evaluation sees the path either
    before or after it, never a mix. :attr:`version` counts the changes.

    References
    ----------
    Kim & Nam (1995), see :mod:`trajgen.spline`.
    """

    def __init__(self, q0, t0=0.0, *, k=2, min_lead_s=MIN_LEAD_S, local="auto", reparam="rational"):
        if np.shape(q0) == (4,):
            q0 = np.reshape(q0, (1, 4))
        q = Q.as_quats(q0, "q0")
        if q.shape[0] != 1:
            raise ValueError(f"Expected `q0` to be one quaternion, got shape {q.shape}.")
        t0 = check_number("t0", t0)
        # Splices match the old path's jet to order k + 1; jets go to order 4.
        self.k = check_number("k", k, integer=True, low=1, high=3)
        self.local = check_choice("local", local, LOCALS)
        self.reparam = check_choice("reparam", reparam, REPARAMS)
        self.min_lead_s = check_number("min_lead_s", min_lead_s, low=MIN_LEAD_S)
        self._hermite = _hermite_matrix(self.k)
        # Taylor coefficients at u = 1 of the terms u^0..u^(k+1).
        self._low = np.array(
            [[comb(i, j) for i in range(self.k + 2)] for j in range(self.k + 1)], float
        )
        self._factorials = np.array([factorial(n) for n in range(self.k + 2)], float)
        self._plan = _Plan((_Piece(t0, None, None, q[0]),))
        self._version = 0
        self._committed = -np.inf
        self._last_at = t0
        self._closed = False
        self._swap = threading.Lock()  # held briefly: the swap, commit
        self._change = threading.Lock()  # held while a change is built: one at a time

    # -- what the path is now ------------------------------------------------

    @property
    def t_start(self) -> float:
        """Earliest time (s) still defined."""
        return self._plan.t_start

    @property
    def t_end(self) -> float:
        """Time (s) of the last keyframe; the path holds it at rest after."""
        return self._plan.t_end

    @property
    def times(self) -> np.ndarray:
        """Times (s), shape (N,): ``t_start`` and the keyframes the last change planned
        through (the keyframe before the splice, and those after it)."""
        return self._plan.times

    @property
    def version(self) -> int:
        """Number of changes so far."""
        return self._version

    @property
    def committed(self) -> float:
        """Latest time (s) a stream has used (-inf before any): changes must not be earlier."""
        return self._committed

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called: no more changes."""
        return self._closed

    @property
    def pieces(self) -> int:
        """Pieces kept (bounded: a change drops those that lie wholly before it)."""
        return len(self._plan.pieces)

    def evaluate(self, t, *, max_order=2, frame="space"):
        """As :meth:`trajgen.path.OrientationPath.evaluate`, for any times >= ``t_start``."""
        return self._plan.evaluate(t, max_order=max_order, frame=frame)

    def __call__(self, t, order=0, *, frame="space"):
        """As :meth:`trajgen.path.OrientationPath.__call__`, for any times >= ``t_start``."""
        return self._plan(t, order, frame=frame)

    def snapshot(self) -> tuple[int, OrientationPath]:
        """``(version, path)``: the path as it is now, which later changes do not alter."""
        with self._swap:
            return self._version, self._plan

    # -- streaming -----------------------------------------------------------

    def commit(self, t: float, version: int) -> bool:
        """Record that a stream uses the path up to ``t`` (s), as evaluated at ``version``.

        Returns False (recording nothing) if a change came after ``version``: the
        caller must evaluate ``t`` again. Once ``t`` is committed, changes at an
        earlier ``at`` raise :class:`ChangeTooLate`.
        """
        with self._swap:
            if version != self._version:
                return False
            self._committed = max(self._committed, float(t))
            return True

    def close(self) -> None:
        """No more changes: a stream of this path may end once it reaches ``t_end``."""
        with self._change:
            self._closed = True

    # -- changes -------------------------------------------------------------

    def extend(self, quats, times, *, at, check=None) -> None:
        """Keep the keyframes after ``at`` and add these after them.

        Parameters
        ----------
        quats : array_like, shape (N, 4), or scipy Rotation
            New keyframes (w, x, y, z), any norm and sign. N >= 1.
        times : array_like, shape (N,)
            Their times (s), strictly increasing, the first after the last
            keyframe kept and at least ``min_lead_s`` after ``at``.
        at : float
            Time (s) of the change: the path up to it stays as it was.
        check : callable, optional
            Called with the new path (an ``OrientationPath`` whose range starts
            at or before ``at``) before it is swapped in; whatever it raises
            rejects the change and leaves the path as it was.

        Raises
        ------
        ValueError, TypeError
            Bad keyframes or times (the message names the argument), ``at``
            before the previous change, or after :meth:`close`.
        ChangeTooLate
            If a stream has already committed a time after ``at``.
        """
        self._change_plan("extend", quats, times, at, check)

    def retarget(self, quats, times, *, at, check=None) -> None:
        """Drop the keyframes after ``at`` and go through these instead.

        Parameters and errors as :meth:`extend`, except that the new keyframes
        only need to be ``min_lead_s`` or more after ``at``.
        """
        self._change_plan("retarget", quats, times, at, check)

    def prepare(self, mode, quats, times, *, at) -> Change:
        """Build a change without making it: the first half of ``extend`` or ``retarget``.

        What :meth:`extend` and :meth:`retarget` do, split where their ``check``
        is called, so that a caller can check the new path (:attr:`Change.path`)
        in its own time, for example in steps between the frames of a stream,
        then make it with :meth:`apply`.

        Parameters
        ----------
        mode : {"extend", "retarget"}
        quats, times, at
            As for :meth:`extend` and :meth:`retarget`.

        Returns
        -------
        Change

        Raises
        ------
        ValueError, TypeError, ChangeTooLate
            As :meth:`extend` and :meth:`retarget`.
        """
        return run_steps(self.prepare_steps(mode, quats, times, at=at))

    def prepare_steps(self, mode, quats, times, *, at):
        """:meth:`prepare` as a generator of steps (the old path's jet at ``at``; the
        new spline, where the change has two or more keyframes; the rest), for a
        caller that runs one step per stream frame; the generator's return value is
        the :class:`Change`."""
        mode = check_choice("mode", mode, MODES)
        q = Q.as_quats(quats, "quats")
        t = check_times(times, len(q))
        at = check_number("at", at)
        with self._swap:
            version, plan = self._version, self._plan
        if self._closed:
            raise ValueError("The spline is closed: no more changes.")
        if at < self._last_at:
            raise ValueError(f"`at` = {at} s is before the previous change at {self._last_at} s.")
        self._check_not_streamed(at)
        lead = t[0] - at
        if lead < self.min_lead_s - 1e-9:
            raise ValueError(
                f"The first new keyframe (t = {t[0]} s) is {lead:.4g} s after `at` = {at} s; "
                f"it must be at least {self.min_lead_s} s after it."
            )
        piece = yield from self._new_piece(plan, mode, q, t, at)
        kept = [p for p in plan.pieces if p.start < piece.start]
        # Drop what lies wholly before `at` (before the streamed time, if earlier: a
        # stream still needs the path from there).
        drop = min(at, self._committed) if self._committed > -np.inf else at
        first = max(0, int(np.searchsorted([p.start for p in kept], drop, side="left")) - 1)
        return Change(version, at, _Plan((*kept[first:], piece)))

    def apply(self, change: Change) -> None:
        """Make a change built by :meth:`prepare`, if the path is still the one it was
        built on.

        Raises
        ------
        ChangeTooLate
            If another change came after it was prepared (prepare it again), or a
            stream has committed a time after its ``at``.
        ValueError
            After :meth:`close`.
        """
        with self._swap:
            if self._closed:
                raise ValueError("The spline is closed: no more changes.")
            if change.version != self._version:
                raise ChangeTooLate(
                    f"The path changed since this change was prepared (version "
                    f"{change.version}, now {self._version}): prepare it again."
                )
            self._check_not_streamed(change.at)
            self._plan = change.path
            self._version += 1
            self._last_at = change.at

    def _change_plan(self, mode, quats, times, at, check) -> None:
        with self._change:  # one at a time: concurrent callers wait, not fail
            change = self.prepare(mode, quats, times, at=at)
            if check is not None:
                check(change.path)
            self.apply(change)

    def _check_not_streamed(self, at: float) -> None:
        if at < self._committed:
            raise ChangeTooLate(f"`at` = {at} s is before the streamed time {self._committed} s.")

    def _new_piece(self, plan: _Plan, mode: str, q, t, at: float):
        """The change's piece, in steps (a generator; its return value is the piece)."""
        last = plan.pieces[-1]
        kt, kq = last.key_times, last.key_quats
        if mode == "extend" and t[0] <= kt[-1]:
            raise ValueError(
                f"extend: the first new keyframe (t = {t[0]} s) must come after the last "
                f"keyframe kept (t = {kt[-1]} s)."
            )
        if at >= plan.t_end:  # at rest: start from where it rests
            return self._rest_piece(last.q_end, at, q, t)
        if mode == "extend":
            ahead = int((kt > at).sum())
            if ahead >= 2:  # splice at the second-to-last keyframe: the offline spline
                i = len(kt) - 2
                j = max(i - 1, 0)
                spline = self._spline(np.vstack([kq[j:], q]), np.concatenate([kt[j:], t]))
                return _Piece(float(kt[i]), spline, None, spline.quats[-1])
            if kt[-1] - at < self.min_lead_s:  # too close to splice: go on from its rest
                return self._rest_piece(kq[-1], float(kt[-1]), q, t)
            q, t = np.vstack([kq[-1:], q]), np.concatenate([kt[-1:], t])
        return (yield from self._splice_piece(plan, q, t, at))

    def _spline(self, q, t) -> BlendingSpline:
        return BlendingSpline(
            q, t, k=self.k, boundary="rest", local=self.local, reparam=self.reparam
        )

    def _rest_piece(self, q0: np.ndarray, t0: float, q, t) -> _Piece:
        """From rest at ``q0`` (4,) at ``t0`` through keyframes ``q`` (N, 4) at ``t`` (N,)."""
        if len(t) == 1:  # the rest spline's one segment, exp(f_(k+1)(u) log(q_1 q0*)) q0
            q1 = q[0] if q[0] @ q0 >= 0 else -q[0]  # the short way round, as the spline goes
            coef = blend_polynomial(self.k + 1)[:, None] * Q.log(Q.mul(q1, Q.conj(q0)))
            return _Piece(t0, None, _Splice(t0, float(t[0]) - t0, q0, coef), q1)
        spline = self._spline(np.vstack([q0, q]), np.concatenate([[t0], t]))
        return _Piece(t0, spline, None, spline.quats[-1])

    def _splice_piece(self, plan: _Plan, q, t, at: float):
        """A splice at ``at`` onto ``plan``, through keyframes ``q`` (N, 4) at ``t`` (N,), in
        two steps (a generator; its return value is the piece)."""
        piece = plan.pieces[int(plan._segment(np.array([at]))[0][0])]
        q_a, d = yield from piece.taylor_steps(at, self.k + 1)
        yield
        return (yield from self._spliced(at, q_a, _log_near_identity(d), q, t))

    def _spliced(self, s: float, q_a: np.ndarray, p: np.ndarray, q, t):
        """The piece that leaves ``q_a`` (4,) at ``s`` with Taylor coefficients ``p``
        (k + 2, 3) of ``log(q(s + tau) q_a*)`` and goes through ``q`` (N, 4) at ``t`` (N,):
        the splice on ``[s, t[0]]``, then the rest spline's blends (none if N = 1). A
        generator (a step after building the spline); its return value is the piece."""
        k = self.k
        h = float(t[0]) - s
        if len(t) >= 2:  # C_1 through (q_a, q_1, q_2): curve 0 of the spline
            spline = self._spline(np.vstack([q_a, q]), np.concatenate([[s], t]))
            yield
            r = _log_of_curve(spline._curves.kernel_table, 0, float(t[0]), q_a)[: k + 1]
            q_end = spline.quats[-1]
        else:  # the rest point q_1, on the short way round (as the spline takes it)
            spline = None
            q_end = q[0] if q[0] @ q_a >= 0 else -q[0]
            r = np.zeros((k + 1, 3))
            r[0] = Q.log(Q.mul(q_end, Q.conj(q_a)))
        powers = h ** np.arange(2 * k + 3)[:, None]
        coef = np.zeros((2 * k + 3, 3))
        coef[: k + 2] = powers[: k + 2] * p
        # Taylor coefficients at u = 1 of the known low part, then solve for the top.
        coef[k + 2 :] = self._hermite @ (powers[: k + 1] * r - self._low @ coef[: k + 2])
        return _Piece(s, spline, _Splice(s, h, q_a, coef), q_end)
