"""Inverse dynamics of the gimbal: the torque a planned joint path needs."""

from __future__ import annotations

import copy
import threading
import weakref
from dataclasses import dataclass, field

import numpy as np

from trajgen.path import run_steps
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

    q, qd, qdd = _states(model.nv, q, qd, qdd)
    data, smooth = _scratch(model)
    models = [model if with_coulomb else smooth for with_coulomb in coulomb]
    taus = [np.empty_like(q) for _ in models]
    runs = list(zip(models, taus, strict=True))
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


#: Per model: its MjData and its copy without Coulomb friction, built once (389 us and
#: 204 us), not per call: the model lead evaluates a frame at a time. Each thread has its
#: own (an MjData is scratch space); a model changed in place after a call is not seen.
_SCRATCH = threading.local()


def _scratch(model):
    """``(MjData, model without Coulomb friction)`` for ``model``, cached (this thread)."""
    import mujoco

    cache = getattr(_SCRATCH, "by_model", None)
    if cache is None:
        cache = _SCRATCH.by_model = weakref.WeakKeyDictionary()
    entry = cache.get(model)
    if entry is None:
        entry = cache[model] = (mujoco.MjData(model), _without_coulomb(model))
    return entry


def _states(nv: int, q, qd, qdd) -> list[np.ndarray]:
    """``q, qd, qdd`` as float arrays (N, nv), checked (:func:`inverse_dynamics`)."""
    arrays = []
    for name, value in (("q", q), ("qd", qd), ("qdd", qdd)):
        a = np.asarray(value, dtype=float)
        if a.ndim != 2 or a.shape[1] != nv:
            raise BadArgument(f"Expected `{name}` to have shape (N, {nv}), got {a.shape}.")
        if not np.all(np.isfinite(a)):
            raise BadArgument(f"Expected `{name}` to be finite, got a NaN or inf.")
        arrays.append(a)
    if not arrays[0].shape == arrays[1].shape == arrays[2].shape:
        shapes = ", ".join(str(a.shape) for a in arrays)
        raise BadArgument(f"Expected `q`, `qd`, `qdd` of one shape, got {shapes}.")
    return arrays


def _without_coulomb(model):
    """A copy of ``model`` without Coulomb friction (``frictionloss`` 0)."""
    model = copy.copy(model)
    model.dof_frictionloss[:] = 0.0
    return model


