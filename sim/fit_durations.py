"""The keyframe-times fit (``trajgen fit`` before the retiming): per-segment durations.

Kept as the retiming's reference (``bench/fit_vs_toppra.py`` measures both) and
for :func:`uniform_time_function`, the floor of this spline's timings.

The keyframes (orientations, order, spline options) stay; only their times
move, one duration per segment. Two nested loops:

1. Plan: for every sample, the largest local speed-up ``s`` the plan allows,
   scaling speed by ``s``, acceleration by ``s^2``, jerk by ``s^3``, and torque
   as ``tau(s) = tau_static + s tau_viscous + s^2 tau_inertial`` against
   ``torque_margin x tau_stall (1 - s |qd| / w0)`` (two quadratics in ``s``,
   solved in closed form). Then:

   a. all durations scaled alike until the slowest stream sample is at its
      limit (uniform scaling keeps the path's shape, so this is exact);
   b. all durations at once (the spline is global: one segment's duration
      moves its neighbours' curves): least total time subject to every sample
      within its limits, by SLSQP (scipy) on the log-durations, the samples
      taken at fixed fractions of each segment so that the constraints are
      smooth in the durations; then (a) again on the stream's own samples;
   c. each segment in turn made as short as it can be *with every sample of
      the whole plan still within its limits* (bisection), until no segment
      can be made ``tolerance`` shorter on its own. After (b) this rarely
      moves anything; it finds each segment's binding limit. A segment held
      by a limit a neighbour would break reports it "in segment k".

2. Simulation: :func:`trajgen.sim.check.check_torque` on the fitted plan. A
   joint whose tracking error passes the limit in a segment gets a speed cap
   there (tracking lag grows with speed); a segment where a joint reaches the
   torque limit (and tracks well) is slowed by 3 %. Then loop 1 again. A
   run that passes with tracking error well inside the limit where a cap
   holds gets that cap raised (caps learned at a failing, faster timing can
   be too strict); the shortest passing timing is kept.

The result is checked as written (times rounded to 1 us) and again 10 %
faster, which must fail: the fit is tight.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from trajgen.sim.fit_result import (
    FitError,
    FitResult,
    keyframe_source,
    refuse_unholdable_keyframes,
    retimed_document,
    segment_fits,
)
from trajgen.sim.limits import JointLimits, check_limits, joint_jerk
from trajgen.sim.model import GimbalConfig
from trajgen.validate import check_number

#: Largest change of the durations per uniform-scaling iteration or bisection start.
_MAX_STEP = 4.0
_TIME_DECIMALS = 6
_FASTER = 1.1
_PLAN_ITERATIONS = 60
#: The joint optimiser samples each segment at these fractions of its duration.
_PROBE_U = np.arange(32) / 32.0
#: Speed-ups above this do not steer the joint optimiser.
_FACTOR_CAP = 4.0
#: Forward-difference step on the log-durations.
_DIFF_STEP = 1e-4
_JOINT_ITERATIONS = 60
_SWEEPS = 8
_BISECTIONS = 7
_SIM_ROUNDS = 12
#: Simulated tries per segment held by a learned limit in another segment.
_SIM_BISECTIONS = 4
#: Tracking speed caps aim this far under the limit.
_TRACKING_TARGET = 0.97
_SIM_SLOW_STEP = 0.97
#: A passing run whose tracking error stays below this fraction of the limit in a
#: capped segment gets that cap raised (by at most _MAX_RELAX per round).
_RELAX_BELOW = 0.9
_MAX_RELAX = 1.5

#: Names of the limits a segment can bind on, indexed by the codes used below.
BINDINGS = (
    "torque envelope",
    "speed limit",
    "acceleration limit",
    "jerk limit",
    "tracking error",
    "sim torque limit",
    "no-load speed",
    "shortest segment",
)
_TORQUE, _SPEED, _ACCEL, _JERK, _TRACKING, _SIM_LIMIT, _NO_LOAD, _FLOOR = range(len(BINDINGS))


def fit_durations(
    source,
    *,
    config: GimbalConfig | None = None,
    limits: JointLimits | None = None,
    rate_hz: float | None = None,
    tolerance: float = 0.005,
    simulate: bool = True,
    progress: Callable[[str], None] | None = None,
) -> FitResult:
    """The fastest per-segment timing of a keyframe file that passes the torque check.

    Parameters
    ----------
    source : str, PathLike or trajgen.KeyframeFile
        The keyframe file.
    config : GimbalConfig, optional
        Default: the file's ``[gimbal]`` table.
    limits : JointLimits, optional
        Default: the file's ``[limits]`` table (none if absent).
    rate_hz : float, optional
        Stream rate (Hz). Default: the file's ``[stream] rate_hz``, else 200.
    tolerance : float
        Each segment ends within this fraction of its binding limit's speed, in
        (0, 0.05]. Default 0.005.
    simulate : bool
        Fit to the simulation's verdict too (default). False fits the plan
        alone (envelope and ``[limits]``, as a time-optimal planner such as
        TOPP-RA does); ``report`` then shows what the simulated servo makes of
        it and may fail.
    progress : callable, optional
        Called with one line of text per plan iteration and simulation round.

    Returns
    -------
    FitResult

    Raises
    ------
    FitError
        If no timing can pass: a pose the gimbal cannot hold against gravity,
        a path near gimbal lock or outside a joint limit, or no convergence.
    trajgen.keyframes.KeyframeFileError
        For a bad file or ``[gimbal]`` / ``[limits]`` table.
    TypeError, ValueError
        For bad arguments.
    """
    from trajgen.sim.check import check_torque

    fitter = _make_fitter(source, config, limits, rate_hz, tolerance, progress)
    source, config, limits = fitter.source, fitter.config, fitter.limits
    say = fitter.say
    refuse_unholdable_keyframes(fitter.source, fitter.model, fitter.config)
    old_times = np.asarray(source.times, dtype=float)
    durations = np.diff(old_times)
    best = None
    for round_ in range(1, _SIM_ROUNDS + 1):
        durations, binding = fitter.fit_plan(durations)
        times = _round_times(old_times[0], durations)
        durations = np.diff(times)
        say(f"round {round_}: simulating {times[-1] - times[0]:.3f} s")
        report = check_torque(fitter.trajectory(times), config=config)
        if not simulate:
            best = (times, binding, report)
            break
        if report.ok:
            if best is not None and np.array_equal(times, best[0]):
                break  # raising the caps changed nothing: other limits hold
            if best is None or times[-1] < best[0][-1]:
                best = (times, binding, report)
            # Speed caps learned at a faster, failing timing may be too strict.
            if not fitter.relax_caps(report, times):
                break
        elif not fitter.learn_from_sim(report, times):
            raise FitError("the simulation fails where the plan passes: " + report.reasons[0])
    if best is None:
        raise FitError(
            f"no passing timing after {_SIM_ROUNDS} simulation rounds: " + report.reasons[0]
        )
    times, binding, report = best
    if simulate:
        times, report = fitter.shorten_by_simulation(times, binding, report)
    faster = old_times[0] + (times - old_times[0]) / _FASTER
    try:
        faster_trajectory = fitter.trajectory(faster)
    except FitError as e:
        faster_reasons = (str(e),)
    else:
        faster_report = check_torque(faster_trajectory, config=config)
        faster_reasons = faster_report.reasons + check_limits(faster_trajectory, limits)
    segments = segment_fits(old_times, times, binding)
    return FitResult(
        faster=_FASTER,
        times=times,
        old_times=old_times,
        segments=segments,
        report=report,
        faster_reasons=tuple(faster_reasons),
        limits=limits,
        document=retimed_document(source.path, times),
        iterations=fitter.iterations,
    )


def uniform_time_function(
    source,
    *,
    config: GimbalConfig | None = None,
    limits: JointLimits | None = None,
    rate_hz: float | None = None,
    probe: bool = False,
) -> Callable[[np.ndarray], float]:
    """The plan's shortest total time for a given shape of durations, for global searches.

    ``f(durations)`` scales all segment durations alike until the slowest
    sample is at its limit (torque envelope and ``[limits]``, as
    ``fit_timing(..., simulate=False)`` fits) and returns that total time (s);
    ``inf`` where the path cannot be planned. It depends on the ratios of the
    durations only, so minimising it over them gives the best timing this
    spline construction allows (e.g. ``bench/fit_vs_toppra.py``'s floor).

    Parameters
    ----------
    source, config, limits, rate_hz
        As for :func:`fit_timing`.
    probe : bool
        Judge each segment at 32 fixed fractions of its duration (fast, smooth)
        instead of at the stream's samples (exact, default).

    Returns
    -------
    callable
        ``durations`` (S,) in s -> total time (s).
    """
    fitter = _make_fitter(source, config, limits, rate_hz, 0.005, None)

    def total_time(durations) -> float:
        durations = np.asarray(durations, dtype=float)
        result = fitter.factors(durations, probe=probe)
        if result is None:
            return np.inf
        return float(durations.sum() / result[0].min())

    return total_time


def _make_fitter(source, config, limits, rate_hz, tolerance, progress) -> _Fitter:
    """Check :func:`fit_timing`'s arguments and fill in the file's defaults."""
    from trajgen.sim.check import DEFAULT_RATE_HZ
    from trajgen.sim.limits import limits_from_tables
    from trajgen.sim.model import build_model, gimbal_config_from_tables

    source = keyframe_source(source)
    tolerance = check_number("tolerance", tolerance, low=0.0, high=0.05, low_open=True)
    if config is None:
        config = gimbal_config_from_tables(source.tables, source.path, any_axes=True)
    if limits is None:
        limits = limits_from_tables(source.tables, source.path)
    rate = rate_hz or source.rate_hz or DEFAULT_RATE_HZ
    say = progress or (lambda _: None)
    return _Fitter(source, config, limits, rate, build_model(config), tolerance, say)


def _segment_of(times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index (M,) of the segment of keyframe ``times`` (N,) holding each of ``t`` (M,), s;
    the last segment holds the end time."""
    return np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)


