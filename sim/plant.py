"""The simulated gimbal as a plant behind a (virtual) servo bus.

A real servo receives goal positions and its own control-table registers.
:class:`GimbalPlant` takes the same: goal positions (whole ticks, from the bus)
and the registers that shape the firmware's position loop (``set_control``),
and runs the same servo model as ``trajgen sim`` (``sim.model``: each joint's
``<dcmotor>`` controller is the firmware loop, ``sim.firmware``). It steps
MuJoCo when told and answers position, velocity, current and PWM as the
servos' present-value registers would (in SI units, trajgen's joint frame).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from trajgen.lift import sent_goals
from trajgen.sim.firmware import apply_loop, loop_from_registers
from trajgen.sim.model import GimbalConfig, build_model
from trajgen.sim.run import (
    SimRecord,
    at_torque_limit,
    check_trajectory,
    planned_path,
    raise_on_new_warnings,
    step_and_record,
    warning_counts,
)
from trajgen.validate import check_number

from .errors import BadArgument

#: Per-joint blocks of a log row after its time: q, qd, torque, goal, drive cap in volts.
_LOG_BLOCKS = 5


class GimbalPlant:
    """The simulated servos of a gimbal (2 or 3 joints, ``config.names``) driven by goal
    positions.

    Like a Dynamixel after power-up, every joint starts at rest with torque
    off, at 0 rad or at ``initial_rad``. Enabling torque on a joint that has no
    goal yet holds its present angle. Each joint's position loop starts with
    the gains of ``config`` (the keyframe file's ``[gimbal.<joint>]`` or the
    servo's defaults) and follows its registers from then on (``set_control``).

    Parameters
    ----------
    config : GimbalConfig, optional
        Default :class:`GimbalConfig`.
    timestep_s : float
        Physics time step (s), in (0, 0.001]; it replaces ``config.timestep_s``.
    initial_rad : array_like, shape (n,), optional
        Joint angles (rad) at power-up, e.g. a trajectory's first frame, so a
        stream needs no move to its start. Default 0.
    record : bool
        Keep every physics step for :meth:`report` (16 numbers a step for three
        joints, about 0.5 GB an hour of simulated time). False for a long-running bus that
        is never reported on.

    Raises
    ------
    TypeError, ValueError
        If ``timestep_s`` is not a number in (0, 0.001] or ``initial_rad`` is not
        one finite number per joint.
    """

    def __init__(
        self,
        config: GimbalConfig | None = None,
        *,
        timestep_s: float = 0.001,
        initial_rad=None,
        record: bool = True,
    ):
        import mujoco

        config = GimbalConfig() if config is None else config
        self.config = dataclasses.replace(config, timestep_s=timestep_s)
        self.n_joints = n = self.config.n_joints
        self._model = build_model(self.config)
        self._data = mujoco.MjData(self._model)
        self._model.opt.disableactuator = (1 << n) - 1
        self._loops = [self.config.loop(j) for j in range(n)]
        self._registers = self.initial_registers()
        if initial_rad is not None:
            start = np.asarray(initial_rad, dtype=float)
            if start.shape != (n,) or not np.all(np.isfinite(start)):
                raise BadArgument(
                    f"Expected `initial_rad` to be {n} finite numbers, got {start!r}."
                )
            self._data.qpos[:] = start
        self._data.ctrl[:] = self._data.qpos
        mujoco.mj_forward(self._model, self._data)
        self._warnings = warning_counts(self._data)
        self._goal = None
        self._goal_times: list[float] = []
        self._kt = np.array([s.torque_constant_nm_a for s in self.config.servos])
        self._supply_v = np.array([s.voltage_v for s in self.config.servos])
        self._log: list[np.ndarray] = []
        self._record = bool(record)
        self._pending_s = 0.0

    @property
    def _log_columns(self) -> int:
        """Numbers in a log row: the time, then ``_LOG_BLOCKS`` blocks of one per joint."""
        return 1 + _LOG_BLOCKS * self.n_joints

    def _blocks(self, rows: np.ndarray) -> list[np.ndarray]:
        """Views of a log's per-joint blocks (q, qd, torque, goal, cap), each (K, n)."""
        n = self.n_joints
        return [rows[:, 1 + b * n : 1 + (b + 1) * n] for b in range(_LOG_BLOCKS)]

    @property
    def time_s(self) -> float:
        """Simulated time (s) since the plant was made."""
        return float(self._data.time)

    def initial_registers(self) -> list[dict[str, int]]:
        """Per joint, the gain registers of ``config``, to set on the virtual servos.

        So a virtual servo powers up with the gains the keyframe file states
        (``[gimbal.<joint>]``), as the real one was configured.
        """
        return [
            {
                "Position P Gain": p.position_p_gain,
                "Position I Gain": p.position_i_gain,
                "Position D Gain": p.position_d_gain,
            }
            for p in self.config.joints
        ]

    @property
    def loops(self) -> tuple:
        """Each joint's position loop (``sim.firmware.PositionLoop``), as last set."""
        return tuple(self._loops)

    @property
    def config_now(self) -> GimbalConfig:
        """``config`` with each joint's gains as its registers last set them."""
        joints = tuple(
            dataclasses.replace(
                p, position_p_gain=l.p_gain, position_i_gain=l.i_gain, position_d_gain=l.d_gain
            )
            for p, l in zip(self.config.joints, self._loops, strict=True)
        )
        return dataclasses.replace(self.config, joints=joints)

    def set_goal(self, positions_rad) -> None:
        """Receive goal positions (rad), shape (n,), as a sync write of Goal Position.

        Raises
        ------
        ValueError
            If ``positions_rad`` is not one finite number per joint.
        """
        goal = np.asarray(positions_rad, dtype=float)
        if goal.shape != (self.n_joints,) or not np.all(np.isfinite(goal)):
            raise BadArgument(
                f"Expected `positions_rad` to be {self.n_joints} finite numbers, got {goal!r}."
            )
        self._goal_times.append(self.time_s)
        self._goal = goal
        self._data.ctrl[:] = goal

    def set_control(self, joint: int, registers: Mapping[str, int]) -> None:
        """Set one servo's position loop from its control-table registers.

        Parameters
        ----------
        joint : int
            0 to ``n_joints - 1``, base out.
        registers : mapping of str to int
            Register values in register units keyed by the SDK's control-table
            names (``trajgen.servo_table.CONTROL_REGISTERS``); missing ones keep their
            last value (initially the gains of ``config``, full PWM, no
            profile, Position Mode).

        Raises
        ------
        TypeError, ValueError
            If ``joint`` is not a joint index, or a gain is out of range.
        sim.firmware.UnsupportedServoSetting
            For a non-zero Profile Velocity / Acceleration or an Operating Mode
            other than 3 or 4 (not simulated).
        """
        joint = self._check_joint(joint)
        merged = {**self._registers[joint], **registers}
        loop = loop_from_registers(
            merged, p_divisor=self.config.p_divisor, joint=self.config.names[joint]
        )
        self._registers[joint] = merged
        integrator_changed = (loop.i_gain > 0) != (self._loops[joint].i_gain > 0)
        self._loops[joint] = loop
        if integrator_changed:
            self._rebuild()
        else:
            apply_loop(self._model, joint, loop, self.config.servos[joint])

    def _rebuild(self) -> None:
        """Compile the model again (an integrator appeared or went), keeping the state."""
        import mujoco

        model = build_model(self.config_now)
        data = mujoco.MjData(model)
        model.opt.disableactuator = self._model.opt.disableactuator
        data.time = self._data.time
        data.qpos[:] = self._data.qpos
        data.qvel[:] = self._data.qvel
        data.ctrl[:] = self._data.ctrl
        for j, loop in enumerate(self._loops):
            apply_loop(model, j, loop, self.config.servos[j])
        mujoco.mj_forward(model, data)
        self._model, self._data = model, data
        self._warnings = warning_counts(data)

    def _check_joint(self, joint) -> int:
        return check_number("joint", joint, integer=True, low=0, high=self.n_joints - 1)

    def set_torque_enabled(self, joint: int, enabled: bool) -> None:
        """Switch one servo's torque on or off (Torque Enable).

        Raises
        ------
        TypeError
            If ``joint`` is not an int.
        ValueError
            If ``joint`` is not a joint index.
        """
        joint = self._check_joint(joint)
        if enabled and self._goal is None:
            self._data.ctrl[joint] = self._data.qpos[joint]
        bit = 1 << int(joint)
        mask = self._model.opt.disableactuator
        self._model.opt.disableactuator = (mask & ~bit) if enabled else (mask | bit)

    def advance(self, dt_s: float) -> None:
        """Run the physics for ``dt_s`` seconds, in whole time steps (the rest carries over).

        Raises
        ------
        ValueError
            If ``dt_s`` is negative or not finite.
        SimulationError
            If a MuJoCo warning counter rises or a contact appears.
        """
        if not np.isfinite(dt_s) or dt_s < 0:
            raise BadArgument(f"Expected `dt_s` >= 0, got {dt_s!r}.")
        # Whole steps only; the remainder carries over to the next call.
        self._pending_s += dt_s
        n = int(self._pending_s / self.config.timestep_s + 1e-9)
        self._pending_s -= n * self.config.timestep_s
        if n == 0:
            return
        t_from = self.time_s
        rows = np.empty((n, self._log_columns))
        q, qd, torque, goal, cap = self._blocks(rows)
        rows[:, 0] = t_from + np.arange(n) * self.config.timestep_s
        goal[:] = self._data.ctrl
        cap[:] = self._model.actuator_gainprm[:, 7]
        step_and_record(self._model, self._data, q, qd, torque)
        if self._record:
            self._log.append(rows)
        raise_on_new_warnings(self._warnings, self._data, t_from, self.time_s)

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present position (rad), velocity (rad/s) and current (A), each shape (n,).

        Current is the actuator torque over the servo's torque constant
        (stall torque / stall current, an approximation); 0 with torque off.
        """
        current = self._data.actuator_force / self._kt
        return self._data.qpos.copy(), self._data.qvel.copy(), current

    def present_pwm(self) -> np.ndarray:
        """Drive output as a fraction of the supply, shape (n,), in [-1, 1].

        The voltage the firmware loop applies to each motor now (0 with torque
        off) over the supply (the servo's rated voltage), as Present PWM / PWM Limit
        885.
        """
        model, data = self._model, self._data
        prm = model.actuator_gainprm
        r, k, kp, ki, kd, vmax = prm[:, 0], prm[:, 1], prm[:, 4], prm[:, 5], prm[:, 6], prm[:, 7]
        n = self.n_joints
        integral = np.zeros(n)
        for j in range(n):
            if model.actuator_actadr[j] >= 0:
                integral[j] = data.act[model.actuator_actadr[j] + model.actuator_actnum[j] - 1]
        w = data.qvel
        tau = kp * (data.ctrl - data.qpos) - kd * w + ki * integral
        volts = np.clip(r / k * tau + k * w, -vmax, vmax)
        enabled = (model.opt.disableactuator >> np.arange(n)) & 1 == 0
        return np.where(enabled, volts / self._supply_v, 0.0)

    def report(self, trajectory, *, lead: str = "none"):
        """Torque report on what the plant recorded while ``trajectory`` was streamed.

        The record is aligned so that the goal received as many goals before the
        end as the trajectory sends is its first frame sent (its lift's first,
        ``trajgen.lift``); steps before it are left out, the lift's are kept
        apart (``SimRecord.lift``). The planned part of the check is computed
        from ``trajectory`` itself.

        Parameters
        ----------
        trajectory : JointTrajectory
            The stream that was sent: the plan (``q``), which the tracking
            error is against, and the goals sent (``goal``, when led).
        lead : str
            How the goals were led (``trajgen.lead``), for the report.

        Returns
        -------
        sim.check.TorqueReport

        Raises
        ------
        TypeError, ValueError
            If ``trajectory`` is not a valid JointTrajectory.
        SimError
            If no goal was received or no step was run after it.
        """
        from trajgen.sim.check import build_report
        from trajgen.sim.errors import SimError

        check_trajectory(trajectory, self.n_joints)
        if not self._record:
            raise SimError("the plant was made with record=False: nothing to report")
        if not self._goal_times:
            raise SimError("no goal position was received: nothing to report")
        # The stream's frames, its lift's first (trajgen.lift), are the last goals
        # received (bring-up and the approach come before them).
        sent_t = sent_goals(trajectory)[0]
        first = self._goal_times[-min(len(sent_t), len(self._goal_times))]
        log = np.concatenate(self._log) if self._log else np.empty((0, self._log_columns))
        log = log[log[:, 0] >= first - 1e-12]
        if len(log) == 0:
            raise SimError("no physics step ran after the first goal: nothing to report")
        t = log[:, 0] - first + sent_t[0]
        q, qd, torque, goal, cap = self._blocks(log)
        record = SimRecord(
            t=t,
            q=q,
            qd=qd,
            torque_nm=torque,
            setpoint=goal,
            planned=planned_path(trajectory, t),
            at_limit=at_torque_limit(self.config, qd, torque, cap),
            timestep_s=self.config.timestep_s,
        ).split_lift(float(trajectory.t[0]))
        return build_report(trajectory, self.config_now, record, lead=lead)
