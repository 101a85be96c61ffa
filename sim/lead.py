"""The simulated gimbal's side of the led goals (``trajgen.lead``).

``trajgen.lead`` holds the bounded arithmetic and knows no MuJoCo; this module
gives it what only the model knows: each joint's loop parameters from a
:class:`~trajgen.sim.model.GimbalConfig` (the file's ``[gimbal.<joint>]``
tables, e.g. fitted by ``trajgen identify``) and the plan's inverse dynamics
(``mj_inverse``: inertia, gravity, viscous and Coulomb friction). It also
switches the lead off on a joint whose plan fails the torque check (part (a)
of ``sim.check``): a saturated servo only pushes a led goal further out.
Everything that streams and ``trajgen sim`` call :func:`lead_trajectory`, so
the simulation runs exactly the goals that would be sent.
"""

from __future__ import annotations

import numpy as np

from trajgen.lead import LeadParams, led_goals, led_trajectory
from trajgen.sim.model import GimbalConfig


def lead_params(config: GimbalConfig, model=None) -> LeadParams:
    """Each joint's ``kp``, ``K^2/R``, lag time and Coulomb friction under ``config``.

    ``kp`` and ``K^2/R`` are the ``<dcmotor>`` controller's (``sim.firmware``:
    ``P / p_divisor`` in torque space, and the back-EMF the drive leaves); the
    lag time is ``(K^2/R + damping) / kp`` (``sim.check.lag_time_s``). With
    ``model`` (the simulated gimbal) also each joint's inertia
    (:func:`joint_inertia`), which the model lead's bounded preview needs.
    """
    kp, back_emf, lag, friction = [], [], [], []
    for j in range(config.n_joints):
        k, _, kd, _ = config.loop(j).mujoco_controller(config.servos[j])
        kp.append(k)
        back_emf.append(kd)
        lag.append((kd + config.joints[j].damping) / k)
        friction.append(config.joints[j].frictionloss)
    inertia = None if model is None else joint_inertia(model)
    return LeadParams(kp, back_emf, lag, friction, enabled=True, inertia_kg_m2=inertia)


def joint_inertia(model) -> np.ndarray:
    """Each joint's inertia at the home pose (kg m^2, shape (n,)): the diagonal of
    MuJoCo's mass matrix (links and reflected rotor inertia, ``armature``)."""
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return np.diag(full).copy()


def torque_function(model):
    """``torque(q, qd, qdd)`` (arrays (N, n) -> N m (N, n)): ``mj_inverse`` on ``model``."""
    from trajgen.sim.dynamics import inverse_dynamics

    def torque(q, qd, qdd):
        return inverse_dynamics(model, q, qd, qdd)

    return torque


def lead_trajectory(
    trajectory, config: GimbalConfig, lead: str = "model", *, limits_rad=None, model=None
):
    """``trajectory`` with the goals to send attached (``JointTrajectory.goal``).

    Parameters
    ----------
    trajectory : JointTrajectory
        The plan.
    config : GimbalConfig
        The servos and their loops (and the torque check's margin).
    lead : {"model", "advance", "none"}
    limits_rad : array_like, shape (n, 2), optional
        Position limits (rad) every goal must stay inside.
    model : mujoco.MjModel, optional
        ``sim.run.simulation_model(config)`` if the caller has built it.

    Returns
    -------
    trajectory : JointTrajectory
        With ``goal`` (N, n) rad, one column per joint.
    goals : trajgen.lead.LedGoals
        The goals and what bounded them.
    reasons : tuple of str
        Why a joint got no lead (its plan fails the torque check), and a note if
        the plan starts or ends moving (:func:`moving_ends`).
    """
    from trajgen.sim.check import check_planned_torque
    from trajgen.sim.run import simulation_model

    model = simulation_model(config) if model is None else model
    params = lead_params(config, model)
    reasons: tuple[str, ...] = ()
    if lead != "none":
        failed = check_planned_torque(trajectory, config, model=model)
        off = [
            j
            for j, name in enumerate(config.names)
            if any(r.startswith(f"{name}:") for r in failed)
        ]
        if off:
            params = params.without(off)
            reasons = tuple(
                f"{config.names[j]}: no lead (the plan fails the torque check)" for j in off
            )
    goals = led_goals(
        trajectory, lead, params, torque=torque_function(model), limits_rad=limits_rad
    )
    return led_trajectory(trajectory, goals), goals, reasons + moving_ends(trajectory)


