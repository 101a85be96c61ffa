"""Running a joint stream through the simulated gimbal."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from trajgen.lift import sent_goals
from trajgen.sim.errors import SimulationError
from trajgen.sim.firmware import PULSES_PER_RAD
from trajgen.sim.model import GimbalConfig, build_model

from .errors import BadArgument

_LIMIT_RTOL = 1e-6
#: The per-step arrays of a SimRecord.
_ARRAYS = ("t", "q", "qd", "torque_nm", "setpoint", "planned", "at_limit")
_PROGRESS_STEP = 0.05


@dataclass(frozen=True)
class SimRecord:
    """What one simulated run recorded, one row per physics step.

    Attributes
    ----------
    t : ndarray, shape (K,)
        Step start times (s), on the trajectory's clock.
    q, qd : ndarray, shape (K, n)
        Joint angles (rad) and velocities (rad/s) at the start of each step.
    torque_nm : ndarray, shape (K, n)
        Actuator torque (N m) applied during each step.
    setpoint : ndarray, shape (K, n)
        Held (zero-order-hold) position setpoint (rad).
    planned : ndarray, shape (K, n)
        The planned path at ``t`` (rad): cubic Hermite through the stream's
        ``(q, qd)`` samples.
    at_limit : ndarray of bool, shape (K, n)
        The servo gave all the torque it had: drive at the rated voltage or torque
        at the stall-torque clamp.
    timestep_s : float
        Physics time step (s).
    lift : SimRecord or None
        The steps of the lift before the plan's first frame (``trajgen.lift``:
        the plan held at its first point), kept apart; None without a lift. The
        arrays above start at the plan's first frame.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    torque_nm: np.ndarray
    setpoint: np.ndarray
    planned: np.ndarray
    at_limit: np.ndarray
    timestep_s: float
    lift: SimRecord | None = None

    def split_lift(self, t0: float) -> SimRecord:
        """This record from ``t0`` (s, the plan's first frame) on, the steps before
        it as its :attr:`lift` (None if there are none)."""
        k = int(np.searchsorted(self.t, t0 - 1e-9))
        if k == 0:
            return self
        before = {a: getattr(self, a)[:k] for a in _ARRAYS}
        after = {a: getattr(self, a)[k:] for a in _ARRAYS}
        lift = SimRecord(**before, timestep_s=self.timestep_s)
        return SimRecord(**after, timestep_s=self.timestep_s, lift=lift)

    def with_lift(self) -> SimRecord:
        """Every step, the lift's first (undoes :meth:`split_lift`)."""
        if self.lift is None:
            return self
        both = {a: np.concatenate([getattr(self.lift, a), getattr(self, a)]) for a in _ARRAYS}
        return SimRecord(**both, timestep_s=self.timestep_s)

    @property
    def tracking_error_rad(self) -> np.ndarray:
        """``q - planned`` (rad), shape (K, n)."""
        return self.q - self.planned

    @property
    def hold_error_rad(self) -> np.ndarray:
        """``q - setpoint`` (rad), shape (K, n): the error the servo sees."""
        return self.q - self.setpoint

    @property
    def steps_at_limit(self) -> np.ndarray:
        """Number of steps at the voltage limit per joint, shape (n,), int."""
        return self.at_limit.sum(axis=0)


def at_torque_limit(config: GimbalConfig, qd, torque_nm, vmax=None) -> np.ndarray:
    """Whether each servo gives all the torque it has.

    A ``<dcmotor>`` with constant ``K = V / w0`` and resistance ``R = K V / tau_stall``
    needs ``v = R tau / K + K w`` volts to give ``tau`` at speed ``w``; it is at
    its limit when that is the drive's cap (the rated voltage at full PWM Limit) or when
    ``|tau|`` is at the stall torque clamp.

    Parameters
    ----------
    config : GimbalConfig
    qd, torque_nm : ndarray, shape (K, n)
        Joint speed (rad/s) and actuator torque (N m).
    vmax : float or array_like, broadcastable to (K, n), optional
        The drive's voltage cap (V); default each servo's rated voltage.

    Returns
    -------
    ndarray of bool, shape (K, n)
    """
    w0 = np.array([s.no_load_speed_rad_s for s in config.servos])
    stall = np.array([s.stall_torque_nm for s in config.servos])
    volts_rated = np.array([s.voltage_v for s in config.servos])
    vmax = volts_rated if vmax is None else vmax
    k = volts_rated / w0
    r = k * volts_rated / stall
    volts = r / k * torque_nm + k * qd
    clamped = np.abs(torque_nm) >= stall * (1.0 - _LIMIT_RTOL)
    return clamped | (np.abs(volts) >= np.asarray(vmax) * (1.0 - _LIMIT_RTOL))


