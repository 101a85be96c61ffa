"""The gimbal's dynamics along a fixed path, tabulated for retiming (TOPP form).

Along a path ``q(s)`` played at path speed ``s'`` and acceleration ``s''``
the joint velocity is ``q_s s'``, the acceleration ``q_ss s'^2 + q_s s''``,
and the torque (``mj_inverse``; Coriolis terms are quadratic in the velocity)

    ``tau = A(s) s'' + B(s) s'^2 + C(s) + D(s) s' + F(s)``

with ``A = M(q) q_s``, ``B = M(q) q_ss + c(q, q_s)``, ``C`` gravity, ``D``
viscous damping ``d q_s`` and ``F`` Coulomb friction ``f sign(q_s)`` (``s' > 0``).
:func:`path_dynamics` tabulates ``A, B, C, D, q_s, q_ss`` per joint on a grid of
path time and interpolates them with cubic splines (scipy), whose first and
second derivatives in ``s`` give the torque rate and the optimiser's gradients.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .errors import SimError

#: Table columns per joint, in order.
COLUMNS = ("A", "B", "C", "D", "qs", "qss")
#: Table points per path segment.
POINTS_PER_SEGMENT = 48


@dataclass(frozen=True)
class PathDynamics:
    """The tables of :func:`path_dynamics`.

    Attributes
    ----------
    path : OrientationPath
        The path in its own time.
    s_keys : ndarray, shape (N,)
        Path times of the keyframes, from 0 (s of path time).
    table : scipy.interpolate.CubicSpline
        ``table(s, nu)`` -> (M, 6, n): ``COLUMNS`` x joints, or their ``nu``-th
        derivative in ``s``, at path times ``s`` (M,) from 0.
    friction, budget, slope : ndarray, shape (n,)
        Coulomb friction (N m), torque budget ``torque_margin x stall`` (N m) and
        the envelope's slope ``budget / no-load speed`` (N m s/rad).
    """

    path: object
    s_keys: np.ndarray
    table: object
    friction: np.ndarray
    budget: np.ndarray
    slope: np.ndarray

    @property
    def s_span(self) -> float:
        return float(self.s_keys[-1])

    def segment(self, s: np.ndarray) -> np.ndarray:
        """Segment index (M,) of path times ``s`` (M,) from 0."""
        return np.clip(np.searchsorted(self.s_keys, s, side="right") - 1, 0, len(self.s_keys) - 2)


def joint_path(path, s: np.ndarray, kinematics=None):
    """Joint angles, ``q_s`` and ``q_ss`` (M, n each) of ``path`` at its own times ``s`` (M,),
    through ``kinematics`` (the gimbal's ``GimbalKinematics``; default pan-tilt-roll).

    Raises
    ------
    SimError
        If the path nears gimbal lock or leaves a joint limit.
    """
    from trajgen.gimbal import GimbalKinematics, KinematicsError

    kinematics = GimbalKinematics() if kinematics is None else kinematics
    samples = path.evaluate(s, max_order=2)
    try:
        q = kinematics.inverse(samples.q, s)
    except KinematicsError as e:
        raise SimError(f"no timing can help: the path {e}") from e
    qs, qss = kinematics.joint_rates(q, samples.omega, samples.alpha)
    return q, qs, qss


def path_dynamics(path, model, config, points_per_segment: int = POINTS_PER_SEGMENT):
    """Tabulate the torque's TOPP coefficients along ``path`` (see the module docstring).

    Parameters
    ----------
    path : OrientationPath
        The path in its own time (``t_start`` .. ``t_end``, keyframes at ``times``).
    model : mujoco.MjModel
        The gimbal (``sim.run.simulation_model(config)``).
    config : GimbalConfig
    points_per_segment : int
        Table points per segment (uniform in each segment's path time).

    Returns
    -------
    PathDynamics

    Raises
    ------
    SimError
        If the path nears gimbal lock or leaves a joint limit.
    """
    from scipy.interpolate import CubicSpline

    from .dynamics import inverse_dynamics

    keys = np.asarray(path.times, dtype=float)
    u = np.arange(points_per_segment) / points_per_segment
    s = np.append((keys[:-1, None] + np.outer(np.diff(keys), u)).ravel(), keys[-1])
    q, qs, qss = joint_path(path, s, config.kinematics())
    bare = copy.copy(model)
    bare.dof_damping[:] = 0.0
    zero = np.zeros_like(q)
    c = inverse_dynamics(bare, q, zero, zero, coulomb=False)
    a = inverse_dynamics(bare, q, zero, qs, coulomb=False) - c
    b = inverse_dynamics(bare, q, qs, qss, coulomb=False) - c
    d = np.asarray(model.dof_damping) * qs
    columns = np.stack([a, b, c, d, qs, qss], axis=1)  # (M, 6, n)
    stall = np.array([sv.stall_torque_nm for sv in config.servos])
    w0 = np.array([sv.no_load_speed_rad_s for sv in config.servos])
    budget = config.torque_margin * stall
    return PathDynamics(
        path=path,
        s_keys=keys - keys[0],
        table=CubicSpline(s - keys[0], columns, axis=0),
        friction=np.array(model.dof_frictionloss),
        budget=budget,
        slope=budget / w0,
    )
