"""Fit the simulated gimbal to telemetry logged on the real one (or a simulated one).

For each joint: ``armature`` (kg m^2), ``frictionloss`` (N m), ``damping``
(N m s/rad) and the Position P Gain (register units, which also tests the P
divisor: a servo whose firmware divides by 256 fits half its register value);
optionally the transport delay (s) from a goal's time label to the present
values read in its frame, and one scale between the logged current and the
simulated torque over the torque constant.

The model is the one ``trajgen sim`` runs (``sim.model``, the firmware loop of
``sim.firmware``). Each log's goals are replayed, held for one stream period,
from the first logged state; the residual is the logged present position
(rad), velocity (weighted by ``VELOCITY_WEIGHT_S``) and current (weighted by
``CURRENT_WEIGHT_RAD_A``) minus the simulated ones at each frame's time plus
the delay. The fit is ``mujoco.sysid``'s optimizer (box-constrained
Gauss-Newton, ``mujoco.minimize.least_squares``) over batched ``mujoco.rollout``
replays, with a Jacobian that perturbs one parameter kind of all three joints
per rollout (``_Replay.jacobian``); the 95 % confidence intervals are
``mujoco.sysid.calculate_intervals`` on a full finite-difference Jacobian at
the optimum. The rest of ``mujoco.sysid`` (its ``TimeSeries`` and ``MjSpec``
model modifiers) is not used: the parameters here are plain ``MjModel``
fields, set in place.

``mujoco.sysid`` needs the ``mujoco[sysid]`` extra (``pip install
'trajgen[sysid]'``); it is imported only here.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trajgen.gimbal import JOINT_NAMES
from trajgen.servo_table import GAIN_MAX
from trajgen.sim.errors import IdentifyError, SimError
from trajgen.sim.firmware import PositionLoop
from trajgen.sim.model import GimbalConfig, JointParams, build_model

#: Weight (s) of a velocity residual (rad/s) against a position residual (rad).
VELOCITY_WEIGHT_S = 0.05
#: Weight (rad/A) of a current residual (A) against a position residual (rad).
CURRENT_WEIGHT_RAD_A = 0.3
#: A parameter whose 95 % interval exceeds this fraction of its value is
#: reported as not excited enough.
POORLY_EXCITED = 0.3

PARAMETERS = ("armature", "frictionloss", "damping", "position_p_gain")
_UNITS = {
    "armature": "kg m^2",
    "frictionloss": "N m",
    "damping": "N m s/rad",
    "position_p_gain": "register",
}
_BOUNDS = {
    "armature": (1e-4, 1.0),
    "frictionloss": (0.0, 1.0),
    "damping": (0.0, 2.0),
    "position_p_gain": (10.0, float(GAIN_MAX)),
}


@dataclass(frozen=True)
class TelemetryLog:
    """One stream's telemetry, as the fit uses it.

    Attributes
    ----------
    path : Path
    t : ndarray, shape (N,)
        Each frame's goal time (s) from the first frame: frame number / rate.
    goal, position, velocity, current : ndarray, shape (N, n)
        Goal angle (rad), present position (rad), velocity (rad/s) and
        current (A); NaN where the read failed.
    rate_hz : float
        Stream rate (Hz).
    """

    path: Path
    t: np.ndarray
    goal: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    current: np.ndarray
    rate_hz: float


def load_telemetry(path, joints=JOINT_NAMES) -> TelemetryLog:
    """Read a ``trajgen stream`` / ``trajgen excite`` telemetry file (.csv, .npz or .mcap)
    of the gimbal whose joints are ``joints`` (columns ``goal_rad_<joint>`` etc.).

    Raises
    ------
    IdentifyError
        If the file lacks the columns, has fewer than 10 rows, or no constant rate.
    OSError
        If it cannot be read.
    """
    path = Path(path)
    if path.suffix == ".mcap":
        from trajgen.ros2_messages import McapMissing
        from trajgen.telemetry_mcap import read_columns

        try:
            columns = read_columns(path)
        except (ValueError, McapMissing) as e:
            raise IdentifyError(str(e)) from None
    elif path.suffix == ".npz":
        with np.load(path) as f:
            columns = {k: np.asarray(f[k]) for k in f.files}
    else:
        with open(path, newline="", encoding="utf-8-sig") as f:  # a spreadsheet's BOM
            rows = list(csv.DictReader(f))
        columns = {k: np.array([r[k] for r in rows]) for k in (rows[0] if rows else {})}
    names = ["frame", "t_s"] + [
        f"{p}_{j}" for p in ("goal_rad", "position_rad", "velocity_rad_s") for j in joints
    ]
    missing = [n for n in names if n not in columns]
    if missing:
        raise IdentifyError(f"{path}: not a telemetry log (no column {missing[0]!r})")
    if len(columns["frame"]) < 10:
        raise IdentifyError(f"{path}: {len(columns['frame'])} rows; a fit needs at least 10")

    def numbers(name):
        return np.array([float(v) if v != "" else math.nan for v in columns[name]])

    frame = numbers("frame")
    steps = np.diff(numbers("t_s"))
    steps = steps[steps > 0]
    if not len(steps):
        raise IdentifyError(f"{path}: t_s never increases: no stream rate")
    rate = 1.0 / float(np.median(steps))
    if not np.all(np.diff(frame) > 0):
        raise IdentifyError(f"{path}: frame numbers do not increase")

    def per_joint(prefix):
        return np.column_stack([numbers(f"{prefix}_{j}") for j in joints])

    return TelemetryLog(
        path=path,
        t=(frame - frame[0]) / rate,
        goal=per_joint("goal_rad"),
        position=per_joint("position_rad"),
        velocity=per_joint("velocity_rad_s"),
        current=per_joint("current_a")
        if f"current_a_{joints[0]}" in columns
        else np.full((len(frame), len(joints)), np.nan),
        rate_hz=rate,
    )


@dataclass(frozen=True)
class JointFit:
    """One joint's fitted parameters.

    Attributes
    ----------
    params : JointParams
        The fit (P gain rounded to a register value).
    values, intervals : dict of str to float
        Each parameter's fitted value and 95 % half-width (inf: not determined).
    residual_rad : float
        RMS position residual (rad).
    poorly_excited : tuple of str
        Parameters whose interval exceeds ``POORLY_EXCITED`` x their value.
    p_divisor, p_divisor_interval : float
        The servo's P scale (``KP = P / p_divisor``) with the P Gain register
        held at the value the servo has (the input config's): the fitted loop
        gain expressed as a scale, and its 95 % half-width.
    """

    params: JointParams
    values: dict
    intervals: dict
    residual_rad: float
    poorly_excited: tuple
    p_divisor: float = math.nan
    p_divisor_interval: float = math.inf


@dataclass(frozen=True)
class Fit:
    """The whole fit.

    Attributes
    ----------
    joints : dict of str to JointFit
        By joint name.
    extras : dict of str to tuple of (float, float or None)
        ``"delay_s"`` (s) and ``"current_scale"``: value and 95 % half-width,
        or None when held.
    config : GimbalConfig
        The input config with the fitted joints.
    rows : int
        Frames used.
    iterations : int
        Gauss-Newton iterations.
    """

    joints: dict
    extras: dict
    config: GimbalConfig
    rows: int
    iterations: int

    @property
    def delay_s(self) -> float:
        """Transport delay (s), fitted or held."""
        return self.extras["delay_s"][0]

    @property
    def current_scale(self) -> float:
        """Logged current over (simulated torque / torque constant), fitted or held."""
        return self.extras["current_scale"][0]

    def _extras_text(self) -> str:
        parts = []
        for name, (value, interval), unit, factor in (
            ("transport delay", self.extras["delay_s"], " ms", 1e3),
            ("current scale", self.extras["current_scale"], "", 1.0),
        ):
            spread = "(held)" if interval is None else f"+- {factor * interval:.2g}{unit}"
            parts.append(f"{name} {factor * value:.3g}{unit} {spread}")
        return "; ".join(parts)

    def format(self) -> str:
        """A table of fit, interval and residual per joint, then what is poorly excited."""
        lines = [
            f"{'joint':<6}{'parameter':<17}{'fit':>12}{'+- 95 %':>12}  {'unit':<10}"
            f"{'residual deg':>13}"
        ]
        for name, joint in self.joints.items():
            for k, p in enumerate(PARAMETERS):
                residual = f"{math.degrees(joint.residual_rad):13.3f}" if k == 0 else ""
                lines.append(
                    f"{name if k == 0 else '':<6}{p:<17}{joint.values[p]:12.5g}"
                    f"{joint.intervals[p]:12.2g}  {_UNITS[p]:<10}{residual}"
                )
        lines.append(f"{self._extras_text()}; {self.rows} frames, {self.iterations} iterations")
        for name, joint in self.joints.items():
            for p in joint.poorly_excited:
                lines.append(
                    f"  - {name} {p}: not excited enough (interval "
                    f"{_relative(joint.intervals[p], joint.values[p])} of the value): "
                    "use a longer or larger excitation (trajgen excite)"
                )
        return "\n".join(lines)

    def toml(self, source: str = "", *, p_scale: bool = False) -> str:
        """``[gimbal.<joint>]`` tables with the intervals in comments.

        With ``p_scale`` the loop gain is written as the servo's P scale
        (``p_divisor``) beside the P Gain register it has, instead of as a P
        Gain at the gimbal's scale: the same loop, for servos whose firmware
        scales P differently (``docs/lead.md``).
        """
        lines = [f"# Fitted by trajgen identify{' from ' + source if source else ''}."]
        lines.append(f"# {self._extras_text()}; intervals are 95 %.")
        for name, joint in self.joints.items():
            lines += [
                "",
                f"[gimbal.{name}]  # residual {math.degrees(joint.residual_rad):.3f} deg RMS",
            ]
            for p in PARAMETERS:
                value = getattr(joint.params, p)
                text = f"{value}" if p == "position_p_gain" else f"{value:.6g}"
                note = "; not excited enough" if p in joint.poorly_excited else ""
                if p == "position_p_gain" and p_scale:
                    held = self.config.joints[self.config.names.index(name)].position_p_gain
                    lines.append(f"{p} = {held:<12}# the register, held")
                    p, text = "p_divisor", f"{joint.p_divisor:.6g}"
                    lines.append(f"{p} = {text:<12}# +- {joint.p_divisor_interval:.2g}{note}")
                    continue
                lines.append(f"{p} = {text:<12}# +- {joint.intervals[p]:.2g} {_UNITS[p]}{note}")
        return "\n".join(lines) + "\n"


def _relative(interval, value):
    if not math.isfinite(interval) or value == 0:
        return "unbounded"
    return f"{100 * interval / abs(value):.0f} %"


class _Replay:
    """Batched rollouts of the gimbal replaying logged goals.

    Parameter vector: per joint armature, frictionloss, damping, P gain (4 n);
    then the names in ``extras`` (``"delay_s"``, ``"current_scale"``), in that
    order; those not in ``extras`` take the values of ``held``.
    """

    def __init__(self, config: GimbalConfig, logs, *, use_current: bool):
        import mujoco

        self.extras: tuple[str, ...] = ()
        self.held = {"delay_s": 0.0, "current_scale": 1.0}
        self.n, self.names = config.n_joints, config.names
        self.model = build_model(config)
        self.dt = config.timestep_s
        self.kp_per_unit = np.array(
            [
                PositionLoop(p_gain=1, p_divisor=config.loop(j).p_divisor).mujoco_controller(s)[0]
                for j, s in enumerate(config.servos)
            ]
        )
        self.kt = np.array([s.torque_constant_nm_a for s in config.servos])
        self.models = []
        self.datas = [mujoco.MjData(self.model) for _ in range(2)]
        self.cases = []
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        for log in logs:
            steps = max(1, round(1.0 / (log.rate_hz * self.dt)))
            frame_step = np.round(log.t / self.dt).astype(int)
            total = frame_step[-1] + 3 * steps
            # Goal of the last frame written at or before each step (zero-order hold).
            which = np.searchsorted(frame_step, np.arange(total), side="right") - 1
            data = mujoco.MjData(self.model)
            data.qpos[:] = log.position[0]
            data.qvel[:] = np.nan_to_num(log.velocity[0])
            state = np.empty(mujoco.mj_stateSize(self.model, spec))
            mujoco.mj_getState(self.model, data, state, spec)
            ok = np.all(np.isfinite(log.position) & np.isfinite(log.velocity), axis=1)
            current = use_current and np.all(np.isfinite(log.current[ok]))
            self.cases.append((log, log.goal[which], state, ok, current))

    def _model_for(self, k, x):
        import mujoco

        while len(self.models) <= k:
            self.models.append(copy.copy(self.model))
        m = self.models[k]
        p = x[: 4 * self.n].reshape(self.n, 4)
        m.dof_armature[:] = p[:, 0]
        m.dof_frictionloss[:] = p[:, 1]
        m.dof_damping[:] = p[:, 2]
        m.actuator_gainprm[:, 4] = p[:, 3] * self.kp_per_unit
        mujoco.mj_setConst(m, self.datas[0])  # constraint scaling depends on armature
        return m

    def _extra_values(self, x) -> dict:
        k = x.shape[1]
        values = {name: np.full(k, value) for name, value in self.held.items()}
        for n, name in enumerate(self.extras):
            values[name] = x[4 * self.n + n]
        return values

    def predict(self, x):
        """Simulated position, velocity and current at each logged frame, for columns of x.

        Parameters
        ----------
        x : ndarray, shape (4 n + len(extras), k)

        Returns
        -------
        list over logs of (pos, vel, cur), each shape (k, N, n)
        """
        from mujoco import rollout

        k, nj = x.shape[1], self.n
        models = [self._model_for(i, x[:, i]) for i in range(k)]
        out = []
        for log, ctrl, state, _, _ in self.cases:
            states, torque = rollout.rollout(models, self.datas, state[None], ctrl[None])
            start = np.broadcast_to(state[1 : 1 + 2 * nj], (k, 1, 2 * nj))
            qv = np.concatenate([start, states[:, :, 1 : 1 + 2 * nj]], axis=1)  # at t = i dt
            grid = np.arange(qv.shape[1]) * self.dt
            torque_grid = grid[1:]  # a step's torque, as read at its end
            pos = np.empty((k, len(log.t), nj))
            vel, cur = np.empty_like(pos), np.empty_like(pos)
            extra = self._extra_values(x)
            for i in range(k):
                when = log.t + extra["delay_s"][i]
                for j in range(nj):
                    pos[i, :, j] = np.interp(when, grid, qv[i, :, j])
                    vel[i, :, j] = np.interp(when, grid, qv[i, :, nj + j])
                    cur[i, :, j] = np.interp(when, torque_grid, torque[i, :, j]) / self.kt[j]
                cur[i] *= extra["current_scale"][i]
            out.append((pos, vel, cur))
        return out

    def jacobian(self, x, r):
        """Finite-difference Jacobian (M, n) at ``x`` (n, 1) with residual ``r`` (M, 1).

        The joints hardly couple (the reflected rotor inertia dwarfs the links),
        so one rollout perturbs the same parameter of all joints and each
        joint's residual rows (every n-th row) are credited to its own
        parameter: 4 rollouts for the 4 n joint parameters, plus one per extra.
        The optimum is unchanged (the residual is exact); only the step
        directions are approximate.
        """
        x = x[:, 0]
        n, own = len(x), 4 * self.n  # all parameters, the joints' own
        steps = 1e-5 * np.maximum(np.abs(x), 1e-3)
        columns = np.repeat(x[:, None], n - own + 4, axis=1)
        for kind in range(4):
            columns[kind:own:4, kind] += steps[kind:own:4]
        for e in range(own, n):
            columns[e, e - own + 4] += steps[e]
        dr = self.residuals(columns) - r
        jac = np.zeros((len(r), n))
        joint = np.arange(len(r)) % self.n
        for kind in range(4):
            for j in range(self.n):
                rows = joint == j
                jac[rows, 4 * j + kind] = dr[rows, kind] / steps[4 * j + kind]
        for e in range(own, n):
            jac[:, e] = dr[:, e - own + 4] / steps[e]
        return jac

    def residuals(self, x):
        """Weighted residuals, shape (M, k), for ``x`` of shape (4 n + len(extras), k)."""
        parts = []
        for (pos, vel, cur), (log, _, _, ok, current) in zip(
            self.predict(x), self.cases, strict=True
        ):
            pieces = [
                pos[:, ok] - log.position[ok],
                (vel[:, ok] - log.velocity[ok]) * VELOCITY_WEIGHT_S,
            ]
            if current:
                pieces.append((cur[:, ok] - log.current[ok]) * CURRENT_WEIGHT_RAD_A)
            parts += [p.reshape(len(p), -1).T for p in pieces]
        return np.concatenate(parts)


def _sysid():
    try:
        from mujoco import sysid
    except ImportError:  # pragma: no cover (mujoco is a core dependency)
        sysid = None
    if sysid is None or not hasattr(sysid, "optimize"):
        raise IdentifyError(
            "trajgen identify needs mujoco.sysid: install the extra with "
            "pip install 'trajgen[sysid]' (or pip install 'mujoco[sysid]')"
        )
    return sysid


def _fit(sysid, replay, start, max_iter, bounds):
    """One ``mujoco.sysid`` fit from ``start`` (4 values per joint, then ``replay.extras``).

    ``bounds`` maps each extra to its (low, high). Returns the fitted vector,
    its 95 % half-widths and the iteration count.
    """
    params = sysid.ParameterDict()
    own = 4 * replay.n
    for j, name in enumerate(replay.names):
        for i, p in enumerate(PARAMETERS):
            low, high = _BOUNDS[p]
            # Start off the bounds (a zero friction or damping would sit on one).
            value = float(np.clip(start[4 * j + i], low + 2e-3 * (high - low), high))
            params.add(sysid.Parameter(f"{name}.{p}", value, low, high))
    for n, name in enumerate(replay.extras):
        low, high = bounds[name]
        value = float(
            np.clip(start[own + n], low + 0.02 * (high - low), high - 0.02 * (high - low))
        )
        params.add(sysid.Parameter(name, value, low, high))

    def residual_fn(x, _params):
        x = np.asarray(x, dtype=float)
        r = replay.residuals(x if x.ndim == 2 else x[:, None])
        return [r if x.ndim == 2 else r[:, 0]], None, None

    scale = np.maximum(np.abs(params.as_vector()), 1e-3)
    trace = io.StringIO()  # the optimizer's per-iteration printout
    fitted, result = sysid.optimize(
        params,
        residual_fn,
        optimizer="mujoco",
        verbose=False,
        max_iters=max_iter,
        x_scale=scale,
        output=trace,
        jacobian=replay.jacobian,
    )
    x = fitted.as_vector()
    r = replay.residuals(x[:, None])[:, 0]
    if not np.all(np.isfinite(r)):
        raise SimError("the fit diverged (the simulated gimbal went unstable)")
    # Intervals from a full forward-difference Jacobian at the optimum, in scaled
    # coordinates (the raw columns span 1e-2 to 1e3 and would look singular).
    jac_scaled = (replay.residuals(x[:, None] + np.diag(1e-5 * scale)) - r[:, None]) / 1e-5
    _, scaled_intervals = sysid.calculate_intervals([r], jac_scaled)
    return x, scaled_intervals * scale, len(result.extras.get("objective", ()))


def identify(
    config: GimbalConfig,
    logs,
    *,
    use_current: bool = True,
    delay_s: float = 0.0,
    fit_delay: bool = False,
    fit_current_scale: bool = False,
    max_iter: int = 30,
    p_scale: bool = False,
) -> Fit:
    """Fit each joint's armature, frictionloss, damping and P gain (and a delay, a current scale).

    Parameters
    ----------
    config : GimbalConfig
        The gimbal (servos, payload); its joints are the starting point.
    logs : sequence of TelemetryLog
        One or more logs (``load_telemetry``), all at the same servos.
    use_current : bool
        Also fit the logged current, as torque over the torque constant (stall
        torque / stall current) times the current scale. Position data alone
        fix the parameters only up to a common scale, which the known back-EMF
        pins weakly; current pins it, if the servo reports it truly.
    delay_s : float
        Time (s) from a frame's goal to its present values: 0 when the log's
        present values are what the servo had as the goal arrived (the
        virtual bus in lock-step); on hardware the read follows the write by
        about a millisecond.
    fit_delay : bool
        Fit the delay too (from ``delay_s``, within two stream periods).
    fit_current_scale : bool
        Fit the current scale too (from 1, within 0.2..5): for a servo whose
        current reading is off by a factor. It brings back the common scale
        that only the back-EMF pins, so expect wider intervals.
    max_iter : int
        Gauss-Newton iterations at most.
    p_scale : bool
        Give the fitted loop gain as each servo's P scale (``p_divisor``) with
        its P Gain register held at ``config``'s value (``Fit.config``); the
        fit itself is the same (only the product P / scale is observable).

    Returns
    -------
    Fit

    Raises
    ------
    IdentifyError
        If ``mujoco[sysid]`` is missing or no log is given.
    SimError
        If the fit diverges.

    Notes
    -----
    The delay and the current scale trade against the joints' parameters (the
    lag of the P gain, the common scale), so the joints are fitted first with
    them held, then everything together from there.
    """
    sysid = _sysid()
    if not logs:
        raise IdentifyError("no telemetry log to fit")
    replay = _Replay(config, logs, use_current=use_current)
    replay.held["delay_s"] = float(delay_s)
    x, intervals, iterations = _fit(
        sysid,
        replay,
        [getattr(config.joints[j], p) for j in range(config.n_joints) for p in PARAMETERS],
        max_iter,
        {},
    )
    period = 1.0 / min(log.rate_hz for log in logs)
    bounds = {"delay_s": (0.0, 2.0 * period), "current_scale": (0.2, 5.0)}
    replay.extras = tuple(
        name
        for name, asked in (("delay_s", fit_delay), ("current_scale", fit_current_scale))
        if asked
    )
    if replay.extras:
        start = np.append(x, [replay.held[name] for name in replay.extras])
        x, intervals, more = _fit(sysid, replay, start, max_iter, bounds)
        iterations += more
    extras = {name: (value, None) for name, value in replay.held.items()}
    for n, name in enumerate(replay.extras):
        own = 4 * config.n_joints
        extras[name] = (float(x[own + n]), float(intervals[own + n]))

    ok_rows = [case[3] for case in replay.cases]
    predicted = replay.predict(x[:, None])
    joints = {}
    for j, name in enumerate(config.names):
        values = {p: float(x[4 * j + i]) for i, p in enumerate(PARAMETERS)}
        ivals = {p: float(intervals[4 * j + i]) for i, p in enumerate(PARAMETERS)}
        errors = np.concatenate(
            [
                pred[0][0, ok, j] - log.position[ok, j]
                for pred, log, ok in zip(predicted, logs, ok_rows, strict=True)
            ]
        )
        poorly = tuple(
            p
            for p in PARAMETERS
            if not math.isfinite(ivals[p]) or ivals[p] > POORLY_EXCITED * abs(values[p])
        )
        register, divisor = config.joints[j].position_p_gain, config.loop(j).p_divisor
        scale = divisor * register / values["position_p_gain"]  # same KP, register held
        joints[name] = JointFit(
            params=JointParams.of(
                config.servos[j],
                armature=values["armature"],
                frictionloss=values["frictionloss"],
                damping=values["damping"],
                position_p_gain=int(round(values["position_p_gain"])),
            ),
            values=values,
            intervals=ivals,
            residual_rad=float(np.sqrt(np.mean(errors**2))),
            poorly_excited=poorly,
            p_divisor=float(scale),
            p_divisor_interval=float(scale * ivals["position_p_gain"] / values["position_p_gain"]),
        )
    fitted = tuple(joints[n].params for n in config.names)
    if p_scale:
        fitted = tuple(
            dataclasses.replace(
                joints[n].params,
                position_p_gain=config.joints[j].position_p_gain,
                p_divisor=joints[n].p_divisor,
            )
            for j, n in enumerate(config.names)
        )
    return Fit(
        joints=joints,
        extras=extras,
        config=dataclasses.replace(config, joints=fitted),
        rows=sum(int(ok.sum()) for ok in ok_rows),
        iterations=iterations,
    )
