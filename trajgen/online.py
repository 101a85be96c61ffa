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

import threading
from dataclasses import dataclass
from math import comb, factorial

import numpy as np

from . import quat as Q
from .errors import BadArgument, TrajgenError
from .online_frames import PlanFrames
from .online_plan import Piece, Plan
from .online_splice import Splice, hermite_matrix, log_near_identity, log_of_curve
from .path import OrientationPath, check_times, run_steps
from .spline import LOCALS, REPARAMS, BlendingSpline, blend_polynomial
from .validate import check_choice, check_number

__all__ = ["MIN_LEAD_S", "MODES", "Change", "ChangeTooLate", "OnlineSpline", "PlanFrames"]

#: Shortest time (s) from ``at`` to the first new keyframe. Peaks of the spliced
#: piece grow like 1 / lead^2 (acceleration) and 1 / lead^3 (jerk); measured after
#: random mid-motion retargets (k = 2, median [90th percentile] relative to the old
#: plan's peak, bench/online_cost.py): 0.2 s gives 8.3x [16x] the acceleration and
#: 36x [95x] the jerk, 0.5 s 1.9x [3.2x] and 3.5x [7.4x], 1 s 0.9x [1.6x] and 0.8x [1.8x].
MIN_LEAD_S = 0.2

MODES = ("extend", "retarget")


