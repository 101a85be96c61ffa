"""The X-series firmware's position loop, in register units and as MuJoCo gains.

From the e-Manual's control-table pages (Position PID Gain, PWM Limit, Goal
PWM, Profile Velocity): with Profile Velocity 0 a Dynamixel X-series servo in
Position or Extended Position Mode drives

    PWM = clip(KP e + KI sum(e) + KD (e - e_prev), +-min(PWM Limit, Goal PWM))

with ``e`` the position error in pulses (4096 per turn), ``KP = P / 128``,
``KI = I / 65536``, ``KD = D / 16`` and PWM 885 = 100 % of the supply. The
feed-forward gains act on the profile only, so with no profile they do nothing.
The motor is a DC motor, ``tau = (K / R)(V - K w)``: the drive does not
compensate back-EMF, so the servo lags a moving goal by about
``speed x (K^2 / R) / kp`` (45 ms for an XM430-W350 with P = 800).

MuJoCo's ``<dcmotor input="pos" controller="kp ki kd 0 0 Vmax">`` drives
``v = clip((R / K)(kp e - kd w + ki x_I) + K w, +-Vmax)``; with ``kp`` and ``ki``
the loop's gains in torque space and ``kd = K^2 / R`` plus the D term, that is
the same voltage as the firmware's (the back-EMF terms cancel), so the native
actuator is the firmware loop without tick rounding.

Stated assumptions:

- The P divisor is the e-Manual's 128; BAM (Rhoban's actuator models)
  measured 256 on an XL330, so it is a parameter (``p_divisor``).
- The firmware's loop period is not published ("much faster than 1 kHz"); the
  I and D terms depend on it (``loop_period_s``, default 1 ms, an estimate).
  D acts on the measured speed (derivative of the error between goal steps).
  The XM430-W350's defaults, I = D = 0, do not depend on it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from trajgen.servo_table import (
    D_DIVISOR,
    DEFAULT_SERVO,
    EXTENDED_POSITION_MODE,
    GAIN_MAX,
    I_DIVISOR,
    P_DIVISOR,
    POSITION_MODE,
    PWM_FULL_SCALE,
    TICKS_PER_REV,
    servo_spec,
)
from trajgen.sim.errors import SimError
from trajgen.sim.servos import ServoModel
from trajgen.validate import check_number

PULSES_PER_RAD = TICKS_PER_REV / (2.0 * math.pi)
LOOP_PERIOD_S = 1e-3

#: Operating modes whose loop this module models: Position (3), Extended Position (4).
POSITION_MODES = (POSITION_MODE, EXTENDED_POSITION_MODE)

#: The loop of a servo whose registers are not given: the default model's factory values.
_FACTORY = servo_spec(DEFAULT_SERVO).defaults


class UnsupportedServoSetting(SimError):
    """A servo register asks for behaviour the simulated servo does not model."""


@dataclass(frozen=True)
class PositionLoop:
    """One servo's position loop in register units.

    Attributes
    ----------
    p_gain, i_gain, d_gain : int
        Position P / I / D Gain registers (84 / 82 / 80), 0..16383.
    pwm_limit, goal_pwm : int
        PWM Limit (36) and Goal PWM (100), 0..885; the drive is capped at the
        smaller one.
    p_divisor : float
        ``KP = p_gain / p_divisor``; 128 in the e-Manual.
    loop_period_s : float
        The firmware's loop period (s), for the I and D terms (an estimate).
    """

    p_gain: int = _FACTORY["Position P Gain"]
    i_gain: int = _FACTORY["Position I Gain"]
    d_gain: int = _FACTORY["Position D Gain"]
    pwm_limit: int = PWM_FULL_SCALE
    goal_pwm: int = PWM_FULL_SCALE
    p_divisor: float = P_DIVISOR
    loop_period_s: float = LOOP_PERIOD_S

    def __post_init__(self):
        for name in ("p_gain", "i_gain", "d_gain"):
            check_register(name, getattr(self, name), 0, GAIN_MAX)
        for name in ("pwm_limit", "goal_pwm"):
            check_register(name, getattr(self, name), 0, PWM_FULL_SCALE)
        for name in ("p_divisor", "loop_period_s"):
            check_number(name, getattr(self, name), low=0.0, low_open=True)

    @property
    def pwm_cap(self) -> int:
        """The drive's cap (PWM units): ``min(PWM Limit, Goal PWM)``."""
        return min(self.pwm_limit, self.goal_pwm)

    def pwm(self, error_pulses, error_sum_pulses=0.0, error_change_pulses=0.0):
        """The drive output (PWM units, +-885 = +-100 % of the supply) for one loop cycle.

        Parameters
        ----------
        error_pulses : float or ndarray
            Goal minus present position (pulses).
        error_sum_pulses : float or ndarray
            Sum of the errors of all cycles so far (pulses).
        error_change_pulses : float or ndarray
            Error minus the previous cycle's error (pulses).

        Returns
        -------
        float or ndarray
            ``clip(KP e + KI sum(e) + KD de, +-pwm_cap)``.
        """
        raw = (
            self.p_gain / self.p_divisor * np.asarray(error_pulses, dtype=float)
            + self.i_gain / I_DIVISOR * np.asarray(error_sum_pulses, dtype=float)
            + self.d_gain / D_DIVISOR * np.asarray(error_change_pulses, dtype=float)
        )
        return np.clip(raw, -self.pwm_cap, self.pwm_cap)

    def mujoco_controller(self, servo: ServoModel) -> tuple[float, float, float, float]:
        """``(kp, ki, kd, vmax)`` of the ``<dcmotor>`` controller that is this loop.

        ``kp`` (N m/rad), ``ki`` (N m/(rad s)) and the D part of ``kd`` are the
        loop's gains in torque space (volts per rad times ``K / R``); ``kd``
        (N m s/rad) adds the back-EMF ``K^2 / R`` the drive leaves
        uncompensated; ``vmax`` (V) is the PWM cap.

        Parameters
        ----------
        servo : ServoModel
            The motor (``K / R = stall torque / rated voltage``, ``K^2 / R = stall / w0``).
        """
        volts_per_pulse = servo.voltage_v / PWM_FULL_SCALE * PULSES_PER_RAD
        k_over_r = servo.stall_torque_nm / servo.voltage_v
        per_rad = volts_per_pulse * k_over_r  # N m per rad per unit of PWM gain
        kp = self.p_gain / self.p_divisor * per_rad
        ki = self.i_gain / I_DIVISOR / self.loop_period_s * per_rad
        kd_loop = self.d_gain / D_DIVISOR * self.loop_period_s * per_rad
        back_emf = servo.stall_torque_nm / servo.no_load_speed_rad_s
        vmax = servo.voltage_v * self.pwm_cap / PWM_FULL_SCALE
        return kp, ki, back_emf + kd_loop, vmax


