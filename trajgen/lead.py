"""Led goals: what to send a position servo so that it is where the plan says.

An X-series servo streamed a Goal Position with Profile Velocity 0 runs a
proportional loop whose drive does not cancel the motor's back-EMF, so it lags
a moving goal by about ``speed x tau``, ``tau = (K^2/R + b) / kp`` (45 ms for an
XM430-W350 at P 800; see ``docs/lead.md``). Sending each goal ahead of the plan
by what the loop needs removes that lag. With ``T`` the stream period (goals
are held for one period, hence ``T/2``) and ``s = t_i + T/2``:

- ``"advance"``: ``goal_i = q(t_i + tau + T/2)``, a point of the plan;
- ``"model"``: ``goal_i = q(s) + [tau_id(q, qd, qdd) + (K^2/R) qd](s) / kp``,
  ``tau_id`` the plan's inverse dynamics (inertia, gravity, viscous and Coulomb
  friction), supplied by the caller (``trajgen.sim.lead`` computes it with
  MuJoCo; this module stays numpy-only);
- ``"none"``: ``goal_i = q(t_i)``.

Bounded, because a goal is what moves a servo:

- the lead (goal minus plan, without the static gravity term) is capped at
  ``LEAD_CAP x tau max|qd|`` plus the Coulomb term, per joint;
- it is ramped in over ``tau`` from the first frame and out over ``tau``
  before the last (a quintic smoothstep), so a plan that starts moving does not
  get a goal step; the static gravity term ``tau_id(q, 0, 0) / kp`` is in full
  from the first frame and to the last (the last goal is ``q_end`` plus it):
  the model lead's goals come with a lift (:mod:`trajgen.lift`), frames sent
  before the plan's first while it holds still, which bring the static term in
  from the goal the servo holds (the plan's first point);
- every goal is clipped to the plan's own range of that joint widened by at
  most the static gravity/friction offset, and to the position limits given;
  with the joints' inertia (``LeadParams.inertia_kg_m2``) the model lead's goals
  around a clip are chosen again by the bounded preview
  (:mod:`trajgen.lead_preview`), inside the same bounds;
- a joint whose lead is switched off (its plan fails the torque check, where a
  saturated servo only pushes the goal further out) gets the plan.

The same arithmetic serves a whole planned trajectory (:func:`led_trajectory`,
what ``trajgen stream`` sends and ``trajgen sim`` simulates) and a live stream
one frame at a time (:class:`LedFrames`, ``trajgen follow``), with ``q(s)``,
``qd(s)`` from each frame's own ``q, qd, qdd`` (second-order Taylor).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from trajgen.errors import BadArgument
from trajgen.validate import check_choice

#: The lead variants, default first.
LEADS = ("model", "advance", "none")
DEFAULT_LEAD = "model"
#: Cap on the lead per joint, as a multiple of ``tau x max|qd|`` (the lag of the
#: fastest moment of the plan); the Coulomb term ``frictionloss / kp`` is added.
LEAD_CAP = 1.5

#: ``torque(q, qd, qdd)``: inverse-dynamics joint torque (N m), arrays (N, n) -> (N, n).
TorqueFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class LeadParams:
    """Per-joint parameters of the servos' position loops, for the lead.

    Attributes
    ----------
    kp_nm_rad : ndarray, shape (n,)
        Loop stiffness in torque space (N m/rad): ``P / p_divisor`` times the
        drive's N m per pulse.
    back_emf_nm_s_rad : ndarray, shape (n,)
        ``K^2/R`` (N m s/rad), the damping the drive leaves uncompensated.
    lag_s : ndarray, shape (n,)
        ``tau = (K^2/R + b) / kp`` (s), the lag behind a goal at constant speed.
    frictionloss_nm : ndarray, shape (n,)
        Coulomb friction (N m).
    enabled : ndarray of bool, shape (n,)
        Joints that get a lead (False: the plan is sent as it is).
    inertia_kg_m2 : ndarray, shape (n,), optional
        Each joint's inertia as its loop sees it (kg m^2: reflected rotor plus
        links). With it, a model lead that a bound clips is corrected by the
        bounded preview (:func:`preview_goals`); None: clipped goals stay clipped.
    """

    kp_nm_rad: np.ndarray
    back_emf_nm_s_rad: np.ndarray
    lag_s: np.ndarray
    frictionloss_nm: np.ndarray
    enabled: np.ndarray
    inertia_kg_m2: np.ndarray | None = None

    def __post_init__(self):
        n = None
        for name in ("kp_nm_rad", "back_emf_nm_s_rad", "lag_s", "frictionloss_nm"):
            a = np.array(getattr(self, name), dtype=float).reshape(-1)
            if (
                not np.all(np.isfinite(a))
                or np.any(a < 0)
                or (name == "kp_nm_rad" and a.min() <= 0)
            ):
                raise BadArgument(f"Expected `{name}` finite and >= 0 (kp > 0), got {a}.")
            if n is not None and len(a) != n:
                raise BadArgument(f"Expected `{name}` to have {n} entries, got {len(a)}.")
            n = len(a)
            object.__setattr__(self, name, a)
        enabled = np.broadcast_to(np.asarray(self.enabled, dtype=bool), (n,)).copy()
        object.__setattr__(self, "enabled", enabled)
        if self.inertia_kg_m2 is not None:
            inertia = np.array(self.inertia_kg_m2, dtype=float).reshape(-1)
            if len(inertia) != n or not np.all(np.isfinite(inertia)) or inertia.min() <= 0:
                raise BadArgument(
                    f"Expected `inertia_kg_m2` to have {n} finite entries > 0, got {inertia}."
                )
            object.__setattr__(self, "inertia_kg_m2", inertia)

    def without(self, joints) -> LeadParams:
        """These parameters with the lead switched off on ``joints`` (indices)."""
        enabled = self.enabled.copy()
        enabled[list(joints)] = False
        return replace(self, enabled=enabled)


@dataclass(frozen=True)
class LedGoals:
    """Goals of a whole trajectory and what bounded them.

    Attributes
    ----------
    goal : ndarray, shape (N, n)
        The goal to send at each frame (rad).
    lead : str
        The variant used.
    clipped : ndarray of int, shape (n,)
        Frames per joint whose goal the cap, the plan's range or the limits changed.
    bounds : ndarray, shape (n, 2)
        Lowest and highest goal allowed per joint (rad).
    wanted : ndarray, shape (N, n), optional
        The goals the lead asked for before the cap, the range and the limits
        (the ramps applied; rad), for diagnostics such as ``bench/lead_tracking.py``.
    lift : trajgen.lift.Lift, optional
        The frames to send before the first (the model lead's static term brought
        in while the plan holds still); None: none.
    """

    goal: np.ndarray
    lead: str
    clipped: np.ndarray
    bounds: np.ndarray
    wanted: np.ndarray | None = None
    lift: object = None


def check_lead(lead) -> str:
    """``lead`` if it is one of :data:`LEADS`; raise BadArgument naming them otherwise."""
    return check_choice("lead", lead, LEADS)


def ramp(x) -> np.ndarray:
    """Quintic smoothstep ``10 x^3 - 15 x^4 + 6 x^5`` of ``x`` clipped to [0, 1]."""
    x = np.clip(np.asarray(x, dtype=float), 0.0, 1.0)
    return x**3 * (10.0 - 15.0 * x + 6.0 * x**2)


def plan_bounds(q, gravity_nm, params: LeadParams, limits_rad=None) -> np.ndarray:
    """The range a goal may take per joint: the plan's own, widened by the static offset.

    Parameters
    ----------
    q : ndarray, shape (N, n)
        Planned joint angles (rad).
    gravity_nm : ndarray, shape (N, n) or None
        Gravity torque at the plan's angles (N m); None: no gravity term.
    params : LeadParams
    limits_rad : array_like, shape (n, 2), optional
        Position limits (rad) the goals must also stay inside.

    Returns
    -------
    ndarray, shape (n, 2)
        ``[min q - offset, max q + offset]`` intersected with ``limits_rad``, where
        ``offset = (max |gravity| + frictionloss) / kp`` (rad).
    """
    q = np.asarray(q, dtype=float)
    g = 0.0 if gravity_nm is None else np.abs(np.asarray(gravity_nm, dtype=float)).max(axis=0)
    offset = (g + params.frictionloss_nm) / params.kp_nm_rad
    bounds = np.stack([q.min(axis=0) - offset, q.max(axis=0) + offset], axis=1)
    if limits_rad is not None:
        limits = np.asarray(limits_rad, dtype=float)
        bounds = np.stack(
            [np.maximum(bounds[:, 0], limits[:, 0]), np.minimum(bounds[:, 1], limits[:, 1])],
            axis=1,
        )
    return bounds


def lead_cap(qd, params: LeadParams) -> np.ndarray:
    """Largest lead per joint (rad), shape (n,): ``LEAD_CAP tau max|qd| + frictionloss / kp``."""
    speed = np.abs(np.asarray(qd, dtype=float)).max(axis=0)
    return LEAD_CAP * params.lag_s * speed + params.frictionloss_nm / params.kp_nm_rad


def _advance_q(t, q, qd, times) -> np.ndarray:
    """Joint ``j`` of the plan at ``times[:, j]`` (clamped to its span), shape (N, n):
    cubic Hermite through ``(q, qd)``."""
    t = np.asarray(t, dtype=float)
    times = np.clip(times, t[0], t[-1])
    i = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 2)
    h = t[i + 1] - t[i]
    x = (times - t[i]) / h
    h00, h10 = 2 * x**3 - 3 * x**2 + 1, x**3 - 2 * x**2 + x
    h01, h11 = -2 * x**3 + 3 * x**2, x**3 - x**2
    j = np.arange(q.shape[1])
    return h00 * q[i, j] + h10 * h * qd[i, j] + h01 * q[i + 1, j] + h11 * h * qd[i + 1, j]


def _raw_goal(lead, t, q, qd, qdd, period_s, params, torque, t_end, advance_q):
    """Unbounded goals and the part of them that is the static gravity term.

    ``h = min(T/2, t_end - t)`` per frame; ``q(s)``, ``qd(s)`` by Taylor from the
    frame's own ``q, qd, qdd``. Returns ``(plan_at_s, lead, static)``, each (N, n):
    the goal is ``plan_at_s + w lead + static`` before the bounds.
    """
    h = np.minimum(0.5 * period_s, np.maximum(t_end - t, 0.0))[:, None]
    zero = np.zeros_like(q)
    if lead == "none":
        return q, zero, zero
    if lead == "advance":
        ahead = advance_q(t[:, None] + h + params.lag_s[None, :])
        return q, ahead - q, zero
    q_s = q + qd * h + 0.5 * qdd * h**2
    qd_s = qd + qdd * h
    tau = np.asarray(torque(q_s, qd_s, qdd), dtype=float)
    gravity = np.asarray(torque(q_s, zero, zero), dtype=float)
    dynamic = (tau - gravity + params.back_emf_nm_s_rad * qd_s) / params.kp_nm_rad
    return q_s, dynamic, gravity / params.kp_nm_rad


def _weights(t, t_start, t_end, lag_s) -> tuple[np.ndarray, np.ndarray]:
    """The ramp in from ``t_start`` and the ramp out to ``t_end``, each over the
    joint's lag, (N, n) each."""
    width = np.maximum(lag_s, 1e-9)[None, :]
    return ramp((t[:, None] - t_start) / width), ramp((t_end - t[:, None]) / width)