def _round_times(t0: float, durations: np.ndarray) -> np.ndarray:
    return np.round(t0 + np.concatenate([[0.0], np.cumsum(durations)]), _TIME_DECIMALS)


class _Fitter:
    """The plan loop's state: the keyframes, the model and the learned simulation caps."""

    def __init__(self, source, config, limits, rate_hz, model, tolerance, say):
        self.source = source
        self.config = config
        self.limits = limits
        self.rate_hz = rate_hz
        self.model = model
        self.tolerance = tolerance
        self.say = say
        n_seg = len(source.times) - 1
        #: Learned from simulation, per segment and joint: speed caps (rad/s).
        self.speed_cap = np.full((n_seg, config.n_joints), np.inf)
        #: Per segment: a factor <= 1 on its speed-up, and the joint that reached
        #: the torque limit in simulation there.
        self.slow = np.ones(n_seg)
        self.slow_joint = [""] * n_seg
        self.min_duration_s = 2.0 / rate_hz
        self.iterations = 0
        servos = config.servos
        self.stall = np.array([s.stall_torque_nm for s in servos])
        self.no_load = np.array([s.no_load_speed_rad_s for s in servos])
        self.damping = np.array(model.dof_damping)

    def trajectory(self, times, at=None):
        """The planned joint path at keyframe ``times``; FitError if the gimbal cannot follow it.

        Parameters
        ----------
        times : ndarray, shape (N,)
            Keyframe times (s).
        at : ndarray, shape (M,), optional
            Sample times (s), increasing, from ``times[0]`` to ``times[-1]``.
            Default: the stream's samples at ``rate_hz`` (what the check runs).

        Returns
        -------
        JointTrajectory
        """
        from trajgen.gimbal import KinematicsError
        from trajgen.stream import JointTrajectory, plan_joint_trajectory

        source, kinematics = self.source, self.config.kinematics()
        spline = source.spline_class(source.quats, times, **source.spline_options)
        try:
            if at is None:
                return plan_joint_trajectory(spline, self.rate_hz, kinematics)
            samples = spline.evaluate(at, max_order=2)
            q = kinematics.inverse(samples.q, at)
            qd, qdd = kinematics.joint_rates(q, samples.omega, samples.alpha)
        except KinematicsError as e:
            raise FitError(f"no timing can help: the path {e}") from e
        return JointTrajectory(at, q, qd, qdd, self.rate_hz)

    def sample_factors(self, trajectory, segment):
        """Largest speed-up per sample and joint, and the code of the limit that sets it.

        Returns
        -------
        factor : ndarray, shape (M, 3)
        code : ndarray of int, shape (M, 3)
        """
        from trajgen.sim.dynamics import inverse_dynamics, inverse_dynamics_split

        q, qd, qdd = trajectory.q, trajectory.qd, trajectory.qdd
        zero = np.zeros_like(q)
        static = inverse_dynamics(self.model, q, zero, zero, coulomb=False)
        full, smooth = inverse_dynamics_split(self.model, q, qd, qdd)
        coulomb = full - smooth
        viscous = self.damping * qd
        inertial = smooth - static - viscous
        speed = np.abs(qd)
        budget = self.config.torque_margin * self.stall  # (n,)
        over = np.abs(static) > budget
        if over.any():
            k, j = np.argwhere(over)[0]
            raise FitError(
                f"at t = {trajectory.t[k]:.3f} s the path passes a pose where the "
                f"{self.config.names[j]} servo cannot hold against gravity: it needs "
                f"{abs(static[k, j]):.3f} N m, the budget is {budget[j]:.3f} N m"
            )
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            # Torque: |c + s v + s^2 i| <= budget (1 - s a), one quadratic per sign.
            constant, slope = static + coulomb, budget * speed / self.no_load
            torque = np.minimum(
                _first_negative_root(budget - constant, -slope - viscous, -inertial),
                _first_negative_root(budget + constant, viscous - slope, inertial),
            )
            no_load = np.where(speed > 0, self.no_load / speed, np.inf)
            bounds = self.limits.as_array()
            speed_cap = np.minimum(bounds[0], self.speed_cap[segment])
            speed_f = np.where(speed > 0, speed_cap / speed, np.inf)
            accel = np.sqrt(bounds[1] / np.abs(qdd))
            jerk = np.cbrt(bounds[2] / np.abs(joint_jerk(trajectory)))
        tracking = np.isfinite(self.speed_cap[segment]) & (self.speed_cap[segment] < bounds[0])
        speed_code = np.where(tracking, _TRACKING, _SPEED)
        torque_code = np.full_like(speed_code, _TORQUE)
        stack = np.stack([torque, speed_f, accel, jerk, no_load])
        codes = np.stack(
            [
                torque_code,
                speed_code,
                np.full_like(speed_code, _ACCEL),
                np.full_like(speed_code, _JERK),
                np.full_like(speed_code, _NO_LOAD),
            ]
        )
        k = np.argmin(stack, axis=0)
        factor = np.take_along_axis(stack, k[None], 0)[0]
        code = np.take_along_axis(codes, k[None], 0)[0]
        return np.nan_to_num(factor, nan=np.inf), code

    def factors(self, durations: np.ndarray, *, probe: bool = False):
        """Per-sample speed-ups at ``durations``, or None if the path cannot be planned.

        Parameters
        ----------
        durations : ndarray, shape (S,)
            Segment durations (s).
        probe : bool
            Sample each segment at ``_PROBES`` fixed fractions of its duration
            (fast, and smooth in ``durations``: for the joint optimiser) instead
            of at the stream's samples (exact: what the check sees).

        Returns
        -------
        factor : ndarray, shape (M, 3)
            Largest speed-up per sample and joint, the segment's learned
            simulation slow-down included; >= 1 keeps every limit.
        code : ndarray of int, shape (M, 3)
            The limit behind each factor (index into ``BINDINGS``).
        segment : ndarray of int, shape (M,)
            The segment each sample lies in.
        """
        self.iterations += 1
        times = float(self.source.times[0]) + np.concatenate([[0.0], np.cumsum(durations)])
        at = None
        if probe:
            at = np.append((times[:-1, None] + np.outer(durations, _PROBE_U)).ravel(), times[-1])
        try:
            trajectory = self.trajectory(times, at)
        except FitError:
            return None
        segment = _segment_of(times, trajectory.t)
        factor, code = self.sample_factors(trajectory, segment)
        return factor * self.slow[segment, None], code, segment

    def evaluate(self, durations: np.ndarray):
        """Plan at ``durations``: per-segment factor and binding, or None if unplannable.

        Returns
        -------
        seg_factor : ndarray, shape (S,)
            Smallest speed-up over each segment's stream samples, times its
            learned simulation slow-down; >= 1 means the plan keeps every limit there.
        binding : list of str
            The limit behind each segment's factor, e.g. ``"torque envelope (pan)"``.
        """
        result = self.factors(durations)
        if result is None:
            return None
        factor, code, segment = result
        n_seg = len(durations)
        flat = factor.min(axis=1)
        joint = factor.argmin(axis=1)
        seg_factor = np.full(n_seg, np.inf)
        binding = [BINDINGS[_FLOOR]] * n_seg
        for i in range(n_seg):
            rows = np.flatnonzero(segment == i)
            if len(rows) == 0:
                continue
            r = rows[np.argmin(flat[rows])]
            seg_factor[i] = flat[r]
            binding[i] = f"{BINDINGS[code[r, joint[r]]]} ({self.config.names[joint[r]]})"
            if self.slow[i] < 1.0 and flat[r] >= self.slow[i] * (1.0 + self.tolerance):
                # The plan alone would allow more: the simulation's slow-down binds.
                binding[i] = f"{BINDINGS[_SIM_LIMIT]} ({self.slow_joint[i]})"
        return seg_factor, binding

    def scale_uniform(self, durations: np.ndarray) -> np.ndarray:
        """All durations scaled alike until the slowest stream sample is at its limit.

        Uniform time scaling keeps the path's shape, so the per-sample factors
        are exact for it and this settles in a few iterations.
        """
        for _ in range(_PLAN_ITERATIONS):
            result = self.evaluate(durations)
            if result is None:
                raise FitError("the path cannot be planned at a uniformly scaled timing")
            worst = float(result[0].min())
            self.say(f"  plan {self.iterations}: {durations.sum():.3f} s, uniform x{1 / worst:.3f}")
            if not np.isfinite(worst) or 1.0 <= worst <= 1.0 + self.tolerance / 4:
                return durations
            durations = (
                durations / np.clip(worst, 1.0 / _MAX_STEP, _MAX_STEP) * (1.0 + self.tolerance / 8)
            )
            if durations.sum() > 1e4 * float(np.diff(self.source.times).sum()):
                raise FitError("the motion needs ever longer durations: the limits cannot be met")
        raise FitError(f"uniform scaling did not settle in {_PLAN_ITERATIONS} iterations")

    def optimise_jointly(self, durations: np.ndarray) -> np.ndarray:
        """All durations at once: least total time with every probe sample within its limits.

        SLSQP on the log-durations, one constraint ``log factor >= 0`` per probe
        sample and joint (see :meth:`factors`), capped at ``log _FACTOR_CAP`` so
        that samples far from their limits do not steer. Its Jacobian is taken by
        forward differences (one plan per segment). The probes sit between the
        stream's samples, so the result may leave a limit slightly between
        probes: the caller rescales it on the stream.
        """
        try:
            from scipy.optimize import minimize
        except ImportError as e:
            raise ImportError("fit_timing needs scipy: pip install 'trajgen[fit]'") from e

        n_seg = len(durations)
        size = 3 * (n_seg * len(_PROBE_U) + 1)
        cache = {}

        def constraints(x):
            key = x.tobytes()
            if key not in cache:
                result = self.factors(np.exp(x), probe=True)
                if result is None:
                    cache[key] = np.full(size, -1.0)  # unplannable: far outside
                else:
                    cache[key] = np.log(np.clip(result[0], 1e-6, _FACTOR_CAP)).ravel()
            return cache[key]

        def jacobian(x):
            base = constraints(x)
            columns = []
            for i in range(n_seg):
                step = x.copy()
                step[i] += _DIFF_STEP
                columns.append((constraints(step) - base) / _DIFF_STEP)
            return np.stack(columns, axis=1)

        def report(x):
            self.say(f"  joint {self.iterations}: {np.exp(x).sum():.3f} s")

        bound = np.log(self.min_duration_s)
        result = minimize(
            lambda x: np.exp(x).sum(),
            np.log(durations),
            jac=np.exp,
            method="SLSQP",
            bounds=[(bound, None)] * n_seg,
            constraints=[{"type": "ineq", "fun": constraints, "jac": jacobian}],
            callback=report,
            options={"maxiter": _JOINT_ITERATIONS, "ftol": 1e-4 * self.tolerance},
        )
        return np.exp(result.x)

    def fit_plan(self, durations: np.ndarray):
        """Loop 1: the shortest durations that keep every limit, and what binds each segment.

        Uniform scaling to the limits first (:meth:`scale_uniform`), then all
        durations at once (:meth:`optimise_jointly`, rescaled on the stream),
        kept if shorter. Then, segment by segment, a shorter duration is kept
        only if the whole plan still keeps every limit (the spline's curves reach
        across segments, so a short segment can push a neighbour over): at the
        end no segment can be made ``tolerance`` shorter on its own, and each
        knows the limit that stops it.
        """
        durations = self.scale_uniform(np.asarray(durations, dtype=float))
        if len(durations) > 1:
            joint = self.optimise_jointly(durations)
            try:
                joint = self.scale_uniform(joint) if np.isfinite(joint).all() else durations
            except FitError:  # a shape whose path the stream cannot follow: keep the uniform one
                joint = durations
            if joint.sum() < durations.sum():
                durations = joint
        seg_factor, binding = self.evaluate(durations)
        shrink_tol = 1.0 + self.tolerance
        for sweep in range(1, _SWEEPS + 1):
            moved = False
            for i in np.argsort(-seg_factor):
                lo, hi = 1.0, float(np.clip(seg_factor[i], shrink_tol, _MAX_STEP))
                best = None
                # Largest feasible shrink of segment i alone, by bisection in log space.
                for _ in range(_BISECTIONS):
                    trial = durations.copy()
                    trial[i] = max(durations[i] / hi, self.min_duration_s)
                    result = self.evaluate(trial)
                    if result is not None and (result[0] >= 1.0).all():
                        best = (trial, result)
                        break
                    if result is not None:
                        k = int(np.argmin(result[0]))
                        binding[i] = result[1][k] + ("" if k == i else f" in segment {k + 1}")
                    hi = float(np.sqrt(lo * hi))
                    if hi < shrink_tol:
                        break
                if best is not None and durations[i] / best[0][i] >= shrink_tol:
                    durations, (seg_factor, new_binding) = best[0], best[1]
                    binding = [
                        b if j == i or seg_factor[j] < shrink_tol else binding[j]
                        for j, b in enumerate(new_binding)
                    ]
                    moved = True
            self.say(f"  sweep {sweep}: {durations.sum():.3f} s")
            if not moved:
                break
        for i in range(len(durations)):
            if durations[i] <= self.min_duration_s * (1 + 1e-9):
                binding[i] = BINDINGS[_FLOOR]
        return durations, binding

    def shorten_by_simulation(self, times, binding, report):
        """Shorten, judged by the simulation itself, segments held by a learned limit elsewhere.

        The limits learned from simulation (tracking speed caps, slow-downs at
        the torque limit) stand in for the simulation in the plan loop, and they
        are conservative: a segment whose plan is held only because a neighbour
        would pass such a limit ("... in segment k") may in fact pass the check
        shorter. Each such segment alone is made ``_FASTER`` shorter while that
        passes the full check (and ``[limits]``), the step's log halved after
        each failure, ``_SIM_BISECTIONS`` simulations per segment.

        Returns
        -------
        times : ndarray, shape (N,)
        report : TorqueReport
            The check at ``times``.
        """
        from trajgen.sim.check import check_torque

        learned = (BINDINGS[_TRACKING], BINDINGS[_SIM_LIMIT])
        for i, b in enumerate(binding):
            if " in segment " not in b or not b.startswith(learned):
                continue
            step = _FASTER
            for _ in range(_SIM_BISECTIONS):
                durations = np.diff(times)
                durations[i] /= step
                trial = _round_times(times[0], durations)
                self.say(f"  segment {i + 1} alone x{step:.3f} faster: simulating")
                try:
                    trial_report = check_torque(self.trajectory(trial), config=self.config)
                except FitError:
                    trial_report = None
                if (
                    trial_report is not None
                    and trial_report.ok
                    and not check_limits(trial_report.trajectory, self.limits)
                ):
                    times, report = trial, trial_report  # and the same step again
                else:
                    step = float(np.sqrt(step))
                if step < 1.0 + self.tolerance:
                    break
        return times, report

    def relax_caps(self, report, times) -> bool:
        """Raise speed caps where a passing run tracks well inside the limit; False if none."""
        record = report.record
        seg = _segment_of(times, record.t)
        limit = report.max_tracking_error_rad
        error = np.abs(record.tracking_error_rad)
        relaxed = False
        for i, j in zip(*np.nonzero(np.isfinite(self.speed_cap)), strict=True):
            worst = error[seg == i, j].max(initial=0.0)
            if worst < _RELAX_BELOW * limit:
                factor = min(_TRACKING_TARGET * limit / max(worst, 1e-9), _MAX_RELAX)
                self.speed_cap[i, j] *= factor
                relaxed = True
        if relaxed:
            self.say("  simulation passes with tracking to spare: speed caps raised")
        return relaxed

    def learn_from_sim(self, report, times) -> bool:
        """Turn the simulation's failures into per-segment caps; False if nothing to learn."""
        record = report.record
        n_seg = len(times) - 1
        seg = _segment_of(times, record.t)
        limit = report.max_tracking_error_rad
        error = np.abs(record.tracking_error_rad)
        at_limit = np.asarray(record.at_limit, dtype=bool)
        plan = report.trajectory
        plan_seg = _segment_of(times, plan.t)
        learned = False
        for i in range(n_seg):
            rows, plan_rows = seg == i, plan_seg == i
            capped = False
            for j in range(self.config.n_joints):
                worst = error[rows, j].max(initial=0.0)
                if worst > limit:
                    peak = np.abs(plan.qd[plan_rows, j]).max(initial=0.0)
                    cap = peak * _TRACKING_TARGET * limit / worst
                    self.speed_cap[i, j] = min(self.speed_cap[i, j], cap)
                    learned = capped = True
            # A servo that falls behind also saturates: the speed cap deals with both.
            hit = [j for j in range(self.config.n_joints) if at_limit[rows, j].any()]
            if hit and not capped:
                self.slow[i] *= _SIM_SLOW_STEP
                self.slow_joint[i] = self.config.names[hit[0]]
                learned = True
        self.say("  simulation: " + ("; ".join(report.reasons[:2]) if report.reasons else "passes"))
        return learned


def _first_negative_root(a, b, c) -> np.ndarray:
    """Per element, the smallest ``s > 0`` where ``a + b s + c s^2`` turns negative.

    ``inf`` where it never does; ``0`` where ``a < 0`` already. Roots by the
    cancellation-free form ``q = -(b + sign(b) sqrt(b^2 - 4ac)) / 2``,
    ``s = q / c`` and ``a / q``.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - 4.0 * a * c
        q = -0.5 * (b + np.copysign(np.sqrt(np.maximum(disc, 0.0)), b))
        roots = np.stack([q / c, a / q])
        roots = np.where((roots > 0) & (disc >= 0), roots, np.inf)
    first = np.nan_to_num(roots.min(axis=0), nan=np.inf)
    return np.where(a < 0, 0.0, first)
