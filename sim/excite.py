"""A multi-sine excitation of the gimbal, for identifying it from its own telemetry.

Each joint follows a sum of sines between about 0.3 and 2 Hz (its own
frequencies, so the joints' responses can be told apart; Schroeder phases, so
the peaks stay low), faded in and out by a quintic ramp so the motion starts
and ends at rest, about a centre pose:

    q_j(t) = c_j + A_j w(t) sum_k sin(2 pi f_jk t + phi_k) / f_jk / norm_j

Equal velocity amplitude per component (the ``1 / f`` weights) exercises the
armature (acceleration, at the high frequencies), the damping (speed), the
Coulomb friction (every reversal) and the P gain (the lag) together. A log of
a slow keyframe motion alone does not separate them.

:class:`Multisine` is an orientation path (the spline protocol:
``t_start``, ``t_end``, ``evaluate(t, max_order)``), so it is planned,
limit-checked and streamed like any keyframe file's path. It moves the joints of
any gimbal (``kinematics``: 2 or 3 axes in any order, :mod:`trajgen.axes`); a
two-axis gimbal's orientation path is the one it has at those angles, so its
inverse kinematics gives the joints back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from trajgen.gimbal import GimbalKinematics
from trajgen.path import Samples

from .errors import BadArgument

#: Frequency band (Hz) of the excitation.
BAND_HZ = (0.3, 2.0)
#: Sines per joint.
N_SINES = 5
#: Default amplitude (rad) per joint: pan, tilt, roll (the first, middle and last joint
#: of any sequence; a two-axis gimbal takes the first two).
DEFAULT_AMPLITUDE_RAD = (math.radians(25.0), math.radians(15.0), math.radians(20.0))
#: Each joint's frequencies are the base band's times these (joints in order).
JOINT_FREQUENCY_FACTORS = (1.0, 1.08, 1.17)


def default_amplitude_rad(n_joints: int) -> tuple[float, ...]:
    """:data:`DEFAULT_AMPLITUDE_RAD` for a gimbal of ``n_joints`` (2 or 3) joints (rad)."""
    return DEFAULT_AMPLITUDE_RAD[:n_joints]


@dataclass(frozen=True)
class Multisine:
    """A rest-to-rest multi-sine joint motion, as an orientation path.

    Parameters
    ----------
    center_rad : array_like, shape (n,)
        Centre pose (rad), ``(pan, tilt, roll)`` by default: where the motion starts
        and ends.
    seconds : float
        Duration (s), >= 3 (two 1 s ramps and at least 1 s between them).
    amplitude_rad : array_like, shape (n,)
        Largest excursion from the centre per joint (rad), >= 0; default
        :func:`default_amplitude_rad`.
    ramp_s : float
        Fade-in and fade-out time (s).
    kinematics : GimbalKinematics, optional
        The gimbal's axes (``n`` joints, 2 or 3); default pan-tilt-roll.

    Raises
    ------
    ValueError
        If a shape or value is out of range.
    """

    center_rad: tuple = (0.0, 0.0, 0.0)
    seconds: float = 8.0
    amplitude_rad: tuple | None = None
    ramp_s: float = 1.0
    kinematics: GimbalKinematics = field(default_factory=GimbalKinematics)
    _norm: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        n = self.kinematics.n_joints
        if self.amplitude_rad is None:
            object.__setattr__(self, "amplitude_rad", default_amplitude_rad(n))
        for name in ("center_rad", "amplitude_rad"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (n,) or not np.all(np.isfinite(value)):
                raise BadArgument(f"Expected `{name}` to be {n} finite numbers, got {value!r}.")
            object.__setattr__(self, name, tuple(float(v) for v in value))
        if min(self.amplitude_rad) < 0:
            raise BadArgument(f"Expected `amplitude_rad` >= 0, got {self.amplitude_rad}.")
        if not self.ramp_s > 0:
            raise BadArgument(f"Expected `ramp_s` > 0, got {self.ramp_s!r}.")
        if not self.seconds >= 2 * self.ramp_s + 1.0:
            raise BadArgument(
                f"Expected `seconds` >= {2 * self.ramp_s + 1.0:g} (two ramps and 1 s), "
                f"got {self.seconds!r}."
            )
        # Scale each joint so its largest excursion on a fine grid is its amplitude.
        t = np.linspace(0.0, self.seconds, int(self.seconds * 1000) + 1)
        q, _, _ = self._unit(t)
        object.__setattr__(self, "_norm", np.abs(q).max(axis=0))

    @property
    def t_start(self) -> float:
        """Start time (s): 0."""
        return 0.0

    @property
    def t_end(self) -> float:
        """End time (s): ``seconds``."""
        return float(self.seconds)

    @property
    def frequencies_hz(self) -> np.ndarray:
        """The sines' frequencies (Hz), shape (n, N_SINES): each joint its own."""
        low, high = BAND_HZ
        base = np.geomspace(low, high / max(JOINT_FREQUENCY_FACTORS), N_SINES)
        factors = np.array(JOINT_FREQUENCY_FACTORS[: self.kinematics.n_joints])
        return base[None, :] * factors[:, None]

    def _window(self, t):
        """Quintic fade in and out, ``w``, ``w'``, ``w''``, each shape (M,)."""
        r = self.ramp_s
        x = np.clip(np.minimum(t, self.seconds - t) / r, 0.0, 1.0)
        sign = np.where(t < self.seconds / 2, 1.0, -1.0) * ((x > 0) & (x < 1))
        w = x**3 * (10 - 15 * x + 6 * x**2)
        dw = sign * 30 * x**2 * (1 - x) ** 2 / r
        ddw = ((x > 0) & (x < 1)) * 60 * x * (1 - x) * (1 - 2 * x) / r**2
        return w, dw, ddw

    def _unit(self, t):
        """The unscaled, windowed sum of sines and its derivatives, each (M, n)."""
        f = self.frequencies_hz  # (n, K)
        k = np.arange(N_SINES)
        phase = -math.pi * k * (k - 1) / N_SINES  # Schroeder
        omega = 2 * math.pi * f
        arg = t[:, None, None] * omega[None] + phase[None, None, :]
        s = (np.sin(arg) / f).sum(axis=2)
        ds = (np.cos(arg) * omega / f).sum(axis=2)
        dds = (-np.sin(arg) * omega**2 / f).sum(axis=2)
        w, dw, ddw = (v[:, None] for v in self._window(t))
        return w * s, dw * s + w * ds, ddw * s + 2 * dw * ds + w * dds

    def joints(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint angles (rad), velocities (rad/s), accelerations (rad/s^2) at ``t``.

        Parameters
        ----------
        t : array_like, shape (M,)
            Times (s) in ``[0, seconds]``.

        Returns
        -------
        tuple of 3 ndarray, each shape (M, n)

        Raises
        ------
        ValueError
            If a time is outside ``[0, seconds]``.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if np.any((t < 0) | (t > self.seconds)) or not np.all(np.isfinite(t)):
            raise BadArgument(f"Expected times in [0, {self.seconds:g}] s.")
        scale = np.asarray(self.amplitude_rad) / self._norm
        q, qd, qdd = self._unit(t)
        return np.asarray(self.center_rad) + scale * q, scale * qd, scale * qdd

    def evaluate(self, t, max_order: int = 2) -> Samples:
        """Orientation and its space-frame rates at ``t`` (the spline protocol).

        ``omega = J(q) qd`` and ``alpha = J(q) qdd + (dJ/dt) qd`` with the
        gimbal's Jacobian (its space-frame joint axes ``e_j``): each axis turns with
        the joints before it, ``de_j/dt = (sum_{i<j} qd_i e_i) x e_j``.

        Parameters
        ----------
        t : array_like, shape (M,)
            Times (s) in ``[0, seconds]``.
        max_order : int
            0, 1 or 2: which of ``omega``, ``alpha`` to compute (jerk is None).

        Returns
        -------
        trajgen.path.Samples
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        q, qd, qdd = self.joints(t)
        orientation = self.kinematics.forward(q)
        if max_order < 1:
            return Samples(t, orientation, None, None, None)
        axes = self.kinematics.jacobian(q)  # (M, 3, n)
        omega = np.einsum("mij,mj->mi", axes, qd)
        if max_order < 2:
            return Samples(t, orientation, omega, None, None)
        alpha = np.einsum("mij,mj->mi", axes, qdd)
        carried = np.zeros_like(omega)  # angular velocity of the joints before j
        for j in range(axes.shape[-1]):
            alpha += qd[:, j, None] * np.cross(carried, axes[..., j])
            carried += qd[:, j, None] * axes[..., j]
        return Samples(t, orientation, omega, alpha, None)