class ChangeTooLate(TrajgenError):
    """A change at a time that a stream has already used (see :meth:`OnlineSpline.commit`)."""


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
    path: Plan


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
            raise BadArgument(f"Expected `q0` to be one quaternion, got shape {q.shape}.")
        t0 = check_number("t0", t0)
        # Splices match the old path's jet to order k + 1; jets go to order 4.
        self.k = check_number("k", k, integer=True, low=1, high=3)
        self.local = check_choice("local", local, LOCALS)
        self.reparam = check_choice("reparam", reparam, REPARAMS)
        self.min_lead_s = check_number("min_lead_s", min_lead_s, low=MIN_LEAD_S)
        self._hermite = hermite_matrix(self.k)
        # Taylor coefficients at u = 1 of the terms u^0..u^(k+1).
        self._low = np.array(
            [[comb(i, j) for i in range(self.k + 2)] for j in range(self.k + 1)], float
        )
        self._factorials = np.array([factorial(n) for n in range(self.k + 2)], float)
        self._plan = Plan((Piece(t0, None, None, q[0]),))
        self._version = 0
        self._committed = -np.inf
        self._last_at = t0
        self._closed = False
        self._swap = threading.Lock()  # held briefly: the swap, commit
        self._change = threading.Lock()  # held while a change is built: one at a time

    @classmethod
    def from_path(cls, path: OrientationPath, *, k=2, min_lead_s=MIN_LEAD_S) -> OnlineSpline:
        """An online spline that plays ``path`` exactly until a change.

        For a path that is not a blending spline, such as a file fitted by
        ``trajgen fit`` (a :class:`~trajgen.timelaw.RetimedPath`): up to the first
        change every evaluation is the path's own. A retarget splices onto it at
        ``at`` as onto any piece (the splice matches the path's jet to order
        ``k + 1``); an extend keeps the whole path and goes on from its rest at
        ``path.t_end`` (the blending spline's locality, which an extend uses
        otherwise, does not hold for another path).

        Parameters
        ----------
        path : OrientationPath
            At rest at both ends, with keyframe ``times`` and ``quats`` (N, 4).
        k : int, optional
            Continuity order kept across every change, 1 or 2 (a splice at
            ``k = 3`` needs the path's jet to order 4, which only a blending
            spline gives). Default 2.
        min_lead_s : float, optional
            As for :class:`OnlineSpline`.

        Raises
        ------
        ValueError, TypeError
            For a ``k`` outside 1..2, or a path without ``times`` and ``quats``.
        """
        k = check_number("k", k, integer=True, low=1, high=2)
        if not all(hasattr(path, name) for name in ("times", "quats", "evaluate")):
            raise TypeError(
                f"Expected `path` to have times, quats and evaluate, got {type(path).__name__}."
            )
        q_end = path(np.array([path.t_end]))[0]
        spline = cls(path(np.array([path.t_start])), path.t_start, k=k, min_lead_s=min_lead_s)
        spline._plan = Plan((Piece(path.t_start, path, None, q_end),))
        return spline

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
    def last_change_at(self) -> float:
        """Time (s) of the latest change (``t0`` before any): the next may not be earlier."""
        return self._last_at

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
        version, plan = self._open_change(at)
        lead = t[0] - at
        if lead < self.min_lead_s - 1e-9:
            raise BadArgument(
                f"The first new keyframe (t = {t[0]} s) is {lead:.4g} s after `at` = {at} s; "
                f"it must be at least {self.min_lead_s} s after it."
            )
        piece = yield from self._new_piece(plan, mode, q, t, at)
        return self._change_to(version, plan, piece, at)

    def prepare_segment(self, segment, *, at) -> Change:
        """A change that follows ``segment`` from ``at``, then rests at its end.

        For a caller that builds its own segment, such as
        :class:`~trajgen.tracker.Tracker`'s jerk-limited joint motion
        (:class:`~trajgen.joint_splice.JointSplice`): an ``OrientationPath`` on
        ``[at, t1]`` with the methods of a splice (``frame``, ``rates``, ``taylor``,
        ``q_a``, ``q_end``). Its continuity with the path before ``at`` is the
        caller's to keep; no minimum lead applies. Make it with :meth:`apply`.

        Raises
        ------
        ValueError
            If ``segment`` does not start at ``at``; ``at`` before the previous change,
            or after :meth:`close`.
        ChangeTooLate
            If a stream has already committed a time after ``at``.
        """
        at = check_number("at", at)
        if abs(segment.t_start - at) > 1e-12 * max(1.0, abs(at)):
            raise BadArgument(f"The segment starts at {segment.t_start} s, not at `at` = {at} s.")
        version, plan = self._open_change(at)
        return self._change_to(version, plan, Piece(at, None, segment, segment.q_end), at)

    def _open_change(self, at: float) -> tuple[int, Plan]:
        """The version and plan a change at ``at`` starts from, if one may be made there."""
        with self._swap:
            version, plan = self._version, self._plan
        if self._closed:
            raise BadArgument("The spline is closed: no more changes.")
        if at < self._last_at:
            raise BadArgument(f"`at` = {at} s is before the previous change at {self._last_at} s.")
        self._check_not_streamed(at)
        return version, plan

    def _change_to(self, version: int, plan: Plan, piece: Piece, at: float) -> Change:
        """The change that appends ``piece`` to ``plan``, dropping what lies wholly
        before ``at`` (before the streamed time, if earlier: a stream still needs the
        path from there)."""
        kept = [p for p in plan.pieces if p.start < piece.start]
        drop = min(at, self._committed) if self._committed > -np.inf else at
        first = max(0, int(np.searchsorted([p.start for p in kept], drop, side="left")) - 1)
        return Change(version, at, Plan((*kept[first:], piece)))

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
                raise BadArgument("The spline is closed: no more changes.")
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

    def _new_piece(self, plan: Plan, mode: str, q, t, at: float):
        """The change's piece, in steps (a generator; its return value is the piece)."""
        last = plan.pieces[-1]
        kt, kq = last.key_times, last.key_quats
        if mode == "extend" and t[0] <= kt[-1]:
            raise BadArgument(
                f"extend: the first new keyframe (t = {t[0]} s) must come after the last "
                f"keyframe kept (t = {kt[-1]} s)."
            )
        if at >= plan.t_end:  # at rest: start from where it rests
            return self._rest_piece(last.q_end, at, q, t)
        if mode == "extend" and not isinstance(last.spline, (BlendingSpline, type(None))):
            # A path of from_path: kept whole, then on from its rest.
            return self._rest_piece(last.q_end, last.t_end, q, t)
        if mode == "extend":
            ahead = int((kt > at).sum())
            if ahead >= 2:  # splice at the second-to-last keyframe: the offline spline
                i = len(kt) - 2
                j = max(i - 1, 0)
                spline = self._spline(np.vstack([kq[j:], q]), np.concatenate([kt[j:], t]))
                return Piece(float(kt[i]), spline, None, spline.quats[-1])
            if kt[-1] - at < self.min_lead_s:  # too close to splice: go on from its rest
                return self._rest_piece(kq[-1], float(kt[-1]), q, t)
            q, t = np.vstack([kq[-1:], q]), np.concatenate([kt[-1:], t])
        return (yield from self._splice_piece(plan, q, t, at))

    def _spline(self, q, t) -> BlendingSpline:
        return BlendingSpline(
            q, t, k=self.k, boundary="rest", local=self.local, reparam=self.reparam
        )

    def _rest_piece(self, q0: np.ndarray, t0: float, q, t) -> Piece:
        """From rest at ``q0`` (4,) at ``t0`` through keyframes ``q`` (N, 4) at ``t`` (N,)."""
        if len(t) == 1:  # the rest spline's one segment, exp(f_(k+1)(u) log(q_1 q0*)) q0
            q1 = q[0] if q[0] @ q0 >= 0 else -q[0]  # the short way round, as the spline goes
            coef = blend_polynomial(self.k + 1)[:, None] * Q.log(Q.mul(q1, Q.conj(q0)))
            return Piece(t0, None, Splice(t0, float(t[0]) - t0, q0, coef), q1)
        spline = self._spline(np.vstack([q0, q]), np.concatenate([[t0], t]))
        return Piece(t0, spline, None, spline.quats[-1])

    def _splice_piece(self, plan: Plan, q, t, at: float):
        """A splice at ``at`` onto ``plan``, through keyframes ``q`` (N, 4) at ``t`` (N,), in
        two steps (a generator; its return value is the piece)."""
        piece = plan.pieces[int(plan._segment(np.array([at]))[0][0])]
        q_a, d = yield from piece.taylor_steps(at, self.k + 1)
        yield
        return (yield from self._spliced(at, q_a, log_near_identity(d), q, t))

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
            r = log_of_curve(spline._curves.kernel_table, 0, float(t[0]), q_a)[: k + 1]
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
        return Piece(s, spline, Splice(s, h, q_a, coef), q_end)
