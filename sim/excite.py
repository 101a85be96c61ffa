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
limit-checked and streamed like any keyframe file's path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from trajgen import quat
from trajgen.gimbal import jacobian
from trajgen.path import Samples

from .errors import BadArgument

#: Frequency band (Hz) of the excitation.
BAND_HZ = (0.3, 2.0)
#: Sines per joint.
N_SINES = 5
#: Default amplitude (rad) per joint: pan, tilt, roll.
DEFAULT_AMPLITUDE_RAD = (math.radians(25.0), math.radians(15.0), math.radians(20.0))


@dataclass(frozen=True)
class Multisine:
    """A rest-to-rest multi-sine joint motion, as an orientation path.

    Parameters
    ----------
    center_rad : array_like, shape (3,)
        Centre pose ``(pan, tilt, roll)`` (rad): where the motion starts and ends.
    seconds : float
        Duration (s), >= 3 (two 1 s ramps and at least 1 s between them).
    amplitude_rad : array_like, shape (3,)
        Largest excursion from the centre per joint (rad), >= 0.
    ramp_s : float
        Fade-in and fade-out time (s).

    Raises
    ------
    ValueError
        If a shape or value is out of range.
    """

    center_rad: tuple = (0.0, 0.0, 0.0)
    seconds: float = 8.0
    amplitude_rad: tuple = DEFAULT_AMPLITUDE_RAD
    ramp_s: float = 1.0
    _norm: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        for name in ("center_rad", "amplitude_rad"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise BadArgument(f"Expected `{name}` to be 3 finite numbers, got {value!r}.")
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
        """The sines' frequencies (Hz), shape (3, N_SINES): each joint its own."""
        low, high = BAND_HZ
        base = np.geomspace(low, high / 1.17, N_SINES)
        return base[None, :] * np.array([1.0, 1.08, 1.17])[:, None]

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
        """The unscaled, windowed sum of sines and its derivatives, each (M, 3)."""
        f = self.frequencies_hz  # (3, K)
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
        tuple of 3 ndarray, each shape (M, 3)

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
        gimbal's Jacobian (``trajgen.gimbal.jacobian``).

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
        orientation = quat.from_pan_tilt_roll(q[:, 0], q[:, 1], q[:, 2])
        if max_order < 1:
            return Samples(t, orientation, None, None, None)
        jac = jacobian(q)
        omega = np.einsum("mij,mj->mi", jac, qd)
        if max_order < 2:
            return Samples(t, orientation, omega, None, None)
        # dJ/dt qd: the tilt axis (-sin p, cos p, 0) turns with pan, the roll axis
        # (cos p cos t, sin p cos t, -sin t) with pan and tilt.
        cp, sp = np.cos(q[:, 0]), np.sin(q[:, 0])
        ct, st = np.cos(q[:, 1]), np.sin(q[:, 1])
        vp, vt, vr = qd.T
        zero = np.zeros_like(cp)
        d_tilt_axis = vp[:, None] * np.stack([-cp, -sp, zero], axis=1)
        d_roll_axis = vp[:, None] * np.stack([-sp * ct, cp * ct, zero], axis=1) + vt[
            :, None
        ] * np.stack([-cp * st, -sp * st, -ct], axis=1)
        alpha = np.einsum("mij,mj->mi", jac, qdd) + vt[:, None] * d_tilt_axis
        alpha += vr[:, None] * d_roll_axis
        return Samples(t, orientation, omega, alpha, None)