def moving_ends(trajectory) -> tuple[str, ...]:
    """A note if the plan starts or ends moving (a servo at rest cannot follow it), with
    the remedy: ``[stream] run_in_s`` (``trajgen.run_in``) plays it from rest."""
    from trajgen.run_in import starts_or_ends_moving

    if not starts_or_ends_moving(trajectory.qd):
        return ()
    speed = np.abs(np.asarray(trajectory.qd)[[0, -1]]).max()
    return (
        f"the plan starts or ends moving (up to {np.degrees(speed):.1f} deg/s) and the "
        "servos start and end at rest: add `[stream] run_in_s = 0.5` to play it from "
        "rest and back (docs/lead.md)",
    )


def live_frames(
    frames,
    config: GimbalConfig,
    lead: str,
    rate_hz: float,
    bounds_rad,
    *,
    speed_rad_s=None,
    model=None,
):
    """Led goals of a live stream (``trajgen follow``), one frame at a time.

    Parameters
    ----------
    frames : iterable of JointFrame
        The live plan's frames.
    config : GimbalConfig
    lead : {"model", "advance", "none"}
    rate_hz : float
    bounds_rad : array_like, shape (n, 2)
        The range every goal stays inside (rad): what bring-up checked against
        the installed limits (the joint limits the live plan may use).
    speed_rad_s : array_like, shape (n,), optional
        The fastest the live plan may move (rad/s), for the lead's cap
        (``trajgen.lead.lead_cap``); default each servo's no-load speed.
    model : mujoco.MjModel, optional
        ``sim.run.simulation_model(config)`` if the caller has built it.

    Returns
    -------
    trajgen.lead.LedFrames
    """
    from trajgen.lead import LedFrames, lead_cap
    from trajgen.sim.run import simulation_model

    model = simulation_model(config) if model is None else model
    params = lead_params(config, model)
    if speed_rad_s is None:
        speed_rad_s = [s.no_load_speed_rad_s for s in config.servos]
    cap = lead_cap(np.asarray(speed_rad_s, dtype=float)[None, :], params)
    torque = torque_function(model) if lead == "model" else None
    return LedFrames(frames, rate_hz, lead, params, bounds_rad, cap, torque=torque)


def sagged_start(trajectory, config: GimbalConfig, model) -> np.ndarray:
    """Where the simulated servos rest before ``trajectory`` is sent (rad, shape (n,)):
    holding its first goal (in whole ticks, as sent) against gravity, at the sagged
    equilibrium :func:`trajgen.lift.sagged` of ``config``'s loops, as a real servo holding
    that goal sits (``drivers.bringup`` starts a stream from the goal held). A joint
    with an I gain rests on its goal (its integral has taken up the load)."""
    from trajgen.lift import sagged, sent_goals
    from trajgen.sim.dynamics import inverse_dynamics
    from trajgen.sim.run import goal_ticks_rad

    held = goal_ticks_rad(sent_goals(trajectory)[1][0])
    kp, ki = [], []
    for j in range(config.n_joints):
        k, i, _, _ = config.loop(j).mujoco_controller(config.servos[j])
        kp.append(k)
        ki.append(i)
    zero = np.zeros((1, config.n_joints))

    def gravity(q):
        return inverse_dynamics(model, q[None, :], zero, zero)[0]

    return np.where(np.asarray(ki) > 0, held, sagged(held, np.asarray(kp), gravity))


class Leader:
    """Led goals for a ``drivers.session.Session`` (the drivers know no MuJoCo).

    Parameters
    ----------
    config : GimbalConfig
        The servos and their loops (the file's [gimbal] tables).
    lead : {"model", "advance", "none"}

    Attributes
    ----------
    notes : list of str
        Why a joint got no lead, for every trajectory led so far.
    """

    def __init__(self, config: GimbalConfig, lead: str) -> None:
        from trajgen.lead import check_lead
        from trajgen.sim.run import simulation_model

        self.config = config
        self.lead = check_lead(lead)
        self.model = simulation_model(config)
        self.notes: list[str] = []

    def trajectory(self, trajectory):
        """``trajectory`` with its led goals attached (:func:`lead_trajectory`)."""
        led, _, notes = lead_trajectory(trajectory, self.config, self.lead, model=self.model)
        self.notes += [n for n in notes if n not in self.notes]
        return led

    def frames(self, frames, rate_hz: float, bounds_rad):
        """A live stream's frames with led goals (:func:`live_frames`)."""
        return live_frames(frames, self.config, self.lead, rate_hz, bounds_rad, model=self.model)
