"""A run-in from rest and a run-out to rest: the same path, its speed ramped at both ends.

A servo at rest cannot follow a plan that starts moving (a ``boundary =
"closed"`` loop, or any path whose first keyframe has a speed): at its first
frame the goal runs away at full speed and the servo must catch up. A
:class:`RunIn` is a time law ``s(t)`` that plays the path's own clock from
speed 0 to speed 1 over ``D`` seconds, at speed 1 in the middle, and back to 0
over the last ``D`` seconds:

    s'(t) = p(t / D)  on [0, D],   1  in the middle,   p((t_end - t) / D)  on the last D,

with ``p(x) = 35 x^4 - 84 x^5 + 70 x^6 - 20 x^7`` the septic smoothstep
(``p(0) = 0``, ``p(1) = 1``, its first three derivatives 0 at both ends). So
``s`` is C4 everywhere, ``s' = s'' = s''' = 0`` at both ends, and the motion
``q(t) = path(s(t))`` (a :class:`~trajgen.timelaw.RetimedPath`) is C3, starts and
ends at rest with zero acceleration and jerk, and passes every keyframe in
order. Each ramp plays ``D / 2`` seconds of the path in ``D`` seconds, so the
motion lasts the path's duration plus ``D``. It is the file's
``[stream] run_in_s``: an explicit, stated change of the clock, never of the path,
and ``trajgen plan``, ``sim`` and ``stream`` all play it.
"""

from __future__ import annotations

import numpy as np

from .errors import BadArgument
from .timelaw import RetimedPath
from .validate import check_number

#: The septic smoothstep ``p`` (the speed ramp) and its integral ``P`` (``P(1) = 1/2``),
#: as polynomial coefficients, highest power first.
SPEED_RAMP = np.array([-20.0, 70.0, -84.0, 35.0, 0.0, 0.0, 0.0, 0.0])
DISTANCE_RAMP = np.polyint(SPEED_RAMP)


class RunIn:
    """The time law of a run-in and run-out of ``run_in_s`` each (see the module docstring).

    Parameters
    ----------
    s_start, s_end : float
        The path's own first and last time (s); ``s_end - s_start >= run_in_s``.
    run_in_s : float
        ``D`` (s), > 0.
    t_start : float
        The motion's first time (s); default ``s_start``.

    Raises
    ------
    BadArgument
        If ``run_in_s`` is not > 0 or longer than the path.
    """

    def __init__(self, s_start: float, s_end: float, run_in_s: float, t_start: float | None = None):
        self.s_start = check_number("s_start", s_start)
        span = check_number("s_end", s_end) - self.s_start
        self.run_in_s = check_number("run_in_s", run_in_s, low=0.0, low_open=True)
        if self.run_in_s > span:
            raise BadArgument(
                f"Expected `run_in_s` at most the path's {span:g} s (each ramp plays half "
                f"of it at half speed on average), got {self.run_in_s:g}."
            )
        self.s_span = span
        self.t_start = self.s_start if t_start is None else check_number("t_start", t_start)

    @property
    def t_end(self) -> float:
        """The motion's last time (s): the path's duration plus ``run_in_s`` later."""
        return self.t_start + self.s_span + self.run_in_s

    def __call__(self, t, max_order: int = 3) -> list[np.ndarray]:
        """``[s, s', s'', s''']`` up to ``max_order`` at motion times ``t`` (M,).

        Units: s, 1, 1/s, 1/s^2 (path time over motion time).
        """
        d = self.run_in_s
        duration = self.t_end - self.t_start
        u = np.clip(np.asarray(t, dtype=float) - self.t_start, 0.0, duration)
        ramp_in, ramp_out = u < d, u > duration - d
        x_in, x_out = np.clip(u / d, 0.0, 1.0), np.clip((duration - u) / d, 0.0, 1.0)
        s = np.where(ramp_in, d * np.polyval(DISTANCE_RAMP, x_in), 0.5 * d + (u - d))
        s = np.where(ramp_out, self.s_span - d * np.polyval(DISTANCE_RAMP, x_out), s)
        out = [self.s_start + s]
        derivative = SPEED_RAMP
        for m in range(1, max_order + 1):
            middle = 1.0 if m == 1 else 0.0
            value = np.where(ramp_in, np.polyval(derivative, x_in), middle)
            value = np.where(ramp_out, (-1.0) ** (m - 1) * np.polyval(derivative, x_out), value)
            out.append(value / d ** (m - 1))
            derivative = np.polyder(derivative)
        return out

    def inverse(self, s) -> np.ndarray:
        """Motion times (M,) at which path times ``s`` (M,) are reached (bisection,
        60 halvings: to 1e-18 of the motion's duration; ``s`` is increasing)."""
        target = np.clip(np.asarray(s, dtype=float), self.s_start, self.s_start + self.s_span)
        lo = np.full_like(target, self.t_start)
        hi = np.full_like(target, self.t_end)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            below = self(mid, 0)[0] < target
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        return 0.5 * (lo + hi)


def run_in(path, run_in_s: float) -> RetimedPath:
    """``path`` played from rest and back to rest by a :class:`RunIn` of ``run_in_s``.

    Parameters
    ----------
    path : OrientationPath
        Any path (a spline, or a :class:`~trajgen.timelaw.RetimedPath`).
    run_in_s : float
        Length of each ramp (s); at most the path's duration.

    Returns
    -------
    RetimedPath
        Starts at ``path.t_start``, lasts ``run_in_s`` longer than ``path``.
    """
    return RetimedPath(path, RunIn(path.t_start, path.t_end, run_in_s))


def starts_or_ends_moving(qd, tolerance: float = 1e-9) -> bool:
    """Whether a planned joint velocity (N, n) rad/s is not at rest at its first or last frame."""
    qd = np.asarray(qd, dtype=float)
    return bool(np.abs(qd[0]).max() > tolerance or np.abs(qd[-1]).max() > tolerance)