class ChainDynamics:
    """Inverse dynamics of a gimbal's hinge chain in numpy, every sample at once.

    The recursive Newton-Euler algorithm in each body's own frame (constant inertia,
    centre of mass and joint axis there), vectorised over the samples: equal to
    ``inverse_dynamics(model, q, qd, qdd, coulomb=False)`` to rounding (rigid bodies,
    gravity, armature, joint springs and dampers; tested against ``mj_inverse``), at
    about a tenth of its cost for a few hundred samples. MuJoCo's Coulomb friction (a
    ``frictionloss`` constraint) adds to each joint a torque of magnitude at most its
    ``frictionloss`` (:attr:`friction`), so ``|smooth(...)| + friction`` bounds
    ``|inverse_dynamics(...)|`` to rounding (:attr:`ROUNDING_NM`).

    Parameters
    ----------
    model : mujoco.MjModel
        A tree of bodies, each with at most one hinge joint (the gimbal of
        ``sim.model.build_model``), without joint limits, tendons, equality
        constraints, fluid forces or gravity compensation.

    Raises
    ------
    SimulationError
        If the model has any of those (``mj_inverse`` would include them).
    """

    #: Bound (N m) on ``|smooth(...) - inverse_dynamics(..., coulomb=False)|`` per unit of
    #: ``1 + |qd|^2 + |qdd|`` (the sample's sums over joints): the two evaluate the same
    #: terms in another order (measured: below 1e-15 N m per unit on the gimbals here).
    ROUNDING_NM = 1e-9

    def __init__(self, model):
        import mujoco

        off, on = mujoco.mjtDisableBit, mujoco.mjtEnableBit
        flags = model.opt.disableflags
        unsupported = [
            name
            for name, bad in (
                (
                    "a joint that is not a hinge",
                    (model.jnt_type != mujoco.mjtJoint.mjJNT_HINGE).any(),
                ),
                ("a body with two joints", (model.body_jntnum > 1).any()),
                ("joint limits", model.jnt_limited.any() and not flags & off.mjDSBL_LIMIT),
                ("tendons", model.ntendon > 0),
                ("equality constraints", model.neq > 0),
                ("fluid forces", model.opt.density > 0 or model.opt.viscosity > 0),
                ("gravity compensation", model.body_gravcomp.any()),
                ("discrete-time inverse dynamics", model.opt.enableflags & on.mjENBL_INVDISCRETE),
            )
            if bad
        ]
        if unsupported:
            raise SimulationError(
                "ChainDynamics takes a tree of hinge joints only; the model has "
                + ", ".join(unsupported)
            )
        gravity = np.zeros(3) if flags & off.mjDSBL_GRAVITY else np.array(model.opt.gravity)
        self._base_acc = -gravity[:, None]  # the world's acceleration that stands for gravity
        self._bodies = []
        moving, ref = [False] * model.nbody, [np.zeros(3)] * model.nbody
        for b in range(1, model.nbody):
            p = int(model.body_parentid[b])
            joint = int(model.body_jntadr[b]) if model.body_jntnum[b] else -1
            moving[b] = moving[p] or joint >= 0
            anchor = np.array(model.jnt_pos[joint]) if joint >= 0 else np.zeros(3)
            ref[b] = anchor  # the body's reference point, in its own frame
            if not moving[b]:
                continue  # fixed to the world: it puts no torque on any joint
            frame = _matrix(model.body_quat[b])  # None below where it is the identity
            principal = _matrix(model.body_iquat[b])
            self._bodies.append(
                _Body(
                    index=b,
                    parent=p if moving[p] else 0,
                    dof=int(model.jnt_dofadr[joint]) if joint >= 0 else -1,
                    qpos0=float(model.qpos0[model.jnt_qposadr[joint]]) if joint >= 0 else 0.0,
                    axis=np.array(model.jnt_axis[joint]) if joint >= 0 else np.zeros(3),
                    frame=None if (frame == np.eye(3)).all() else frame,
                    r=np.array(model.body_pos[b]) + frame @ anchor - ref[p],
                    com=np.array(model.body_ipos[b]) - anchor,
                    mass=float(model.body_mass[b]),
                    inertia=principal @ np.diag(model.body_inertia[b]) @ principal.T,
                )
            )
        self.nv = int(model.nv)
        self._armature = np.array(model.dof_armature)
        self._damping = np.zeros(self.nv)
        if not flags & off.mjDSBL_DAMPER:
            self._damping = np.array(model.dof_damping)
        self._stiffness, self._spring = np.zeros(self.nv), np.zeros(self.nv)
        if not flags & off.mjDSBL_SPRING:
            dofs, adrs = model.jnt_dofadr, model.jnt_qposadr
            self._stiffness[dofs] = model.jnt_stiffness
            self._spring[dofs] = model.qpos_spring[adrs]
        no_friction = flags & (off.mjDSBL_FRICTIONLOSS | off.mjDSBL_CONSTRAINT)
        #: Coulomb friction per joint (N m): the bound on the torque it adds.
        self.friction = np.zeros(self.nv) if no_friction else np.array(model.dof_frictionloss)

    def smooth(self, q, qd, qdd) -> np.ndarray:
        """Joint torques (N, nv) (N m) without Coulomb friction at joint angles,
        velocities and accelerations ``q, qd, qdd`` (N, nv) (rad, rad/s, rad/s^2)."""
        return run_steps(self.smooth_steps(q, qd, qdd))

    def smooth_steps(self, q, qd, qdd):
        """:meth:`smooth` as a generator of steps (two a body out along the chain, one
        back), for a caller that runs the work between frames of a stream; its value
        is the torques.

        Raises
        ------
        ValueError
            As :func:`inverse_dynamics`.
        """
        q, qd, qdd = _states(self.nv, q, qd, qdd)
        qt, qdt, qddt = q.T, qd.T, qdd.T  # (nv, N): each body's vectors are (3, N)
        # per body: angular velocity, acceleration, acceleration of its reference point,
        # in its own frame (w and alpha None: zero, the world's)
        state = {0: (None, None, self._base_acc)}
        parts = []
        for body in self._bodies:
            w, al, acc = state[body.parent]
            turn = gyro = None
            if body.dof >= 0:
                angle = qt[body.dof] - body.qpos0
                turn = (body, np.cos(angle), np.sin(angle))
            if w is None:  # the parent is the world
                acc = _into(body, turn, acc[:, None])[:, 0]
            else:  # the parent's motion at this body's reference point, in its frame
                acc = acc - body.r_x @ al + _centripetal(w, body.r)
                w, al, acc = _into(body, turn, np.stack([w, al, acc], axis=1)).transpose(1, 0, 2)
            yield
            if body.dof >= 0:
                spin, rate = body.axis[:, None] * qdt[body.dof], qdt[body.dof]
                if w is None:
                    w, al = spin, body.axis[:, None] * qddt[body.dof]
                    gyro = np.outer(body.gyro, rate * rate)  # w x (I w), w along the axis
                else:  # alpha + axis qdd + w x (axis qd)
                    al = al + body.axis[:, None] * qddt[body.dof] - (body.axis_x @ w) * rate
                    w = w + spin
            if gyro is None:
                gyro = _cross(w, body.inertia @ w)
            state[body.index] = (w, al, acc)
            force = body.mass * (acc - body.com_x @ al + _centripetal(w, body.com))
            moment = body.inertia @ al + gyro + body.com_x @ force  # about the reference point
            parts.append((body, turn, force, moment))
            yield
        tau = np.empty((self.nv, len(q)))
        wrench: dict = {}
        for i, (body, turn, force, moment) in enumerate(reversed(parts)):
            if i:
                yield
            for f, m in wrench.pop(body.index, ()):
                force, moment = force + f, moment + m
            if body.dof >= 0:
                tau[body.dof] = body.axis @ moment
            force, moment = _out_of(body, turn, np.stack([force, moment], axis=1)).transpose(
                1, 0, 2
            )
            wrench.setdefault(body.parent, []).append((force, moment + body.r_x @ force))
        return (
            tau.T + self._armature * qdd + self._damping * qd + self._stiffness * (q - self._spring)
        )


