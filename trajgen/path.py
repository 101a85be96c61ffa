"""The orientation-path protocol shared by the spline and the comparison methods.

A path is defined on ``[t_start, t_end]`` by keyframe times and gives, at any
time in that range, a unit quaternion and its angular velocity, acceleration and
jerk. Subclasses write the path once as a quaternion jet (:meth:`_jet`); the
derivatives follow exactly (see :mod:`trajgen.jet`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import jet as J
from . import quat as Q
from .errors import BadArgument
from .sampling import sample_times
from .validate import check_choice, check_number

FRAMES = ("space", "body")


class Samples(NamedTuple):
    """Orientations and their derivatives at times ``t`` (M,).

    ``q`` (M, 4) unit quaternions (w, x, y, z); ``omega``, ``alpha``, ``jerk``
    (M, 3) angular velocity (rad/s), acceleration (rad/s^2) and jerk (rad/s^3).
    Fields above the requested ``max_order`` are None.
    """

    t: np.ndarray
    q: np.ndarray
    omega: np.ndarray | None
    alpha: np.ndarray | None
    jerk: np.ndarray | None


def check_times(times, n: int) -> np.ndarray:
    """Validate keyframe times: shape (n,), finite, strictly increasing."""
    try:
        t = np.asarray(times, dtype=float)
    except (TypeError, ValueError) as e:
        raise TypeError(f"Expected `times` to be numeric, got {type(times).__name__}.") from e
    if t.shape != (n,):
        raise BadArgument(f"Expected `times` to have shape ({n},) to match `quats`, got {t.shape}.")
    if not np.isfinite(t).all():
        raise BadArgument(f"`times` must be finite, got {t[~np.isfinite(t)][0]}.")
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise BadArgument(
            f"`times` must be strictly increasing, got times[{i}] = {t[i]} "
            f"and times[{i + 1}] = {t[i + 1]}."
        )
    return t


def _check_order(name: str, value, top: int = 3) -> int:
    return check_number(name, value, integer=True, low=0, high=top)


class OrientationPath:
    """Base class: keyframe ``times`` (N,) and the path as a quaternion jet.

    Subclasses set ``self.times`` and implement ``_jet(t, seg, order)``.
    """

    times: np.ndarray
    #: Closed paths repeat with period ``t_end - t_start``; open ones raise outside.
    periodic: bool = False

    @property
    def t_start(self) -> float:
        return float(self.times[0])

    @property
    def t_end(self) -> float:
        return float(self.times[-1])

    def _jet(self, t: np.ndarray, seg: np.ndarray, order: int) -> J.Jet:
        """The path as a quaternion jet (order + 1, 4, M) at times ``t`` (M,) in segments ``seg``
        (M,)."""
        raise NotImplementedError

    def _segment(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Segment index and (wrapped) time for times ``t`` (M,); raises outside the range."""
        t0, t1 = self.t_start, self.t_end
        if self.periodic:
            t = t0 + np.mod(t - t0, t1 - t0)
        else:
            eps = 1e-12 * max(1.0, abs(t0), abs(t1))
            bad = (t < t0 - eps) | (t > t1 + eps)
            if bad.any():
                raise BadArgument(
                    f"Time {float(t[bad][0])!r} s is outside the path's range [{t0}, {t1}] s."
                )
            t = np.minimum(np.maximum(t, t0), t1)
        seg = np.searchsorted(self.times, t, side="right") - 1
        seg = np.minimum(np.maximum(seg, 0), len(self.times) - 2)
        return seg, t

    def evaluate(self, t, *, max_order: int = 2, frame: str = "space") -> Samples:
        """Orientation and its derivatives up to ``max_order`` at times ``t``.

        Parameters
        ----------
        t : array_like, shape (M,) or scalar
            Times (s) within ``[t_start, t_end]`` (any time for closed paths).
        max_order : int, optional
            Highest derivative computed, 0..3. Default 2.
        frame : {"space", "body"}, optional
            Frame of the angular velocity and its derivatives. Default "space".

        Returns
        -------
        Samples
            ``t`` (M,) the times asked for; ``q`` (M, 4), ``omega``, ``alpha``,
            ``jerk`` (M, 3) or None.

        Raises
        ------
        ValueError
            If a time is outside the range, or ``max_order`` or ``frame`` is unknown.
        """
        max_order = _check_order("max_order", max_order)
        check_choice("frame", frame, FRAMES)
        t_in = _as_times(t).reshape(-1)
        seg, ta = self._segment(t_in)
        q, rates = self._space_rates(ta, seg, max_order)
        if frame == "body":
            # w_b = R^T w_s, a_b = R^T a_s, j_b = R^T (j_s - w_s x a_s).
            if max_order >= 3:
                rates[2] = rates[2] - np.cross(rates[0], rates[1])
            rates = [Q.rotate(Q.conj(q), r) for r in rates]
        derivs = rates + [None] * (3 - len(rates))
        # A closed path keeps the caller's times (t_end stays t_end, not t_start).
        return Samples(t_in if self.periodic else ta, q, *derivs)

    def evaluation_steps(self, t, *, max_order: int = 2):
        """:meth:`evaluate` (space frame) as a generator of small steps.

        For a caller that spreads the work of an evaluation over time, such as
        the online stream (one step per frame): each ``next()`` does a part of the
        work and the generator's return value (``StopIteration.value``, or the
        value of ``yield from``) is the :class:`Samples`. The default is one step;
        a path may split its work further.

        Raises
        ------
        ValueError
            As :meth:`evaluate`, at the first ``next()``.
        """
        max_order = _check_order("max_order", max_order)
        seg, ta = self._segment(_as_times(t).reshape(-1))
        yield
        q, rates = yield from self._space_rate_steps(ta, seg, max_order)
        return Samples(ta, q, *(rates + [None] * (3 - len(rates))))

    def _space_rate_steps(self, t, seg, max_order):
        """:meth:`_space_rates` as a generator of steps (here: one)."""
        return self._space_rates(t, seg, max_order)
        yield  # makes this a generator

    def _space_rates(self, t, seg, max_order) -> tuple[np.ndarray, list[np.ndarray]]:
        """Unit quaternions (M, 4) and the space-frame angular derivatives of orders
        1..max_order, each (M, 3), from the path's jet."""
        qj = self._jet(t, seg, max_order)
        q = (qj.value / np.linalg.norm(qj.value, axis=0)).T
        if max_order == 0:
            return q, []
        # omega = 2 vec(q' q*), as a jet one order lower.
        w = J.qmul(qj.d(), J.qconj(qj))
        return q, [2.0 * w.derivative(n)[1:].T for n in range(max_order)]

    def __call__(self, t, order: int = 0, *, frame: str = "space") -> np.ndarray:
        """Orientation (order 0, shape (..., 4)) or angular velocity, acceleration,
        jerk (orders 1, 2, 3, shape (..., 3), rad/s^n) at times ``t`` (s).

        A scalar ``t`` gives one result, an array a stack.

        Raises
        ------
        ValueError
            If ``order`` is not in 0..3 or a time is outside the range.
        """
        order = _check_order("order", order)
        ta = _as_times(t)
        s = self._recall(ta.reshape(-1), order, frame)
        out = (s.q, s.omega, s.alpha, s.jerk)[order]
        # A copy: the samples stay in the cache below for the next call.
        return out.reshape(*ta.shape, out.shape[-1]).copy()

    #: The last evaluation made by ``__call__``: ``(t, frame, max_order, samples)``.
    _last: tuple | None = None

    def _recall(self, t: np.ndarray, order: int, frame: str) -> Samples:
        """Samples at times ``t`` (M,) up to ``order``, shared between calls at the same times.

        A scipy-style caller asks ``s(t)``, ``s(t, 1)``, ``s(t, 2)``: three calls at
        the same times. The first evaluates the orientation only; a call for a rate
        at the times of the call before evaluates the rates up to order 2 (or
        ``order`` if higher) at once and keeps them, so the third is read back. Only
        the last evaluation is kept (paths are immutable, so it never goes stale).
        """
        last = self._last
        same = (
            last is not None
            and last[1] == frame
            and last[0].shape == t.shape
            and np.array_equal(last[0], t)
        )
        if same and last[2] >= order:
            return last[3]
        max_order = max(order, 2) if same else order
        samples = self.evaluate(t, max_order=max_order, frame=frame)
        self._last = (t.copy(), frame, max_order, samples)
        return samples

    def sample(self, rate_hz: float, *, max_order: int = 2, frame: str = "space") -> Samples:
        """:meth:`evaluate` at ``rate_hz`` from ``t_start`` to ``t_end`` inclusive (the last
        sample at ``t_end`` even when the duration is not a whole number of periods; for a
        closed path too, whose ``t_end`` repeats the orientation at ``t_start``).

        Raises
        ------
        trajgen.PlanTooLarge
            Above :data:`trajgen.sampling.MAX_SAMPLES` samples, before allocating.
        """
        t = sample_times(self.t_start, self.t_end, rate_hz)
        return self.evaluate(t, max_order=max_order, frame=frame)


class Steps:
    """A generator of work steps (see :meth:`OrientationPath.evaluation_steps`) run one
    step at a time, and its return value once it has ended."""

    def __init__(self, steps):
        self._steps, self.done, self.result = steps, False, None

    def step(self) -> bool:
        """Do one step (nothing once done); True once done."""
        if not self.done:
            try:
                next(self._steps)
            except StopIteration as end:
                self.done, self.result = True, end.value
        return self.done

    def finish(self):
        """Do the remaining steps; the return value."""
        while not self.step():
            pass
        return self.result


def run_steps(steps):
    """Run a generator of work steps to its end; its return value."""
    return Steps(steps).finish()


def _as_times(t) -> np.ndarray:
    try:
        ta = np.asarray(t, dtype=float)
    except (TypeError, ValueError) as e:
        raise TypeError(f"Expected `t` to be numeric, got {type(t).__name__}.") from e
    if not np.isfinite(ta).all():
        raise BadArgument("Expected `t` to be finite.")
    return ta