def check_register(name: str, value, low: int, high: int) -> None:
    """Raise TypeError / ValueError unless ``value`` is an int in ``low..high``."""
    check_number(name, value, low=low, high=high, integer=True)


def loop_from_registers(
    registers: Mapping[str, int], *, p_divisor: float = P_DIVISOR, joint: str = "servo"
) -> PositionLoop:
    """The position loop a servo's control-table registers describe.

    Parameters
    ----------
    registers : mapping of str to int
        Register values keyed by the SDK's control-table names
        (``CONTROL_REGISTERS``); missing ones take the default servo's (XM430-W350) factory values.
    p_divisor : float
        See :class:`PositionLoop`.
    joint : str
        Named in error messages.

    Returns
    -------
    PositionLoop

    Raises
    ------
    UnsupportedServoSetting
        If Profile Velocity or Profile Acceleration is non-zero (a profile
        rate-limits streamed goals; it is not simulated, and the streamer
        writes 0), or the Operating Mode is not 3 or 4.
    TypeError, ValueError
        If a gain or PWM register is not an int in range.
    """
    mode = registers.get("Operating Mode", POSITION_MODE)
    if mode not in POSITION_MODES:
        raise UnsupportedServoSetting(
            f"{joint}: Operating Mode {mode} is not simulated (only 3 position and "
            "4 extended position)"
        )
    for name in ("Profile Velocity", "Profile Acceleration"):
        if registers.get(name, 0):
            raise UnsupportedServoSetting(
                f"{joint}: {name} {registers[name]} is not simulated: the simulated servo "
                "steps to each goal (profile 0, as the streamer configures it)"
            )
    return PositionLoop(
        p_gain=registers.get("Position P Gain", _FACTORY["Position P Gain"]),
        i_gain=registers.get("Position I Gain", _FACTORY["Position I Gain"]),
        d_gain=registers.get("Position D Gain", _FACTORY["Position D Gain"]),
        pwm_limit=registers.get("PWM Limit", PWM_FULL_SCALE),
        goal_pwm=registers.get("Goal PWM", registers.get("PWM Limit", PWM_FULL_SCALE)),
        p_divisor=p_divisor,
    )


def apply_loop(model, actuator: int, loop: PositionLoop, servo: ServoModel) -> None:
    """Write ``loop`` into a compiled ``<dcmotor>``'s controller parameters.

    Parameters
    ----------
    model : mujoco.MjModel
        A model from ``sim.model.build_model``.
    actuator : int
        Actuator index.
    loop : PositionLoop
    servo : ServoModel

    Raises
    ------
    UnsupportedServoSetting
        If the I gain switches between zero and non-zero: the integrator's
        state is part of the compiled model (build it with the new loop).
    """
    kp, ki, kd, vmax = loop.mujoco_controller(servo)
    prm = model.actuator_gainprm[actuator]
    if (prm[5] > 0) != (ki > 0):
        raise UnsupportedServoSetting(
            "Position I Gain switched between zero and non-zero: rebuild the model"
        )
    prm[4:8] = kp, ki, kd, vmax
