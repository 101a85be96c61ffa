"""The lift: the static gravity term brought in before the plan moves.

A position servo holding a goal against gravity sits below it: its loop gives
torque ``kp e`` only for an error ``e``, so it rests where ``kp (goal - q) =
g(q)``, the *sagged equilibrium* (:func:`sagged`). A stream starts from the goal
the servo holds, the plan's first point ``q0`` (``drivers.bringup``), so the
servo starts ``g/kp`` below its plan. The model lead (``trajgen.lead``) sends
``q0 + g(q0)/kp`` to hold the plan's first point; sending it on the first frame
would be a goal step of the whole sag.

The lift comes first instead, while the plan holds still at ``q0``: frames at
the stream rate whose goals carry the servo from where it sags to ``q0``. They
are the model lead of a lift motion ``y(s) = y_0 + (q0 - y_0) r((s - s_0)/D)``,
``y_0`` the sagged equilibrium under ``q0`` and ``r`` the nonic smoothstep
``126 x^5 - 420 x^6 + 540 x^7 - 315 x^8 + 70 x^9`` (its first four
derivatives 0 at both ends), so each goal is

    goal_k = y(s_k) + [tau_id(y, y', y'') + (K^2/R) y'](s_k) / kp,   s_k = t_k + T/2

(``T`` the stream period; a goal is held one period). The first goal is the
goal held, ``y_0 + g(y_0)/kp = q0``; the last is the first led goal of the
plan, ``q0 + g(q0)/kp``; in between the goal moves smoothly (C2: ``r`` is C4),
and it stays inside the plan's goal bounds (the plan's range widened by the
static offset, and the position limits), clipped to them.

How long: the loop ``J e'' + c e' + kp e`` (``c = kp tau``) forgets where it
started with its slowest time constant ``tau_s`` (``2 J / c`` when it is
underdamped, the slow real pole otherwise; ``tau`` as ``J -> 0``;
:func:`settle_time_s`). A held servo really sits anywhere in the Coulomb
friction's band ``+-frictionloss/kp`` around the sagged equilibrium; the lift
lasts ``LIFT_SETTLE = 3`` of the slowest joint's ``tau_s``, so at most
``e^-3`` (5 %) of that start error is left when the plan starts (0.59 s on an
XL330-M288 with the pan-tilt head's camera, 0.32 s on the XM430 gimbal).

Numpy only: the inverse dynamics ``tau_id`` comes from the caller
(``trajgen.sim.lead`` computes it with MuJoCo).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import BadArgument

#: How many of the loop's slowest time constants the lift lasts.
LIFT_SETTLE = 3.0
#: The nonic smoothstep ``r`` of the lift motion, polynomial coefficients, highest power first.
LIFT_RAMP = np.array([70.0, -315.0, 540.0, -420.0, 126.0, 0.0, 0.0, 0.0, 0.0, 0.0])
#: Fixed-point iterations allowed for the sagged equilibrium, and its tolerance (rad).
_SAG_ITERATIONS, _SAG_TOLERANCE_RAD = 100, 1e-13


@dataclass(frozen=True)
class Lift:
    """The frames sent before a plan's first frame while its first point is held.

    Attributes
    ----------
    t : ndarray, shape (M,)
        Frame times (s): the stream period apart, the last one period before
        the plan's first frame.
    goal : ndarray, shape (M, n)
        The goals (rad): from the plan's first point (the goal held) to the
        plan's first led goal.
    path : ndarray, shape (M, n)
        Where each goal aims the servo (rad), the lift motion at ``t + T/2``:
        from :attr:`sagged` to :attr:`q`.
    q : ndarray, shape (n,)
        The plan's first point (rad), which the plan holds during the lift.
    sagged : ndarray, shape (n,)
        Where the servo rests under the goal ``q`` (rad), the lift's start.
    rate_hz : float
        The stream rate (Hz).
    """

    t: np.ndarray
    goal: np.ndarray
    path: np.ndarray
    q: np.ndarray
    sagged: np.ndarray
    rate_hz: float

    def __len__(self) -> int:
        return len(self.t)

    @property
    def duration_s(self) -> float:
        """How long the lift takes (s): its frames, one period each."""
        return len(self.t) / self.rate_hz


def sagged(goal, kp_nm_rad, gravity) -> np.ndarray:
    """Where servos holding ``goal`` rest under gravity: ``q = goal - g(q) / kp``.

    Parameters
    ----------
    goal : array_like, shape (n,)
        The goal each servo holds (rad).
    kp_nm_rad : array_like, shape (n,)
        The loops' stiffness (N m/rad).
    gravity : callable
        ``gravity(q)`` for ``q`` (n,): the torque (N m, (n,)) holding ``q`` at rest
        needs (the inverse dynamics at zero speed and acceleration).

    Returns
    -------
    ndarray, shape (n,)
        The frictionless equilibrium (rad); Coulomb friction lets a servo rest
        anywhere within ``frictionloss / kp`` of it.

    Raises
    ------
    BadArgument
        If the iteration does not settle (gravity stiffer than the loop: the
        servo cannot hold the load still).
    """
    goal = np.asarray(goal, dtype=float)
    kp = np.asarray(kp_nm_rad, dtype=float)
    q = goal.copy()
    for _ in range(_SAG_ITERATIONS):
        nxt = goal - np.asarray(gravity(q), dtype=float) / kp
        if np.max(np.abs(nxt - q)) <= _SAG_TOLERANCE_RAD:
            return nxt
        q = nxt
    raise BadArgument(
        f"Expected servos that can hold {goal} rad against gravity, but the sag does not "
        "settle: gravity is stiffer than the position loop."
    )


def settle_time_s(params) -> np.ndarray:
    """Each joint's slowest loop time constant (s), shape (n,), from a ``LeadParams``.

    The poles of ``J s^2 + c s + kp`` (``c = kp tau``): ``2 J / c`` when
    underdamped (``c^2 < 4 kp J``), else ``2 J / (c - sqrt(c^2 - 4 kp J))``; the
    lag ``tau`` without inertia (``J -> 0``).
    """
    kp, lag = params.kp_nm_rad, params.lag_s
    c = kp * lag
    inertia = params.inertia_kg_m2
    if inertia is None:
        return lag.copy()
    disc = c**2 - 4.0 * kp * inertia
    slow = np.where(disc < 0, c, c - np.sqrt(np.maximum(disc, 0.0)))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(slow > 0, 2.0 * inertia / slow, lag)


def lift_frames(duration_s: float, rate_hz: float) -> int:
    """Frames of a lift of at least ``duration_s`` (s) at ``rate_hz``: ``ceil(D rate) + 1``
    (the first holds the goal held, the last aims at the lift's end)."""
    return math.ceil(duration_s * rate_hz - 1e-9) + 1


def plan_lift(q0, t0: float, rate_hz: float, params, torque, bounds, static=None) -> Lift | None:
    """The lift before a plan that starts at ``q0`` at ``t0`` (see the module docstring).

    Parameters
    ----------
    q0 : array_like, shape (n,)
        The plan's first point (rad): the goal the servos hold.
    t0 : float
        The plan's first frame time (s).
    rate_hz : float
        Stream rate (Hz).
    params : trajgen.lead.LeadParams
        The loops (``kp``, ``K^2/R``, ``tau``, inertia); joints not ``enabled``
        keep the goal ``q0`` (no lead, no lift).
    torque : callable
        ``torque(q, qd, qdd)`` -> (N, n) N m, the inverse dynamics.
    bounds : array_like, shape (n, 2)
        Lowest and highest goal per joint (rad).
    static : array_like, shape (n,), optional
        The static term ``g(q0)/kp`` (rad) if the caller has it.

    Returns
    -------
    Lift or None
        None when no enabled joint has a static term to lift.
    """
    q0 = np.asarray(q0, dtype=float)
    zero = np.zeros((1, len(q0)))

    def gravity(q):
        return np.asarray(torque(np.asarray(q, float)[None, :], zero, zero), dtype=float)[0]

    kp = params.kp_nm_rad
    if static is None:
        static = gravity(q0) / kp
    enabled = params.enabled
    if not np.any(enabled & (np.abs(static) > 0)):
        return None
    start = np.where(enabled, sagged(q0, kp, gravity), q0)
    period = 1.0 / float(rate_hz)
    moving = enabled & (np.abs(static) > 0)
    duration = LIFT_SETTLE * float(settle_time_s(params)[moving].max())
    m = lift_frames(duration, rate_hz)
    t = t0 - period * np.arange(m, 0, -1)
    span = (m - 1) * period
    x = (np.arange(m) * period) / span
    rise = q0 - start
    y = start + rise * np.polyval(LIFT_RAMP, x)[:, None]
    yd = rise * (np.polyval(np.polyder(LIFT_RAMP), x) / span)[:, None]
    ydd = rise * (np.polyval(np.polyder(LIFT_RAMP, 2), x) / span**2)[:, None]
    tau = np.asarray(torque(y, yd, ydd), dtype=float)
    goal = y + (tau + params.back_emf_nm_s_rad * yd) / kp
    goal[0] = q0  # the goal held (the formula gives it to the sag's tolerance)
    goal[-1] = q0 + static  # the plan's first led goal (y = q0 at rest)
    bounds = np.asarray(bounds, dtype=float)
    goal = np.clip(goal, bounds[:, 0], bounds[:, 1])
    goal = np.where(enabled[None, :], goal, q0)
    path = np.where(enabled[None, :], y, start)
    return Lift(t=t, goal=goal, path=path, q=q0, sagged=start, rate_hz=float(rate_hz))


def sent_goals(trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Every frame a trajectory sends, in order: its lift's (if any), then its own.

    Returns
    -------
    t : ndarray, shape (M + N,)
        Frame times (s).
    goal : ndarray, shape (M + N, n)
        The goal of each frame (rad): ``goal`` where attached, else ``q``.
    """
    goal = getattr(trajectory, "goal", None)
    goal = np.asarray(trajectory.q if goal is None else goal, dtype=float)
    t = np.asarray(trajectory.t, dtype=float)
    lift = getattr(trajectory, "lift", None)
    if lift is None:
        return t, goal
    return np.concatenate([lift.t, t]), np.vstack([lift.goal, goal])