@dataclass(frozen=True)
class _Body:
    """A moving body of :class:`ChainDynamics`, in its own frame: ``frame`` its rotation
    from the parent's before the joint turns it about ``axis`` (3,); ``r`` (m) from the
    parent's reference point to its own (the joint's anchor, else its origin), in the
    parent's frame; ``com`` (m) from its reference point; ``inertia`` (kg m^2) about
    the centre of mass; ``dof`` -1 for a body welded to its parent."""

    index: int
    parent: int
    dof: int
    qpos0: float
    axis: np.ndarray
    frame: np.ndarray | None
    r: np.ndarray
    com: np.ndarray
    mass: float
    inertia: np.ndarray
    r_x: np.ndarray = field(init=False)  # the matrices of r x, com x, axis x
    com_x: np.ndarray = field(init=False)
    axis_x: np.ndarray = field(init=False)
    gyro: np.ndarray = field(init=False)  # axis x (inertia axis)

    def __post_init__(self):
        for name in ("r", "com", "axis"):
            object.__setattr__(self, name + "_x", _skew(getattr(self, name)))
        object.__setattr__(self, "gyro", np.cross(self.axis, self.inertia @ self.axis))


def _matrix(quat) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (w, x, y, z)."""
    w, x, y, z = quat
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _skew(v) -> np.ndarray:
    """The matrix (3, 3) of ``u -> v x u``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _centripetal(w, r) -> np.ndarray:
    """``w x (w x r)`` (3, N) for angular velocities ``w`` (3, N) and a vector ``r`` (3,)."""
    return w * (r @ w) - np.outer(r, (w * w).sum(axis=0))


def _into(body, turn, v) -> np.ndarray:
    """Vectors ``v`` (3, M, N) of the parent's frame in ``body``'s:
    ``Rot(axis, angle)^T frame^T v``; ``turn`` is ``(body, cos, sin)`` of the joint's
    angle (each (N,)), None for a body without a joint."""
    u = v if body.frame is None else _mat(body.frame.T, v)
    if turn is None:
        return u
    _, c, s = turn
    return u * c - _mat(body.axis_x, u) * s + _along(body.axis, u, 1.0 - c)


def _out_of(body, turn, v) -> np.ndarray:
    """:func:`_into` inverted: vectors (3, M, N) of ``body``'s frame in its parent's."""
    if turn is not None:
        _, c, s = turn
        v = v * c + _mat(body.axis_x, v) * s + _along(body.axis, v, 1.0 - c)
    return v if body.frame is None else _mat(body.frame, v)


def _mat(m, v) -> np.ndarray:
    """A matrix (3, 3) times vectors (3, M, N)."""
    return (m @ v.reshape(3, -1)).reshape(v.shape)


def _along(k, u, scale) -> np.ndarray:
    """``k (k . u) scale``: the parts (3, M, N) of vectors ``u`` along the unit ``k`` (3,)."""
    return k[:, None, None] * ((k @ u.reshape(3, -1)).reshape(u.shape[1:]) * scale)


def _cross(a, b):
    """Cross products of vectors (3, N)."""
    return np.stack(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )
