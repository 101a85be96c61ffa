"""The path of an online spline at one moment: an immutable list of pieces.

Part of :mod:`trajgen.online`: piece ``j`` (:class:`Piece`: a rest blending
spline, a splice replacing its first segment, or a hold) is used on
``(s_j, s_{j+1}]``; a change appends a piece and never edits one, so a
:class:`Plan` is a snapshot that later changes do not alter. Evaluated as any
``OrientationPath`` (numpy) or, per stream frame, by
:class:`~trajgen.online_frames.PlanFrames`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import jet as J
from . import quat as Q
from .errors import BadArgument
from .online_frames import PlanFrames
from .online_splice import Splice, taylor_from_rates
from .path import OrientationPath
from .spline import BlendingSpline


@dataclass(frozen=True)
class Piece:
    """One piece of the plan, used on ``(start, next piece's start]``.

    ``spline`` is a rest BlendingSpline, ``splice`` a spliced segment that replaces
    its first segment (or, without a spline, leads to ``q_end`` on its own); with
    neither, the piece holds ``q_end`` from ``start``. After ``t_end`` the piece
    holds ``q_end``. The first piece of :meth:`OnlineSpline.from_path
    <trajgen.online.OnlineSpline.from_path>` is any path at rest at its ends (with
    ``times`` and ``quats``, e.g. a fitted file's RetimedPath) in place of the
    blending spline.
    """

    start: float
    spline: BlendingSpline | OrientationPath | None
    splice: Splice | None
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
            return q, taylor_from_rates(rates[:order])
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


class Plan(OrientationPath):
    """An immutable list of pieces: the path at one moment, from ``t_start`` on."""

    def __init__(self, pieces: tuple[Piece, ...]):
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
            raise BadArgument(
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
