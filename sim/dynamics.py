"""Inverse dynamics of the gimbal: the torque a planned joint path needs."""

from __future__ import annotations

import copy

import numpy as np

from trajgen.sim.errors import SimulationError

from .errors import BadArgument


def inverse_dynamics(model, q, qd, qdd, *, coulomb: bool = True) -> np.ndarray:
    """Joint torques (N m) that produce ``qdd`` at ``(q, qd)``: MuJoCo's ``mj_inverse``.

    The torque includes the reflected rotor inertia (armature), gravity,
    Coriolis terms, viscous and Coulomb joint friction: everything the motor
    must supply.

    Parameters
    ----------
    model : mujoco.MjModel
        The gimbal (``sim.model.build_model``); dof ``i`` is joint ``i``.
    q, qd, qdd : array_like, shape (N, 3)
        Joint angles (rad), velocities (rad/s), accelerations (rad/s^2).
    coulomb : bool
        Include Coulomb friction (``frictionloss``). Without it the torque is
        smooth wherever the plan is; with it, it steps by twice the friction
        wherever a joint starts or reverses.

    Returns
    -------
    ndarray, shape (N, 3)
        Torque per joint (N m).

    Raises
    ------
    ValueError
        If the inputs are not (N, 3) arrays of finite numbers.
    SimulationError
        If any pose puts two gimbal geoms in contact (the torque would be meaningless).
    """
    return _inverse(model, q, qd, qdd, (coulomb,))[0]


def inverse_dynamics_split(model, q, qd, qdd) -> tuple[np.ndarray, np.ndarray]:
    """:func:`inverse_dynamics` with and without Coulomb friction, in one pass.

    Equal, bit for bit, to ``inverse_dynamics(model, q, qd, qdd)`` and
    ``inverse_dynamics(model, q, qd, qdd, coulomb=False)``; each sample is set
    once for both.

    Returns
    -------
    tau, tau_smooth : ndarray, shape (N, 3)
        Torque per joint (N m) with and without Coulomb friction.

    Raises
    ------
    ValueError, SimulationError
        As :func:`inverse_dynamics`.
    """
    return _inverse(model, q, qd, qdd, (True, False))


def _inverse(model, q, qd, qdd, coulomb: tuple[bool, ...]) -> list[np.ndarray]:
    """``mj_inverse`` at every sample, once per entry of ``coulomb`` (:func:`inverse_dynamics`)."""
    import mujoco

    arrays = []
    for name, value in (("q", q), ("qd", qd), ("qdd", qdd)):
        a = np.asarray(value, dtype=float)
        if a.ndim != 2 or a.shape[1] != model.nv:
            raise BadArgument(f"Expected `{name}` to have shape (N, {model.nv}), got {a.shape}.")
        if not np.all(np.isfinite(a)):
            raise BadArgument(f"Expected `{name}` to be finite, got a NaN or inf.")
        arrays.append(a)
    q, qd, qdd = arrays
    if not q.shape == qd.shape == qdd.shape:
        raise BadArgument(
            f"Expected `q`, `qd`, `qdd` of one shape, got {q.shape}, {qd.shape}, {qdd.shape}."
        )
    models = [model if with_coulomb else _without_coulomb(model) for with_coulomb in coulomb]
    taus = [np.empty_like(q) for _ in models]
    runs = list(zip(models, taus, strict=True))
    data = mujoco.MjData(model)
    # Views and the function bound once, rows iterated: the Python around each
    # mj_inverse call costs about as much as the call.
    qpos, qvel, qacc, qfrc = data.qpos, data.qvel, data.qacc, data.qfrc_inverse
    inverse = mujoco.mj_inverse
    for i, (q_i, qd_i, qdd_i) in enumerate(zip(q, qd, qdd, strict=True)):
        qpos[:] = q_i
        qvel[:] = qd_i
        qacc[:] = qdd_i
        for m, tau in runs:
            inverse(m, data)
            if data.ncon:
                raise SimulationError(
                    f"{data.ncon} contact(s) inside the gimbal at sample {i}, q = {q_i} rad"
                )
            tau[i] = qfrc
    return taus


def _without_coulomb(model):
    """A copy of ``model`` without Coulomb friction (``frictionloss`` 0)."""
    model = copy.copy(model)
    model.dof_frictionloss[:] = 0.0
    return model