def _band(plan_at_s, static, w_in, w_out, cap, bounds):
    """Each frame's lowest and highest goal, (N, n) each: the range intersected with
    the cap around the plan (``plan + static +- w_in w_out cap``)."""
    centre, half = plan_at_s + static, w_in * w_out * cap
    lo = np.clip(centre - half, bounds[:, 0], bounds[:, 1])
    hi = np.clip(centre + half, bounds[:, 0], bounds[:, 1])
    return lo, hi


def _bound(plan_at_s, lead, static, w_in, w_out, cap, bounds, enabled, q):
    """Apply the cap, the ramps, the range and the enabled mask; return (goal, clipped).

    The dynamic lead is ramped in and out; the static gravity term is in full (the
    lift brought it in; it ends on ``q_end`` + gravity). The cap and the ramps clip
    ``w_in w_out lead`` to ``+- w_in w_out cap`` around ``static`` (the same as
    capping the lead, then ramping).
    """
    unbounded = plan_at_s + w_in * w_out * lead + static
    lo, hi = _band(plan_at_s, static, w_in, w_out, cap, bounds)
    bounded = np.clip(unbounded, lo, hi)
    goal = np.where(enabled[None, :], bounded, q)
    changed = bounded != unbounded
    return goal, (changed & enabled[None, :]).sum(axis=0)


