"""Fit a motion to the servos by retiming its path: the keyframes stay, the clock is free.

The path is the file's spline at its own keyframe times ``s_i`` (the file's
``[timing] path_times`` if it has them, else durations in proportion to the
square root of each segment's rotation: the bang-bang time under a fixed
acceleration). The motion plays it by a time law ``s(t) = s_0 + S sigma(t / T)``
(:mod:`trajgen.timelaw`), ``sigma`` a clamped quintic B-spline, so the motion is
C3, at rest at both ends, and passes every keyframe in order. Three stages:

1. Plan (:mod:`sim.retime`): the shortest ``T`` and its ``sigma`` under the
   torque-speed envelope (x ``torque_margin``), the torque-rate bound
   ``[limits] torque_rate_nm_s`` and the ``[limits]`` table, by a sequential LP
   with analytic gradients on a grid; then stretched uniformly (at most a few
   per cent) until the exact motion keeps every limit at 1 kHz and at the
   stream rate.
2. Simulation: :func:`trajgen.sim.check.check_torque` (the full check,
   simulated servo included) on the stream. A joint whose tracking error passes
   the limit in a path segment gets a speed cap there (lag grows with speed); a
   stretch of path where a joint reaches the torque limit loses 5-15 % of its
   torque budget. Then stage 1 again from the last law, until the check passes;
   after ``_SIM_ROUNDS`` the last law is stretched uniformly (bisection under
   the check) instead.
3. Tightness: the same motion 5 % faster (``T / 1.05``) must fail the check;
   if it passes, ``T`` is shortened by bisection under the full check.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from trajgen.sim.fit_result import (
    FitError,
    FitResult,
    SegmentFit,
    keyframe_source,
    refuse_unholdable_keyframes,
    retimed_document,
    segment_fits,
)
from trajgen.sim.limits import JointLimits, check_limits
from trajgen.sim.model import GimbalConfig
from trajgen.smooth import SmoothSpline

__all__ = ["FitError", "FitResult", "SegmentFit", "fit_timing", "plan_reasons"]

#: The speed-up that must fail: the fit is tight to 5 %.
FASTER = 1.05
#: Rate (Hz) at which the exact motion is checked against the envelope and torque rate.
CHECK_RATE_HZ = 1000.0
_SIM_ROUNDS = 8
#: Uniform stretches tried under the full check when the local slow-downs do not settle.
_SIM_STRETCHES = (1.02, 1.05, 1.1, 1.2, 1.4, 2.0)
_TRACKING_TARGET = 0.97
#: Uniform stretches tried, in turn, until the exact plan keeps every limit.
_STRETCHES = (1.0, 1.002, 1.005, 1.01, 1.02, 1.05, 1.1, 1.2, 1.5)
_TIGHT_BISECTIONS = 4
_STRETCH_BISECTIONS = 4
#: Learned bounds are kept at this many points per path segment ...
_LEARN_POINTS_PER_SEGMENT = 64
#: ... and set over this much motion time (s) around a failure.
_WINDOW_S = 0.05


def fit_timing(
    source,
    *,
    config: GimbalConfig | None = None,
    limits: JointLimits | None = None,
    rate_hz: float | None = None,
    torque_rate_nm_s: float | None = None,
    simulate: bool = True,
    progress: Callable[[str], None] | None = None,
) -> FitResult:
    """The shortest smooth retiming of a keyframe file's path that passes the torque check.

    Parameters
    ----------
    source : str, PathLike or trajgen.KeyframeFile
        The keyframe file (its spline: ``boundary = "rest"``).
    config : GimbalConfig, optional
        Default: the file's ``[gimbal]`` table.
    limits : JointLimits, optional
        Default: the file's ``[limits]`` table (none if absent).
    rate_hz : float, optional
        Stream rate (Hz). Default: the file's ``[stream] rate_hz``, else 200.
    torque_rate_nm_s : float, optional
        Bound on every joint's |d torque / dt| (N m/s). Default: the file's
        ``[limits] torque_rate_nm_s``, else 300.
    simulate : bool
        Fit to the simulation's verdict too (default). False fits the plan
        alone (envelope, torque rate and ``[limits]``, as a time-optimal
        planner such as TOPP-RA does); ``report`` then shows what the simulated
        servo makes of it and may fail.
    progress : callable, optional
        Called with one line of text per stage and every 10 LP iterations.

    Returns
    -------
    FitResult
        ``law`` and ``path`` hold the time law and the retimed path;
        ``toml()`` is the file with the new keyframe times and a ``[timing]``
        table (docs/fit.md), which ``sim``, ``stream``, ``follow`` and ``plan``
        play as fitted.

    Raises
    ------
    FitError
        If no timing can pass: a pose the gimbal cannot hold against gravity,
        a path near gimbal lock or outside a joint limit, a spline not at rest
        at its ends, or a check that keeps failing.
    trajgen.keyframes.KeyframeFileError
        For a bad file or ``[gimbal]`` / ``[limits]`` table.
    TypeError, ValueError
        For bad arguments.
    """
    fitter = _Fitter.build(source, config, limits, rate_hz, torque_rate_nm_s, progress)
    c, z = fitter.plan(None, None)
    if simulate:
        c, z, report = fitter.fit_to_simulation(c, z)
    else:
        report = fitter.simulate(c, z)
    law = fitter.law(c, z)
    law, report, faster_reasons = fitter.tighten(c, z, law, report, simulate)
    return fitter.result(c, law, report, faster_reasons)


def plan_reasons(path, config: GimbalConfig, limits: JointLimits, torque_rate_nm_s, rate_hz):
    """Why a motion's plan breaks a limit the fit keeps (empty when it keeps them all).

    The envelope (x ``torque_margin``) and the torque rate (without Coulomb
    friction, by differences) at :data:`CHECK_RATE_HZ`, the ``[limits]`` table
    at the stream rate.

    Parameters
    ----------
    path : spline-like
        The motion (``t_start``, ``t_end``, ``evaluate``).
    config, limits
    torque_rate_nm_s : float
        Bound on |d torque / dt| (N m/s).
    rate_hz : float
        Stream rate (Hz).

    Returns
    -------
    tuple of str
    """
    from trajgen.gimbal import KinematicsError
    from trajgen.sim.dynamics import inverse_dynamics_split
    from trajgen.sim.run import simulation_model
    from trajgen.stream import plan_joint_trajectory

    try:
        fine = plan_joint_trajectory(path, CHECK_RATE_HZ, config.kinematics())
        stream = plan_joint_trajectory(path, rate_hz, config.kinematics())
    except KinematicsError as e:
        raise FitError(f"no timing can help: the path {e}") from e
    tau, smooth = inverse_dynamics_split(simulation_model(config), fine.q, fine.qd, fine.qdd)
    reasons = []
    for j, name in enumerate(config.names):
        servo = config.servos[j]
        avail = config.torque_margin * servo.tau_max(fine.qd[:, j])
        k = int(np.argmax(np.abs(tau[:, j]) - avail))
        if abs(tau[k, j]) > avail[k]:
            reasons.append(
                f"{name}: planned torque {abs(tau[k, j]):.3f} N m exceeds "
                f"{config.torque_margin:g} x envelope ({avail[k]:.3f} N m) at t = {fine.t[k]:.3f} s"
            )
        rate = np.abs(np.diff(smooth[:, j])) / np.diff(fine.t)
        k = int(np.argmax(rate))
        if rate[k] > torque_rate_nm_s:
            reasons.append(
                f"{name}: torque rate {rate[k]:.0f} N m/s > limit {torque_rate_nm_s:g} N m/s "
                f"at t = {fine.t[k]:.3f} s"
            )
    return tuple(reasons) + check_limits(stream, limits)


def default_path_times(source) -> np.ndarray:
    """The path's own keyframe times (N,): the file's ``[timing] path_times`` if it has them,
    else segment durations in proportion to the square root of each segment's rotation
    (at least a fifth of the largest's), over the file's total time."""
    if source.timing is not None:
        return np.asarray(source.timing[0], dtype=float)
    q = source.quats
    angle = 2.0 * np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", q[1:], q[:-1])), 0.0, 1.0))
    root = np.sqrt(np.maximum(angle, 1e-12))
    weights = np.maximum(root, 0.2 * root.max())
    total = float(source.times[-1] - source.times[0])
    return float(source.times[0]) + np.concatenate([[0.0], np.cumsum(weights)]) * (
        total / weights.sum()
    )


class _Fitter:
    """The fit's state: the path, its dynamics tables, the limits and what simulation taught."""

    @classmethod
    def build(cls, source, config, limits, rate_hz, torque_rate, progress) -> _Fitter:
        from trajgen.sim.check import DEFAULT_RATE_HZ
        from trajgen.sim.limits import limits_from_tables, torque_rate_from_tables
        from trajgen.sim.model import gimbal_config_from_tables
        from trajgen.validate import check_number

        source = keyframe_source(source)
        if config is None:
            config = gimbal_config_from_tables(source.tables, source.path, any_axes=True)
        if limits is None:
            limits = limits_from_tables(source.tables, source.path)
        if torque_rate is None:
            torque_rate = torque_rate_from_tables(source.tables, source.path)
        torque_rate = check_number("torque_rate_nm_s", torque_rate, low=0.0, low_open=True)
        rate = rate_hz or source.rate_hz or DEFAULT_RATE_HZ
        boundary = source.spline_options.get("boundary", "rest")
        if boundary != "rest":
            raise FitError(
                f"the fit retimes motions from rest to rest: [spline] boundary is {boundary!r}, "
                "not 'rest'"
            )
        return cls(source, config, limits, rate, torque_rate, progress or (lambda _: None))

    def __init__(self, source, config, limits, rate_hz, torque_rate, say):
        from trajgen.sim.retime import LawBounds, LawProblem, knots_for
        from trajgen.sim.retime_path import path_dynamics
        from trajgen.sim.run import simulation_model

        self.source, self.config, self.limits = source, config, limits
        self.rate_hz, self.torque_rate, self.say = rate_hz, torque_rate, say
        self.model = simulation_model(config)
        refuse_unholdable_keyframes(source, self.model, config)
        self.path_times = default_path_times(source)
        # The path is always the C3 SmoothSpline (a blending spline is C2 at k = 2: its
        # jerk steps at the keyframes, and so would the torque rate).
        self.spline_table = {"method": "smooth"} | {
            k: v for k, v in source.spline_options.items() if k in ("boundary", "knots")
        }
        try:
            self.path = SmoothSpline(
                source.quats,
                self.path_times,
                **{k: v for k, v in self.spline_table.items() if k != "method"},
            )
        except (ValueError, TypeError) as e:
            raise FitError(f"the spline refuses the keyframes: {e}") from e
        try:
            self.dyn = path_dynamics(self.path, self.model, config)
        except FitError:
            raise
        except Exception as e:  # SimError from the kinematics
            raise FitError(str(e)) from e
        self._check_path_static()
        grid = np.linspace(
            0.0, self.dyn.s_span, _LEARN_POINTS_PER_SEGMENT * (len(self.path_times) - 1) + 1
        )
        self.bounds = LawBounds(
            limits,
            torque_rate,
            grid,
            np.ones(len(grid)),
            np.full((len(grid), config.n_joints), np.inf),
        )
        self.knots = knots_for(self.dyn.s_keys)
        self._problem_class = LawProblem
        self.iterations = 0
        self.problem = None

    def _check_path_static(self) -> None:
        """Refuse a path that passes a pose the gimbal cannot hold against gravity."""
        s = np.linspace(0.0, self.dyn.s_span, 20 * len(self.path_times))
        hold = np.abs(self.dyn.table(s)[:, 2, :])
        over = hold > self.dyn.budget
        if over.any():
            k, j = np.argwhere(over)[0]
            raise FitError(
                f"the path passes a pose where the {self.config.names[j]} servo cannot hold "
                f"against gravity: it needs {hold[k, j]:.3f} N m, the budget is "
                f"{self.dyn.budget[j]:.3f} N m"
            )

    def plan(self, c, z):
        """Stage 1: the law's coefficients and ``log T``, from ``(c, z)`` (None: from scratch),
        stretched until the exact plan keeps every limit."""
        from trajgen.sim.retime import initial_law, optimise

        if c is None:
            self.knots, c, _ = initial_law(self.dyn, self.bounds)
        self.problem = self._problem_class(self.dyn, self.bounds, self.knots)
        try:
            start = self.problem.start(c)
        except ValueError as e:
            raise FitError(f"the path cannot be timed within its limits: {e}") from e
        z = start if z is None else max(z, start - 0.5)
        self.say(f"plan: from {np.exp(z):.3f} s")
        c, z, iterations, _ = optimise(self.problem, c, z, self.say)
        self.iterations += iterations
        passed, failed = None, 0.0
        for stretch in _STRETCHES:
            reasons = plan_reasons(
                self.retimed(self.law(c, z + np.log(stretch))), *self._plan_args()
            )
            if not reasons:
                passed = np.log(stretch)
                break
            failed, why = np.log(stretch), reasons[0]
        if passed is None:
            raise FitError(f"the plan keeps breaking a limit between the optimiser's points: {why}")
        for _ in range(_STRETCH_BISECTIONS if passed > 0 else 0):
            mid = 0.5 * (passed + failed)
            if plan_reasons(self.retimed(self.law(c, z + mid)), *self._plan_args()):
                failed = mid
            else:
                passed = mid
        self.say(f"plan: {np.exp(z + passed):.3f} s ({iterations} LP steps, x{np.exp(passed):.4f})")
        return c, z + passed

    def _plan_args(self):
        return self.config, self.limits, self.torque_rate, self.rate_hz

    def law(self, c, z):
        from trajgen.timelaw import TimeLaw

        return TimeLaw(
            self.knots,
            c,
            float(self.source.times[0]),
            float(np.exp(z)),
            float(self.path_times[0]),
            float(self.dyn.s_span),
        )

    def retimed(self, law):
        from trajgen.timelaw import RetimedPath

        return RetimedPath(self.path, law)

    def trajectory(self, law):
        from trajgen.stream import plan_joint_trajectory

        return plan_joint_trajectory(self.retimed(law), self.rate_hz, self.config.kinematics())

    def learn_from_sim(self, report, law) -> bool:
        """Turn the simulation's failures into local bounds; False if nothing to learn.

        Where a joint reaches the torque limit, the torque budget loses 5, 10 or
        15 % (fewer than 20, 100 or more physics steps at the limit) within
        ``_WINDOW_S`` of motion time either side; where its tracking error passes
        the limit, its speed is capped over the ``_WINDOW_S`` before (lag builds
        up with speed).
        """
        record, plan = report.record, report.trajectory
        bounds = self.bounds
        limit = report.max_tracking_error_rad
        error = np.abs(record.tracking_error_rad)
        at_limit = np.asarray(record.at_limit, dtype=bool)
        s_plan = law(plan.t, 0)[0] - self.path_times[0]

        def window(t_from, t_to):
            lo, hi = (
                law([max(t_from, law.t_start), min(t_to, law.t_end)], 0)[0] - self.path_times[0]
            )
            return (bounds.s_grid >= lo) & (bounds.s_grid <= hi), (s_plan >= lo) & (s_plan <= hi)

        learned = False
        for j in range(self.config.n_joints):
            over = error[:, j] > limit
            if over.any():
                for t in np.unique(np.round(record.t[over], 2)):
                    where, plan_rows = window(t - _WINDOW_S, t + 0.01)
                    worst = error[np.abs(record.t - t) <= 0.01, j].max(initial=limit)
                    peak = np.abs(plan.qd[plan_rows, j]).max(initial=0.0)
                    cap = peak * _TRACKING_TARGET * limit / worst
                    bounds.speed_cap[where, j] = np.minimum(bounds.speed_cap[where, j], cap)
                learned = True
            elif at_limit[:, j].any():
                hit = np.zeros(len(bounds.s_grid), dtype=bool)
                for t in np.unique(np.round(record.t[at_limit[:, j]], 2)):
                    hit |= window(t - _WINDOW_S, t + _WINDOW_S)[0]
                steps = int(at_limit[:, j].sum())
                bounds.budget_scale[hit] *= 0.95 if steps < 20 else 0.9 if steps < 100 else 0.85
                learned = True
        self.say("  simulation: " + "; ".join(report.reasons[:2]))
        return learned

    def simulate(self, c, z):
        """The full check (:func:`trajgen.sim.check.check_torque`) of the law ``(c, z)``."""
        from trajgen.sim.check import check_torque

        return check_torque(
            self.trajectory(self.law(c, z)), config=self.config, lead=self.source.lead
        )

    def fit_to_simulation(self, c, z):
        """Stage 2: local slow-downs where the check fails, re-planned, then (if that has not
        passed after ``_SIM_ROUNDS``) a uniform stretch by bisection under the check.

        Returns
        -------
        c, z, report
            The passing law and its check.
        """
        for round_ in range(1, _SIM_ROUNDS + 1):
            self.say(f"round {round_}: simulating {np.exp(z):.3f} s")
            report = self.simulate(c, z)
            if report.ok:
                return c, z, report
            if not self.learn_from_sim(report, self.law(c, z)):
                break
            c, z = self.plan(c, z)
        # The local slow-downs did not settle: stretch the last law as a whole.
        failed, passed, passing = 0.0, None, None
        for stretch in _SIM_STRETCHES:
            self.say(f"  stretched x{stretch:g}: simulating")
            trial = self.simulate(c, z + np.log(stretch))
            if trial.ok:
                passed, passing = np.log(stretch), trial
                break
            failed, report = np.log(stretch), trial
        if passed is None:
            raise FitError(f"no passing timing found by simulation: {report.reasons[0]}")
        for _ in range(_STRETCH_BISECTIONS):
            mid = 0.5 * (failed + passed)
            trial = self.simulate(c, z + mid)
            if trial.ok:
                passed, passing = mid, trial
            else:
                failed = mid
        return c, z + passed, passing

    def tighten(self, c, z, law, report, simulate):
        """Stage 3: make sure ``FASTER`` times as fast fails; returns the law, its report and
        why the faster motion fails."""
        from trajgen.sim.check import check_torque

        def verdict(trial):
            reasons = plan_reasons(self.retimed(trial), *self._plan_args())
            if not simulate:
                return reasons, None
            trial_report = check_torque(
                self.trajectory(trial), config=self.config, lead=self.source.lead
            )
            return reasons + trial_report.reasons, trial_report

        for _ in range(_TIGHT_BISECTIONS):
            faster = self.law(c, z - np.log(FASTER))
            reasons, faster_report = verdict(faster)
            if reasons:
                return law, report, reasons
            self.say(f"  {FASTER - 1:.0%} faster passes too: shortening")
            z -= np.log(FASTER)
            law, report = faster, faster_report
        return law, report, ()

    def binding(self, c, law) -> list[str]:
        """Per segment: the limit family nearest its bound, and how near (e.g. ``99 %``)."""
        z = np.log(law.duration_s)
        h, _ = self.problem.rows(c, z)
        names = self.problem.family_names()
        sig = self.problem.B[0] @ c
        seg = self.dyn.segment(self.dyn.s_span * sig)
        out = []
        for i in range(len(self.path_times) - 1):
            cols = seg == i
            if not cols.any():
                out.append("-")
                continue
            sub = h[:, cols]
            f, _ = np.unravel_index(int(np.argmax(sub)), sub.shape)
            name = names[f]
            joint = self.config.names.index(name[name.index("(") + 1 : -1])
            learned = self.bounds.index(self.dyn.s_span * sig[cols])
            if name.startswith("torque envelope") and (self.bounds.budget_scale[learned] < 1).any():
                name = f"sim torque limit ({self.config.names[joint]})"
            if (
                name.startswith("speed limit")
                and np.isfinite(self.bounds.speed_cap[learned, joint]).any()
            ):
                name = f"tracking error ({self.config.names[joint]})"
            out.append(f"{name}, {1 + sub.max():.0%}")
        return out

    def result(self, c, law, report, faster_reasons) -> FitResult:
        path = self.retimed(law)
        times = path.times
        old = np.asarray(self.source.times, dtype=float)
        binding = self.binding(c, law)
        segments = segment_fits(old, times, binding)
        return FitResult(
            times=times,
            old_times=old,
            segments=segments,
            report=report,
            faster_reasons=tuple(faster_reasons),
            limits=self.limits,
            document=self.document(times, law),
            iterations=self.iterations,
            faster=FASTER,
            law=law,
            path=path,
        )

    def document(self, times, law) -> dict:
        """The input's TOML document with the keyframes' new times and the ``[timing]`` table."""
        document = retimed_document(self.source.path, times)
        document["spline"] = dict(self.spline_table)
        document["timing"] = {
            "path_times": [float(s) for s in self.path_times],
            "duration_s": float(law.duration_s),
            "knots": [float(k) for k in law.knots],
            "coefficients": [float(x) for x in law.coefficients],
        }
        return document
