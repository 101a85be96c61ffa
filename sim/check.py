"""The torque check: does a planned motion stay inside the servos' torque-speed envelope?

Two parts, both per joint:

(a) Plan: the torque the plan needs (``mj_inverse`` on the planned ``q, qd, qdd``)
    must stay within ``torque_margin * tau_max(qd)``, where
    ``tau_max(w) = tau_stall (1 - |w| / w0)`` at the servo's rated voltage
    (``trajgen.servo_table``: 12 V for the 430 and 540 cases, 5 V for the 330s).
(b) Simulation: the stream is played to the simulated servos (goal positions
    in whole ticks, zero-order hold, 1 ms physics, the firmware's position loop
    with the configured gains); no step may reach the servo's torque limit (the
    drive at the rated voltage, or the stall-torque clamp when braking), and the
    joints must stay within ``max_tracking_error_rad`` of the planned path (the
    plan, not the goals sent). With default gains (P 800) an X-series servo lags
    a moving goal by about speed x 45 ms (``lag_time_s``); the goals sent are
    led ahead of the plan by that lag (``trajgen.lead``, default ``"model"``:
    about 1 mrad of error left), and must stay inside the plan's own range
    widened by the static gravity/friction offset.

The verdict ``ok`` needs all three. The simulated torque's own margin against
``torque_margin x envelope`` is reported but does not decide the verdict.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from trajgen.keyframes import DEFAULT_RATE_HZ
from trajgen.lead import DEFAULT_LEAD, check_lead
from trajgen.lift import sent_goals
from trajgen.path import run_steps
from trajgen.sim.errors import SimulationError, TorqueLimitExceeded
from trajgen.sim.model import GimbalConfig
from trajgen.sim.run import SimRecord, check_trajectory, simulate, simulation_model
from trajgen.sim.servos import servo_by_name

from .errors import BadArgument


@dataclass(frozen=True)
class JointReport:
    """Torque figures of one joint (SI units).

    Attributes
    ----------
    name, servo : str
        Joint name and servo model.
    peak_planned_torque_nm : float
        Max |planned torque| (N m), from ``mj_inverse``.
    peak_torque_nm : float
        Max |simulated actuator torque| (N m).
    peak_torque_rate_nm_s : float
        Max |d(planned torque)/dt| (N m/s), by differences between stream
        samples, without Coulomb friction (which steps at every start and
        reversal whatever the plan).
    rms_torque_nm : float
        RMS simulated torque (N m).
    max_tracking_error_rad : float
        Max |simulated angle - planned path| (rad), from the plan's first frame.
    max_lift_error_rad : float
        Max |simulated angle - the plan's first point| (rad) during the lift
        before it (``trajgen.lift``: from where the servo sags); 0 without one.
    worst_planned_margin_nm : float
        ``min over samples of (margin tau_max(qd) - |tau|)`` for the plan (N m);
        negative means the plan leaves the envelope x margin.
    worst_margin_nm : float
        The same for the simulated torque and speed (N m); reported only.
    peak_speed_rad_s : float
        Max |planned joint speed| (rad/s).
    steps_at_limit : int
        Physics steps at the torque limit: the drive at the rated voltage, or the
        stall-torque clamp when braking (the lift's included).
    ok : bool
    reasons : tuple of str
        Why not ok (empty when ok).
    """

    name: str
    servo: str
    peak_planned_torque_nm: float
    peak_torque_nm: float
    peak_torque_rate_nm_s: float
    rms_torque_nm: float
    max_tracking_error_rad: float
    worst_planned_margin_nm: float
    worst_margin_nm: float
    peak_speed_rad_s: float
    steps_at_limit: int
    ok: bool
    reasons: tuple[str, ...]
    max_lift_error_rad: float = 0.0


@dataclass(frozen=True)
class TorqueReport:
    """The torque check's verdict with per-joint figures.

    Attributes
    ----------
    ok : bool
        True when every joint passes.
    reasons : tuple of str
        Every joint's reasons for failing (empty when ok).
    joints : dict of str to JointReport
        Keyed by joint name (``config.names``), base out.
    torque_margin, max_tracking_error_rad : float
        The thresholds used.
    rate_hz, duration_s : float
        Stream rate (Hz) and duration (s).
    trajectory : JointTrajectory
        The plan checked.
    planned_torque_nm : ndarray, shape (N, n)
        Torque the plan needs at each stream sample (N m).
    record : SimRecord
        The simulated run.
    config : GimbalConfig
    planned_torque_smooth_nm : ndarray, shape (N, n), or None
        The planned torque without Coulomb friction (N m), which steps by twice
        the friction at every start and reversal whatever the plan.
    lead : str
        How the goals sent were led ahead of the plan (``trajgen.lead``).
    lead_notes : tuple of str
        Joints that got no lead, and why.
    goal_bounds_rad : ndarray, shape (n, 2), or None
        The range the goals had to stay inside (rad).
    lift_s : float
        How long the lift before the plan lasted (s; ``trajgen.lift``), 0 without one.
    """

    ok: bool
    reasons: tuple[str, ...]
    joints: dict
    torque_margin: float
    max_tracking_error_rad: float
    rate_hz: float
    duration_s: float
    trajectory: object = field(repr=False)
    planned_torque_nm: np.ndarray = field(repr=False)
    record: SimRecord = field(repr=False)
    config: GimbalConfig = field(repr=False)
    planned_torque_smooth_nm: np.ndarray | None = field(default=None, repr=False)
    lead: str = "none"
    lead_notes: tuple[str, ...] = ()
    goal_bounds_rad: np.ndarray | None = field(default=None, repr=False)
    lift_s: float = 0.0

    def to_json_dict(self) -> dict:
        """Plain-JSON summary: ``{"ok", "reasons", ..., "joints": {"pan": {...}, ...}}``."""
        joints = {}
        for name, joint in self.joints.items():
            d = asdict(joint)
            d.pop("name")
            d["reasons"] = list(joint.reasons)
            joints[name] = d
        return {
            "ok": self.ok,
            "reasons": list(self.reasons),
            "rate_hz": self.rate_hz,
            "duration_s": self.duration_s,
            "torque_margin": self.torque_margin,
            "max_tracking_error_rad": self.max_tracking_error_rad,
            "lead": self.lead,
            "lead_notes": list(self.lead_notes),
            "lift_s": self.lift_s,
            "joints": joints,
        }

    @property
    def envelope_volts(self) -> str:
        """The supply voltage(s) of the joints' envelopes, e.g. ``"12 V"`` or ``"5 V / 12 V"``."""
        volts = sorted({servo_by_name(j.servo).voltage_v for j in self.joints.values()})
        return " / ".join(f"{v:g} V" for v in volts)

    def format(self) -> str:
        """A readable table of the per-joint figures and the verdict."""
        verdict = "OK" if self.ok else "FAILED"
        w = max(6, 1 + max(len(name) for name in self.joints))  # the joint column
        lines = [
            f"torque check: {verdict} ({self.duration_s:.2f} s at {self.rate_hz:g} Hz, "
            f"margin {self.torque_margin:g} of the {self.envelope_volts} envelope, "
            f"tracking limit {math.degrees(self.max_tracking_error_rad):.1f} deg; "
            f"lead {self.lead})",
            f"{'joint':<{w}}{'servo':<12}{'plan':>8}{'sim':>8}{'rate':>9}{'rms':>8}"
            f"{'margin':>9}{'speed':>8}{'error':>8}{'limit':>8}",
            f"{'':<{w}}{'':<12}{'N m':>8}{'N m':>8}{'N m/s':>9}{'N m':>8}"
            f"{'N m':>9}{'rad/s':>8}{'deg':>8}{'steps':>8}",
        ]
        for j in self.joints.values():
            lines.append(
                f"{j.name:<{w}}{j.servo:<12}"
                + _cell(j.peak_planned_torque_nm, 8, 3)
                + _cell(j.peak_torque_nm, 8, 3)
                + _cell(j.peak_torque_rate_nm_s, 9, 2)
                + _cell(j.rms_torque_nm, 8, 3)
                + _cell(j.worst_planned_margin_nm, 9, 3)
                + _cell(j.peak_speed_rad_s, 8, 2)
                + _cell(math.degrees(j.max_tracking_error_rad), 8, 2)
                + _cell(j.steps_at_limit, 8, 0)
            )
        lines.append(
            "plan/sim: peak |torque|; rate: peak planned torque rate; margin: worst "
            "(margin x envelope - |planned torque|); error: simulated angle - plan"
        )
        lines.extend(f"  - {r}" for r in self.reasons)
        lines.extend(f"  note: {r}" for r in self.lead_notes)
        if self.lift_s:
            worst = max(self.joints.values(), key=lambda j: j.max_lift_error_rad)
            lines.append(
                f"  lift: {self.lift_s:.3f} s before the plan, which holds its first point "
                f"while the goals lift the servos from their sag (up to "
                f"{math.degrees(worst.max_lift_error_rad):.2f} deg, {worst.name}); the error "
                "above is from the plan's start"
            )
        return "\n".join(lines)


def _cell(value: float, width: int, decimals: int) -> str:
    """``value`` right-aligned in ``width`` characters, at least one of them a space.

    Fixed decimals while they fit; otherwise as few significant digits as fit
    (``1.2e+09``), so that columns never run together whatever the figures.
    """
    text = f"{value:.{decimals}f}"
    for digits in (3, 2, 1):
        if len(text) < width:
            break
        text = f"{value:.{digits}g}"
    return f" {text:>{width - 1}}"


def _envelope_reason(name, servo, margin, tau_plan, qd_plan, t, worst, j) -> str:
    """Why sample ``worst`` of joint ``j`` leaves ``margin`` x the envelope."""
    w_worst = abs(qd_plan[worst, j])
    if w_worst >= servo.no_load_speed_rad_s:
        return (
            f"{name}: planned speed {w_worst:.2f} rad/s exceeds the {servo.name}'s no-load "
            f"speed {servo.no_load_speed_rad_s:.2f} rad/s (no torque left) at t = "
            f"{t[worst]:.3f} s"
        )
    return (
        f"{name}: planned torque {abs(tau_plan[worst, j]):.3f} N m at "
        f"{w_worst:.2f} rad/s exceeds {margin:g} x envelope "
        f"({margin * servo.tau_max(qd_plan[worst, j]):.3f} N m) at t = {t[worst]:.3f} s"
    )


def check_planned_torque(trajectory, config: GimbalConfig, *, model=None) -> tuple[str, ...]:
    """Part (a) alone: why the plan leaves ``torque_margin x`` the envelope (empty if not).

    Parameters
    ----------
    trajectory : JointTrajectory
    config : GimbalConfig
    model : mujoco.MjModel, optional
        ``sim.run.simulation_model(config)`` if the caller has built it already.

    Returns
    -------
    tuple of str
        One reason per joint that leaves it, as in :class:`TorqueReport`.
    """
    from trajgen.sim.dynamics import inverse_dynamics

    check_trajectory(trajectory, config.n_joints)
    model = simulation_model(config) if model is None else model
    tau = inverse_dynamics(model, trajectory.q, trajectory.qd, trajectory.qdd)
    t = np.asarray(trajectory.t, dtype=float)
    qd = np.asarray(trajectory.qd, dtype=float)
    reasons = []
    for j, name in enumerate(config.names):
        servo = config.servos[j]
        plan_margin = config.torque_margin * servo.tau_max(qd[:, j]) - np.abs(tau[:, j])
        worst = int(np.argmin(plan_margin))
        if plan_margin[worst] < 0:
            reasons.append(
                _envelope_reason(name, servo, config.torque_margin, tau, qd, t, worst, j)
            )
    return tuple(reasons)


def envelope_check(config: GimbalConfig, *, model=None) -> EnvelopeCheck:
    """The torque check of part (a) as a function of a joint motion, for
    ``trajgen.tracker.Tracker(envelope=...)``: see :class:`EnvelopeCheck`.

    Parameters
    ----------
    config : GimbalConfig
    model : mujoco.MjModel, optional
        ``sim.run.simulation_model(config)`` if the caller has built it already.
    """
    return EnvelopeCheck(config, model=model)


class EnvelopeCheck:
    """``check(q, qd, qdd)`` (each (N, n); rad, rad/s, rad/s^2) is a bool array (N,),
    True where every joint's torque (``mj_inverse``, with Coulomb friction) is within
    ``torque_margin x`` its servo's torque-speed envelope at that speed, as
    :func:`check_planned_torque`; :meth:`steps` is the same in steps.

    The verdict is ``mj_inverse``'s on every sample, computed in two passes: the
    torque without Coulomb friction of every sample in numpy
    (:class:`~trajgen.sim.dynamics.ChainDynamics`), which with the friction's bound
    and a rounding bound added passes most samples (``mj_inverse`` would pass them
    too); ``mj_inverse`` itself on the others, ``EXACT_CHUNK`` samples a step. A
    model that ``ChainDynamics`` does not take (a user's, with joint limits, say)
    has every sample checked by ``mj_inverse``.

    Parameters
    ----------
    config : GimbalConfig
    model : mujoco.MjModel, optional
        ``sim.run.simulation_model(config)`` if the caller has built it already.
    """

    #: Samples given to ``mj_inverse`` in one step of :meth:`steps` (about 7 us each).
    EXACT_CHUNK = 25

    def __init__(self, config: GimbalConfig, *, model=None):
        from trajgen.sim.dynamics import ChainDynamics

        self.model = simulation_model(config) if model is None else model
        try:
            self.chain = ChainDynamics(self.model)
        except SimulationError:
            self.chain = None  # mj_inverse decides every sample
        self.servos, self.margin = config.servos, config.torque_margin

    def __call__(self, q, qd, qdd) -> np.ndarray:
        return run_steps(self.steps(q, qd, qdd))

    def steps(self, q, qd, qdd):
        """The check as a generator of steps (those of
        :meth:`~trajgen.sim.dynamics.ChainDynamics.smooth_steps`, then of the exact
        pass); its value is the bool array (N,)."""
        from trajgen.sim.dynamics import inverse_dynamics

        q, qd, qdd = (np.asarray(x, dtype=float) for x in (q, qd, qdd))
        chain = self.chain
        if chain is not None:
            tau = yield from chain.smooth_steps(q, qd, qdd)
            yield
        usable = np.stack(
            [self.margin * s.tau_max(qd[:, j]) for j, s in enumerate(self.servos)], axis=1
        )
        ok = np.zeros(len(q), dtype=bool)
        if chain is not None:
            slack = chain.ROUNDING_NM * (1.0 + (qd * qd).sum(axis=1) + np.abs(qdd).sum(axis=1))
            ok = (np.abs(tau) + chain.friction + slack[:, None] <= usable).all(axis=1)
        doubt = np.flatnonzero(~ok)
        for i in range(0, len(doubt), self.EXACT_CHUNK):
            yield
            rows = doubt[i : i + self.EXACT_CHUNK]
            exact = inverse_dynamics(self.model, q[rows], qd[rows], qdd[rows])
            ok[rows] = (np.abs(exact) <= usable[rows]).all(axis=1)
        return ok


def lag_time_s(config: GimbalConfig, joint: int) -> float:
    """How far (s) joint ``joint``'s servo lags a goal moving at constant speed.

    The firmware loop's torque ``kp e`` balances the motor's back-EMF and the
    joint's viscous damping at speed ``w``: ``e = w (K^2 / R + damping) / kp``
    (Coulomb friction adds a constant ``frictionloss / kp``). 45 ms for an
    XM430-W350 at P 800.
    """
    kp, _, kd, _ = config.loop(joint).mujoco_controller(config.servos[joint])
    return (kd + config.joints[joint].damping) / kp


def build_report(
    trajectory,
    config: GimbalConfig,
    record: SimRecord,
    *,
    model=None,
    lead: str = "none",
    lead_notes: tuple[str, ...] = (),
    goal_bounds_rad=None,
) -> TorqueReport:
    """Judge a plan and its simulated run (see the module docstring).

    Parameters
    ----------
    trajectory : JointTrajectory
        The plan (``q``; its torque comes from ``sim.dynamics.inverse_dynamics``)
        and the goals sent (``goal``, when led).
    config : GimbalConfig
    record : SimRecord
        The simulated run of ``trajectory``.
    model : mujoco.MjModel, optional
        ``sim.run.simulation_model(config)`` if the caller has built it already.
    lead : str
        How the goals were led (for the report).
    lead_notes : tuple of str
        Joints that got no lead, and why (for the report).
    goal_bounds_rad : array_like, shape (n, 2), optional
        Lowest and highest goal allowed per joint (rad); a goal outside fails
        the check.

    Returns
    -------
    TorqueReport
    """
    from trajgen.sim.dynamics import inverse_dynamics_split

    q, qd, qdd = trajectory.q, trajectory.qd, trajectory.qdd
    # Coulomb friction steps at every start and reversal whatever the plan;
    # the torque rate is taken without it (tau_smooth), so it measures the plan.
    model = simulation_model(config) if model is None else model
    tau_plan, tau_smooth = inverse_dynamics_split(model, q, qd, qdd)
    t = np.asarray(trajectory.t, dtype=float)
    qd_plan = np.asarray(qd, dtype=float)
    tau_rate = np.gradient(tau_smooth, t, axis=0)
    margin = config.torque_margin
    sent_t, goal = sent_goals(trajectory)
    bounds = None if goal_bounds_rad is None else np.asarray(goal_bounds_rad, dtype=float)
    lift = record.lift
    # Torque and its limit over every step sent, the lift's too; the tracking error
    # from the plan's first frame, the lift's apart.
    whole = record.with_lift()
    joints = {}
    for j, name in enumerate(config.names):
        servo = config.servos[j]
        plan_margin = margin * servo.tau_max(qd_plan[:, j]) - np.abs(tau_plan[:, j])
        sim_margin = margin * servo.tau_max(whole.qd[:, j]) - np.abs(whole.torque_nm[:, j])
        error = np.abs(record.tracking_error_rad[:, j])
        lift_error = 0.0 if lift is None else float(np.abs(lift.tracking_error_rad[:, j]).max())
        at_limit = int(whole.steps_at_limit[j])
        reasons = []
        worst = int(np.argmin(plan_margin))
        if plan_margin[worst] < 0:
            reasons.append(_envelope_reason(name, servo, margin, tau_plan, qd_plan, t, worst, j))
        if at_limit:
            first = whole.t[np.argmax(whole.at_limit[:, j])]
            reasons.append(
                f"{name}: {at_limit} physics steps at the torque limit "
                f"({servo.voltage_v:g} V drive or stall clamp), the first at t = {first:.3f} s"
            )
        k = int(np.argmax(error))
        if error[k] > config.max_tracking_error_rad:
            reasons.append(
                f"{name}: tracking error {error[k]:.3f} rad > "
                f"{config.max_tracking_error_rad:g} rad at t = {record.t[k]:.3f} s "
                f"(P gain {config.joints[j].position_p_gain} lags "
                f"{1e3 * lag_time_s(config, j):.0f} ms x speed; lead {lead})"
            )
        if bounds is not None:
            outside = np.flatnonzero((goal[:, j] < bounds[j, 0]) | (goal[:, j] > bounds[j, 1]))
            if len(outside):
                i = int(outside[0])
                reasons.append(
                    f"{name}: goal {goal[i, j]:.4f} rad at t = {sent_t[i]:.3f} s is outside "
                    f"{bounds[j, 0]:.4f}..{bounds[j, 1]:.4f} rad (the plan's range and the "
                    "static offset, or the position limits)"
                )
        joints[name] = JointReport(
            name=name,
            servo=servo.name,
            peak_planned_torque_nm=float(np.abs(tau_plan[:, j]).max()),
            peak_torque_nm=float(np.abs(whole.torque_nm[:, j]).max()),
            peak_torque_rate_nm_s=float(np.abs(tau_rate[:, j]).max()),
            rms_torque_nm=float(np.sqrt(np.mean(record.torque_nm[:, j] ** 2))),
            max_tracking_error_rad=float(error[k]),
            worst_planned_margin_nm=float(plan_margin[worst]),
            worst_margin_nm=float(sim_margin.min()),
            peak_speed_rad_s=float(np.abs(qd_plan[:, j]).max()),
            steps_at_limit=at_limit,
            ok=not reasons,
            reasons=tuple(reasons),
            max_lift_error_rad=lift_error,
        )
    reasons = tuple(r for joint in joints.values() for r in joint.reasons)
    return TorqueReport(
        ok=not reasons,
        reasons=reasons,
        joints=joints,
        torque_margin=margin,
        max_tracking_error_rad=config.max_tracking_error_rad,
        rate_hz=float(trajectory.rate_hz),
        duration_s=float(t[-1] - t[0]),
        trajectory=trajectory,
        planned_torque_nm=tau_plan,
        record=record,
        config=config,
        planned_torque_smooth_nm=tau_smooth,
        lead=lead,
        lead_notes=tuple(lead_notes),
        goal_bounds_rad=bounds,
        lift_s=0.0 if getattr(trajectory, "lift", None) is None else trajectory.lift.duration_s,
    )


def resolve_source(source, *, rate_hz=None, config=None):
    """Turn what a user has into ``(JointTrajectory, GimbalConfig)``.

    Parameters
    ----------
    source : str, PathLike, KeyframeFile, spline or JointTrajectory
        A keyframe file (path or loaded), anything with the spline protocol
        (``evaluate``, ``t_start``, ``t_end``), or a planned stream.
    rate_hz : float, optional
        Stream rate (Hz). Default: the file's ``[stream] rate_hz``, else 200.
        A JointTrajectory carries its own rate; passing a different one raises.
    config : GimbalConfig, optional
        Default: the file's ``[gimbal]`` table, else :class:`GimbalConfig`.

    Returns
    -------
    tuple of (JointTrajectory, GimbalConfig)

    Raises
    ------
    TypeError
        If ``source`` is none of the above.
    ValueError
        If ``rate_hz`` conflicts with a JointTrajectory's rate.
    trajgen.keyframes.KeyframeFileError
        For a bad keyframe file or ``[gimbal]`` table.
    trajgen.gimbal.KinematicsError
        If the path leaves the joint limits or nears gimbal lock.
    """
    if isinstance(source, (str, os.PathLike)):
        from trajgen.keyframes import load_keyframe_file

        source = load_keyframe_file(source)
    if hasattr(source, "tables") and hasattr(source, "spline"):
        if config is None:
            from trajgen.sim.model import gimbal_config_from_tables

            config = gimbal_config_from_tables(source.tables, source.path, any_axes=True)
        if rate_hz is None:
            rate_hz = getattr(source, "rate_hz", None)
        source = source.spline()
    config = GimbalConfig() if config is None else config
    if hasattr(source, "evaluate") and hasattr(source, "t_start"):
        from trajgen.stream import plan_joint_trajectory

        rate = DEFAULT_RATE_HZ if rate_hz is None else rate_hz
        return plan_joint_trajectory(source, rate, config.kinematics()), config
    if hasattr(source, "qdd") and hasattr(source, "rate_hz"):
        check_trajectory(source, config.n_joints)
        if rate_hz is not None and rate_hz != source.rate_hz:
            raise BadArgument(
                f"Expected `rate_hz` to match the trajectory's {source.rate_hz} Hz, got {rate_hz}."
            )
        return source, config
    raise TypeError(
        "Expected `source` to be a keyframe file path, a KeyframeFile, a spline or a "
        f"JointTrajectory, got {type(source).__name__}."
    )


def check_torque(
    source,
    *,
    rate_hz: float | None = None,
    config: GimbalConfig | None = None,
    progress: Callable[[float], None] | None = None,
    lead: str | None = None,
    limits_rad=None,
    servo_config: GimbalConfig | None = None,
) -> TorqueReport:
    """Plan, lead, simulate and judge a motion; never raises for a failed check.

    The goals simulated are the ones a stream sends (``sim.lead.lead_trajectory``:
    the same function); the tracking error is against the plan.

    Parameters
    ----------
    source : str, PathLike, KeyframeFile, spline or JointTrajectory
        See :func:`resolve_source`.
    rate_hz : float, optional
        Stream rate (Hz); see :func:`resolve_source`.
    config : GimbalConfig, optional
        See :func:`resolve_source`.
    progress : callable, optional
        Passed to :func:`sim.run.simulate`.
    lead : {"model", "advance", "none"}, optional
        How the goals are led (``trajgen.lead``); default the file's
        ``[stream] lead``, else ``"model"``.
    limits_rad : array_like, shape (n, 2), optional
        Position limits (rad) the goals must stay inside.
    servo_config : GimbalConfig, optional
        The servos as simulated, when they differ from what the lead assumes
        (``config``), e.g. another P divisor: how much the lead depends on
        the model. Default ``config``.

    Returns
    -------
    TorqueReport
        ``report.ok`` is the verdict.

    Raises
    ------
    TypeError, ValueError, KeyframeFileError, KinematicsError
        For bad input (see :func:`resolve_source`).
    SimulationError
        If MuJoCo warns or a contact appears during the run.
    """
    from trajgen.sim.lead import lead_trajectory

    if isinstance(source, (str, os.PathLike)):
        from trajgen.keyframes import load_keyframe_file

        source = load_keyframe_file(source)
    if lead is None:
        lead = getattr(source, "lead", None) or DEFAULT_LEAD
    lead = check_lead(lead)
    trajectory, config = resolve_source(source, rate_hz=rate_hz, config=config)
    model = simulation_model(config)
    trajectory, goals, notes = lead_trajectory(
        trajectory, config, lead, limits_rad=limits_rad, model=model
    )
    if servo_config is not None:
        config, model = servo_config, simulation_model(servo_config)
    record = simulate(trajectory, config, progress=progress, model=model)
    return build_report(
        trajectory,
        config,
        record,
        model=model,
        lead=lead,
        lead_notes=notes,
        goal_bounds_rad=goals.bounds,
    )


def assert_torque_ok(
    source, *, rate_hz: float | None = None, config=None, lead: str | None = None
) -> TorqueReport:
    """Pytest helper: raise unless ``source`` passes the torque check.

    Use it in your own tests::

        def test_my_shot_is_gentle_enough():
            sim.assert_torque_ok("shots/look_around.toml")

    Parameters
    ----------
    source, rate_hz, config, lead
        As for :func:`check_torque`.

    Returns
    -------
    TorqueReport
        When the check passes.

    Raises
    ------
    TorqueLimitExceeded
        When it fails; the message lists the reasons, ``.report`` has the rest.
    """
    __tracebackhide__ = True  # pytest shows the caller's line, not this helper
    report = check_torque(source, rate_hz=rate_hz, config=config, lead=lead)
    if not report.ok:
        raise TorqueLimitExceeded(report)
    return report