def led_goals(
    trajectory,
    lead: str,
    params: LeadParams,
    *,
    torque: TorqueFn | np.ndarray | None = None,
    limits_rad=None,
) -> LedGoals:
    """The goals to send for a whole planned trajectory.

    Parameters
    ----------
    trajectory : JointTrajectory
        ``t`` (N,), ``q``, ``qd``, ``qdd`` (N, n), ``rate_hz``.
    lead : {"model", "advance", "none"}
    params : LeadParams
    torque : callable, optional
        ``torque(q, qd, qdd)`` -> (N, n) N m, the inverse dynamics; needed by
        ``"model"`` (its gravity term is ``torque(q, 0, 0)``).
    limits_rad : array_like, shape (n, 2), optional
        Position limits (rad) every goal must stay inside.

    Returns
    -------
    LedGoals

    Raises
    ------
    ValueError
        If ``lead`` is unknown, or ``"model"`` is asked without ``torque``.
    """
    lead = check_lead(lead)
    if lead == "model" and torque is None:
        raise BadArgument('Expected `torque` (the inverse dynamics) for lead = "model".')
    t = np.asarray(trajectory.t, dtype=float)
    q, qd, qdd = (np.asarray(a, dtype=float) for a in (trajectory.q, trajectory.qd, trajectory.qdd))
    period = 1.0 / float(trajectory.rate_hz)
    plan_at_s, raw, static = _raw_goal(
        lead, t, q, qd, qdd, period, params, torque, t[-1], lambda x: _advance_q(t, q, qd, x)
    )
    zero = np.zeros_like(q)
    gravity = None if lead != "model" else torque(q, zero, zero)
    bounds = plan_bounds(q, gravity, params, limits_rad)
    if lead == "none":  # the plan as it is: a plan outside the limits is refused, not clipped
        return LedGoals(q.copy(), lead, np.zeros(q.shape[1], dtype=int), bounds, q.copy())
    w_in, w_out = _weights(t, t[0], t[-1], params.lag_s)
    cap = lead_cap(qd, params)
    lift = None
    if lead == "model":
        from trajgen.lift import plan_lift

        lift = plan_lift(q[0], t[0], trajectory.rate_hz, params, torque, bounds)
    if lead == "model" and params.inertia_kg_m2 is not None:
        goals = _previewed(plan_at_s, raw, static, w_in, w_out, cap, bounds, params, q, period)
        return replace(goals, lift=lift)
    goal, clipped = _bound(plan_at_s, raw, static, w_in, w_out, cap, bounds, params.enabled, q)
    wanted = np.where(params.enabled[None, :], plan_at_s + w_in * w_out * raw + static, q)
    return LedGoals(goal, lead, clipped, bounds, wanted, lift)