def planned_path(trajectory, t) -> np.ndarray:
    """The planned joint path at times ``t`` (cubic Hermite through ``(q, qd)`` samples).

    Parameters
    ----------
    trajectory : trajgen.stream.JointTrajectory
    t : ndarray, shape (K,)
        Times (s); clamped to the trajectory's span.

    Returns
    -------
    ndarray, shape (K, n)
    """
    ts = trajectory.t
    t = np.clip(np.asarray(t, dtype=float), ts[0], ts[-1])
    i = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2)
    h = (ts[i + 1] - ts[i])[:, None]
    s = ((t - ts[i])[:, None]) / h
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    q, qd = trajectory.q, trajectory.qd
    return h00 * q[i] + h10 * h * qd[i] + h01 * q[i + 1] + h11 * h * qd[i + 1]


def warning_counts(data) -> np.ndarray:
    """MuJoCo's warning counters ``data.warning[i].number`` as an int array (a copy)."""
    return data.warning.number.copy()


def goal_ticks_rad(q_rad) -> np.ndarray:
    """Angles (rad) rounded to whole encoder ticks (4096 per turn), as Goal Position is."""
    return np.round(np.asarray(q_rad, dtype=float) * PULSES_PER_RAD) / PULSES_PER_RAD


def step_frames(trajectory, timestep_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Physics steps of a stream: each step's start time and the frame it holds.

    The frames are every frame sent (``trajgen.lift.sent_goals``: the lift's, if
    any, then the trajectory's). Frame ``i`` is held from ``t[i]`` to ``t[i + 1]``,
    the last one for one stream period.

    Returns
    -------
    step_t : ndarray, shape (K,)
        Step start times (s).
    frame : ndarray of int, shape (K,)
        Index of the frame (of those sent) held during each step.
    """
    ts = sent_goals(trajectory)[0]
    period = 1.0 / float(trajectory.rate_hz)
    n_steps = int(round((ts[-1] - ts[0] + period) / timestep_s))
    step_t = ts[0] + np.arange(n_steps) * timestep_s
    return step_t, np.searchsorted(ts, step_t + 1e-9, side="right") - 1


def step_controls(trajectory, timestep_s: float) -> tuple[np.ndarray, np.ndarray]:
    """What the servos are sent, one row per physics step.

    Each frame's goal (``trajectory.goal`` if the goals are led, see
    ``trajgen.lead``; else its planned angles; the lift's first, see
    ``trajgen.lift``), rounded to whole ticks as Goal Position is, held for its
    frame (:func:`step_frames`).

    Returns
    -------
    step_t : ndarray, shape (K,)
        Step start times (s).
    ctrl : ndarray, shape (K, n)
        Goal position per joint (rad, whole ticks).
    """
    step_t, frame = step_frames(trajectory, timestep_s)
    return step_t, goal_ticks_rad(sent_goals(trajectory)[1])[frame]


def simulation_model(config: GimbalConfig):
    """The gimbal (:func:`~trajgen.sim.model.build_model`) without the stages nothing here uses.

    Three of MuJoCo's stages are switched off, and no result changes (tests
    compare bit for bit):

    - collision detection (``mjDSBL_CONTACT``): every geom of the gimbal is
      contact-free (``contype = conaffinity = 0``, no explicit ``<pair>``), so
      it can never find a contact;
    - sensors (``mjDSBL_SENSOR``): the torque is read from ``actuator_force``,
      and the model's torque sensors cost an extra pass over the bodies each step;
    - island discovery (``mjDSBL_ISLAND``): the gimbal is one kinematic chain,
      so its constraints (the joints' Coulomb friction) always form one island.

    A physics step then costs about a third less, an ``mj_inverse`` call
    about a tenth.

    Raises
    ------
    SimulationError
        If the model has geoms that could collide after all.
    """
    import mujoco

    model = build_model(config)
    collides = model.geom_contype[:, None] & model.geom_conaffinity[None, :]
    if model.npair or collides.any():
        raise SimulationError(
            "the gimbal model has geoms that can collide; every geom must have "
            'contype="0" conaffinity="0"'
        )
    off = mujoco.mjtDisableBit
    model.opt.disableflags |= off.mjDSBL_CONTACT | off.mjDSBL_SENSOR | off.mjDSBL_ISLAND
    return model


def run_batch(
    models,
    q0,
    t0: float,
    step_t: np.ndarray,
    controls: np.ndarray,
    *,
    threads: int = 1,
    labels=None,
    progress: Callable[[float], None] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run the gimbal under open-loop goal positions, one run per model.

    Each run starts at rest at ``q0`` (one row per run, or one for all) at time
    ``t0`` (after ``mj_forward``)
    and takes one ``mj_step`` per row of its controls, all inside MuJoCo
    (``mujoco.batch.Batch.rollout`` on ``threads`` threads: no Python per
    step). The results equal a plain ``mj_step`` loop's bit for bit. Runs whose
    models give ``MjData`` the same layout share one batch (the gimbal with a
    payload has one geom more than without).

    Parameters
    ----------
    models : sequence of mujoco.MjModel, length B
        One per run (e.g. :func:`simulation_model` of several configs).
    q0 : array_like, shape (nq,) or (B, nq)
        Joint angles at the start (rad).
    t0 : float
        Simulated time at the start (s).
    step_t : ndarray, shape (K,)
        Step start times (s), for messages.
    controls : ndarray, shape (B, K, nu)
        Goal positions (rad) per run and step.
    threads : int
        Worker threads, including the caller's.
    labels : sequence of str, optional
        One per run, to name a run that fails.
    progress : callable, optional
        Called with the fraction done (0..1) every 5 % of the steps; without
        it each batch runs in one call.

    Returns
    -------
    q, qd : ndarray, shape (B, K, nv)
        Joint angles (rad) and velocities (rad/s) at the start of each step.
    torque : ndarray, shape (B, K, nu)
        Actuator torque (N m) applied during each step.

    Raises
    ------
    SimulationError
        If a MuJoCo warning counter rises in a run (MuJoCo stops that run there).
    """
    import mujoco
    from mujoco import batch

    n_runs, n_steps, nu = controls.shape
    nv = models[0].nv
    q = np.empty((n_runs, n_steps + 1, nv))
    qd = np.empty((n_runs, n_steps + 1, nv))
    torque = np.empty((n_runs, n_steps, nu))
    n_chunks = 1 if progress is None else round(1.0 / _PROGRESS_STEP)
    edges = np.unique(np.linspace(0, n_steps, n_chunks + 1).round().astype(int))
    when = mujoco.mjtState.mjSTATE_TIME
    number = 1  # a warning's (lastinfo, number), as mjWarningStat
    done = 0
    q0 = np.broadcast_to(np.asarray(q0, dtype=float), (n_runs, nv))
    for ids in _same_layout(models):
        runs = batch.Batch(models[ids[0]], len(ids), nthread=threads)
        runs.set_models([models[i] for i in ids])
        runs.qpos[:] = q0[ids]
        runs.time[:] = t0
        runs.forward()
        q[ids, 0], qd[ids, 0] = runs.qpos, runs.qvel
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            before = runs.warning[..., number].copy()
            rec = runs.rollout(
                int(b - a),
                control=controls[ids, a:b],
                record=("qpos", "qvel", "actuator_force", when),
            )
            risen = runs.warning[..., number] > before
            _raise_on_stopped_runs(risen, rec[when][..., 0], step_t[a:b], ids, labels)
            q[ids, a + 1 : b + 1], qd[ids, a + 1 : b + 1] = rec["qpos"], rec["qvel"]
            torque[ids, a:b] = rec["actuator_force"]
            done += len(ids) * (b - a)
            if progress is not None:
                progress(done / (n_runs * n_steps))
    return q[:, :-1], qd[:, :-1], torque


def _same_layout(models) -> list[list[int]]:
    """Indices of ``models`` grouped by the sizes that lay out their ``MjData``."""
    if len(models) == 1:  # nothing to compare (and listing a model's sizes takes 0.5 ms)
        return [[0]]
    groups: dict[tuple, list[int]] = {}
    for i, m in enumerate(models):
        sizes = tuple(
            v for a in dir(m) if a.startswith("n") and isinstance(v := getattr(m, a), int)
        )
        groups.setdefault(sizes, []).append(i)
    return list(groups.values())


def _raise_on_stopped_runs(risen, time, step_t, ids, labels) -> None:
    """Raise for the first run whose warning counters rose (``risen``, shape (b, nwarning)).

    MuJoCo stops a run after the step that warned and repeats that step's
    record, so the step is the last one whose end time ``time`` (shape (b, k))
    moved on. ``ids`` maps the rows to runs, for ``labels``.
    """
    failed = np.flatnonzero(risen.any(axis=1))
    if not len(failed):
        return
    import mujoco

    row = int(failed[0])
    stalled = np.flatnonzero(np.diff(time[row]) == 0)
    step = int(stalled[0]) if len(stalled) else len(step_t) - 1
    names = ", ".join(mujoco.mjtWarning(int(i)).name for i in np.flatnonzero(risen[row]))
    where = "" if labels is None else f"{labels[ids[row]]}: "
    raise SimulationError(f"{where}MuJoCo warning in the step at t = {step_t[step]:.4f} s: {names}")


def record_from_run(trajectory, config: GimbalConfig, step_t, ctrl, q, qd, torque) -> SimRecord:
    """The :class:`SimRecord` of one run of ``trajectory`` (arrays as :func:`run_batch` gives),
    the steps of its lift (before ``trajectory.t[0]``) kept apart (``SimRecord.lift``)."""
    return SimRecord(
        t=step_t,
        q=q,
        qd=qd,
        torque_nm=torque,
        setpoint=ctrl,
        planned=planned_path(trajectory, step_t),
        at_limit=at_torque_limit(config, qd, torque),
        timestep_s=config.timestep_s,
    ).split_lift(float(trajectory.t[0]))


def step_and_record(model, data, q, qd, torque) -> None:
    """Step ``len(q)`` times, recording each step's start state and its torque.

    Parameters
    ----------
    model, data : mujoco.MjModel, mujoco.MjData
    q, qd, torque : ndarray, shape (K, nv)
        Filled in place: joint angles (rad) and velocities (rad/s) at the start
        of each step, actuator torque (N m) applied during it.

    Raises
    ------
    SimulationError
        If a contact appears inside the gimbal.
    """
    import mujoco

    for k in range(len(q)):
        q[k] = data.qpos
        qd[k] = data.qvel
        mujoco.mj_step(model, data)
        torque[k] = data.actuator_force
        if data.ncon:
            raise SimulationError(
                f"{data.ncon} contact(s) inside the gimbal at t = {data.time:.4f} s"
            )


def raise_on_new_warnings(before: np.ndarray, data, t_from: float, t_to: float) -> None:
    """Raise :class:`SimulationError` if a MuJoCo warning counter rose since ``before``.

    ``t_from`` and ``t_to`` (s) bound the steps since the counts were taken,
    for the message.
    """
    after = data.warning.number
    if not (after > before).any():
        return
    import mujoco

    risen = np.flatnonzero(after > before)
    if len(risen):
        names = ", ".join(mujoco.mjtWarning(int(i)).name for i in risen)
        raise SimulationError(f"MuJoCo warning between t = {t_from:.4f} and {t_to:.4f} s: {names}")


def check_trajectory(trajectory, n_joints: int = 3) -> None:
    """Raise if ``trajectory`` is not a usable ``JointTrajectory`` of ``n_joints`` joints
    (the gimbal's, ``GimbalConfig.n_joints``; one column per joint in every array).

    Raises
    ------
    TypeError
        If it lacks the ``t``, ``q``, ``qd``, ``qdd``, ``rate_hz`` fields.
    ValueError
        If the arrays have the wrong shapes, fewer than 2 frames, or non-finite values.
    """
    fields = ("t", "q", "qd", "qdd", "rate_hz")
    if not all(hasattr(trajectory, f) for f in fields):
        raise TypeError(
            f"Expected `trajectory` to be a JointTrajectory, got {type(trajectory).__name__}."
        )
    n = np.shape(trajectory.t)
    if len(n) != 1 or n[0] < 2:
        raise BadArgument(f"Expected `trajectory.t` to have shape (N,), N >= 2, got {n}.")
    lift = getattr(trajectory, "lift", None)
    if lift is not None and np.shape(lift.goal) != (len(lift.t), n_joints):
        raise BadArgument(
            f"Expected `trajectory.lift.goal` to have shape ({len(lift.t)}, {n_joints}), "
            f"got {np.shape(lift.goal)}."
        )
    fields = ("q", "qd", "qdd") + (() if getattr(trajectory, "goal", None) is None else ("goal",))
    for f in fields:
        a = np.asarray(getattr(trajectory, f))
        if a.shape != (n[0], n_joints):
            raise BadArgument(
                f"Expected `trajectory.{f}` to have shape ({n[0]}, {n_joints}), got {a.shape}."
            )
        if not np.all(np.isfinite(a)):
            raise BadArgument(f"Expected `trajectory.{f}` to be finite, got a NaN or inf.")


def simulate(
    trajectory,
    config: GimbalConfig | None = None,
    *,
    progress: Callable[[float], None] | None = None,
    model=None,
) -> SimRecord:
    """Stream a planned joint trajectory to the simulated servos.

    The gimbal starts at rest where servos holding the first goal sent sit
    (``sim.lead.sagged_start``: sagged under gravity below it, as real ones). Each
    frame's goal (the lift's first, ``trajgen.lift``; ``trajectory.goal`` when
    led, else its angles), rounded to whole ticks as Goal Position is, is the
    servos' goal from ``t[i]`` to ``t[i + 1]`` (the last frame's for one stream
    period); the servos' own position loop
    (``sim.firmware``, gains from ``config``) does the rest, exactly as
    behind the virtual bus (``sim.plant.GimbalPlant``). Physics runs at
    ``config.timestep_s``, inside MuJoCo (:func:`run_batch`).

    Parameters
    ----------
    trajectory : trajgen.stream.JointTrajectory
        The planned stream, with the goals to send attached (``goal``) or not;
        the record's tracking error is against the plan (``q``).
    config : GimbalConfig, optional
        Default :class:`GimbalConfig`.
    progress : callable, optional
        Called with the fraction done (0..1) every 5 % of the run.
    model : mujoco.MjModel, optional
        ``simulation_model(config)`` if the caller has built it already.

    Returns
    -------
    SimRecord

    Raises
    ------
    TypeError, ValueError
        If ``trajectory`` is not a valid ``JointTrajectory``.
    SimulationError
        If a MuJoCo warning counter rises during the run.
    """
    from trajgen.sim.lead import sagged_start

    config = GimbalConfig() if config is None else config
    check_trajectory(trajectory, config.n_joints)
    step_t, ctrl = step_controls(trajectory, config.timestep_s)
    model = simulation_model(config) if model is None else model
    q, qd, torque = run_batch(
        [model],
        sagged_start(trajectory, config, model),
        step_t[0],
        step_t,
        ctrl[None],
        progress=progress,
    )
    return record_from_run(trajectory, config, step_t, ctrl, q[0], qd[0], torque[0])