def _previewed(plan_at_s, lead, static, w_in, w_out, cap, bounds, params, q, period):
    """The model lead's goals with their clips anticipated (``trajgen.lead_preview``)."""
    from trajgen.lead_preview import preview_goals

    unbounded = plan_at_s + w_in * w_out * lead + static
    lo, hi = _band(plan_at_s, static, w_in, w_out, cap, bounds)
    c = params.kp_nm_rad * params.lag_s
    goal, changed = preview_goals(
        unbounded, lo, hi, period, params.kp_nm_rad, c, params.inertia_kg_m2
    )
    enabled = params.enabled
    goal = np.where(enabled[None, :], goal, q)
    wanted = np.where(enabled[None, :], unbounded, q)
    return LedGoals(goal, "model", np.where(enabled, changed, 0), bounds, wanted)


def led_trajectory(trajectory, goals: LedGoals):
    """``trajectory`` with its goals and its lift attached (``JointTrajectory.goal``,
    ``JointTrajectory.lift``)."""
    return replace(trajectory, goal=goals.goal, lift=goals.lift)


class LedFrames:
    """Led goals of a live stream, one frame at a time (``trajgen follow``).

    Each frame's goal comes from that frame's own ``q, qd, qdd`` (the model
    lead by Taylor to ``t + T/2``; the advance lead by Taylor to
    ``t + tau + T/2``), ramped in over ``tau`` from the first frame, capped at
    ``cap_rad`` and clipped to ``bounds_rad`` (the range the live plan may use).
    No ramp out: a live plan's end is not known ahead; it ends at rest, where
    the lead is the static gravity term. The model lead's static term is in
    full from the first frame: once the first frame is drawn, :attr:`lift`
    holds the lift to send before it (:func:`trajgen.lift.plan_lift` from the
    first frame's ``q``, inside ``bounds_rad``), as for a planned trajectory.

    Parameters
    ----------
    frames : iterable of JointFrame
    rate_hz : float
    lead : {"model", "advance", "none"}
    params : LeadParams
    bounds_rad : array_like, shape (n, 2)
        Lowest and highest goal per joint (rad).
    cap_rad : array_like, shape (n,)
        Largest lead per joint (rad), e.g. :func:`lead_cap` of the fastest the
        live plan may move.
    torque : callable, optional
        As for :func:`led_goals`; needed by ``"model"``.

    Yields
    ------
    JointFrame
        The frame with ``goal`` set.

    Attributes
    ----------
    lift : trajgen.lift.Lift or None
        Set when the first frame is drawn (None before, and without a static term).
    """

    def __init__(self, frames: Iterable, rate_hz, lead, params, bounds_rad, cap_rad, torque=None):
        self.lead = check_lead(lead)
        if self.lead == "model" and torque is None:
            raise BadArgument('Expected `torque` (the inverse dynamics) for lead = "model".')
        self._frames = frames
        self.period_s = 1.0 / float(rate_hz)
        self.params = params
        self.bounds = np.asarray(bounds_rad, dtype=float)
        self.cap = np.asarray(cap_rad, dtype=float)
        self.torque = torque
        self.lift = None

    def __iter__(self) -> Iterator:
        t_start = None
        for frame in self._frames:
            if t_start is None:
                t_start = frame.t
                if self.lead == "model":
                    from trajgen.lift import plan_lift

                    self.lift = plan_lift(
                        frame.q, frame.t, 1.0 / self.period_s, self.params, self.torque, self.bounds
                    )
            yield replace(frame, goal=self.goal(frame, t_start))

    def goal(self, frame, t_start: float) -> np.ndarray:
        """The bounded goal (rad, shape (n,)) of one frame of a stream that began at ``t_start``."""
        t = np.array([float(frame.t)])
        q, qd, qdd = (np.asarray(a, dtype=float)[None, :] for a in (frame.q, frame.qd, frame.qdd))
        if self.lead == "none":
            return q[0].copy()

        def ahead(times):  # the advance lead's q(t + tau + T/2), by Taylor
            dt = times - t[:, None]
            return q + qd * dt + 0.5 * qdd * dt**2

        plan_at_s, raw, static = _raw_goal(
            self.lead, t, q, qd, qdd, self.period_s, self.params, self.torque, np.inf, ahead
        )
        w_in = ramp((t[0] - t_start) / np.maximum(self.params.lag_s, 1e-9))[None, :]
        enabled = self.params.enabled
        goal, _ = _bound(plan_at_s, raw, static, w_in, 1.0, self.cap, self.bounds, enabled, q)
        return goal[0]


def sent_q(trajectory_or_frame) -> np.ndarray:
    """What is sent: the ``goal`` if one is attached, else the planned ``q``."""
    goal = getattr(trajectory_or_frame, "goal", None)
    return trajectory_or_frame.q if goal is None else goal
