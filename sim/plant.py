"""The simulated gimbal as a plant behind a (virtual) servo bus.

A real servo receives goal positions only. :class:`GimbalPlant` takes the same,
estimates a velocity setpoint from the goals of the last ``VELOCITY_WINDOW_S``
(goals are whole ticks, 0.0015 rad: differencing two consecutive goals of a slow
move gives 0 or 1 tick per frame, a velocity target that chatters),
steps MuJoCo when told, and answers position, velocity and current as the
servos' present-value registers would (in SI units, trajgen's joint frame).
"""

from __future__ import annotations

import dataclasses
from collections import deque

import numpy as np

from trajgen.sim.errors import SimulationError
from trajgen.sim.model import GimbalConfig, build_model
from trajgen.sim.run import (
    SimRecord,
    at_torque_limit,
    check_trajectory,
    planned_path,
    raise_on_new_warnings,
    warning_counts,
)
from trajgen.validate import check_number

#: Window (s) over which the velocity setpoint is the mean rate of the goals.
VELOCITY_WINDOW_S = 0.025


class GimbalPlant:
    """Three simulated servos (pan, tilt, roll) driven by goal positions.

    Like a Dynamixel after power-up, every joint starts at rest with torque
    off, at 0 rad or at ``initial_rad``. Enabling torque on a joint that has no
    goal yet holds its present angle.

    Parameters
    ----------
    config : GimbalConfig, optional
        Default :class:`GimbalConfig`.
    timestep_s : float
        Physics time step (s), in (0, 0.001]; it replaces ``config.timestep_s``.
    initial_rad : array_like, shape (3,), optional
        Joint angles (rad) at power-up, e.g. a trajectory's first frame, so a
        stream needs no move to its start. Default 0.

    Raises
    ------
    TypeError, ValueError
        If ``timestep_s`` is not a number in (0, 0.001] or ``initial_rad`` is not
        3 finite numbers.
    """

    n_joints = 3

    def __init__(
        self, config: GimbalConfig | None = None, *, timestep_s: float = 0.001, initial_rad=None
    ):
        import mujoco

        config = GimbalConfig() if config is None else config
        self.config = dataclasses.replace(config, timestep_s=timestep_s)
        self._model = build_model(self.config)
        self._data = mujoco.MjData(self._model)
        self._model.opt.disableactuator = 0b111
        if initial_rad is not None:
            start = np.asarray(initial_rad, dtype=float)
            if start.shape != (3,) or not np.all(np.isfinite(start)):
                raise ValueError(f"Expected `initial_rad` to be 3 finite numbers, got {start!r}.")
            self._data.qpos[:] = start
        mujoco.mj_forward(self._model, self._data)
        self._warnings = warning_counts(self._data)
        self._goal = None
        self._goals: deque[tuple[float, np.ndarray]] = deque()
        self._goal_times: list[float] = []
        self._kt = np.array([s.torque_constant_nm_a for s in self.config.servos])
        self._log: list[np.ndarray] = []
        self.control: list[dict] = [{} for _ in range(3)]

    @property
    def time_s(self) -> float:
        """Simulated time (s) since the plant was made."""
        return float(self._data.time)

    def set_goal(self, positions_rad) -> None:
        """Receive goal positions (rad), shape (3,), as a sync write of Goal Position.

        The velocity setpoint is the mean rate of change of the goals received
        in the last ``VELOCITY_WINDOW_S`` of simulated time (0 for the first goal).

        Raises
        ------
        ValueError
            If ``positions_rad`` is not 3 finite numbers.
        """
        goal = np.asarray(positions_rad, dtype=float)
        if goal.shape != (3,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"Expected `positions_rad` to be 3 finite numbers, got {goal!r}.")
        now = self.time_s
        self._goals.append((now, goal))
        while len(self._goals) > 2 and now - self._goals[1][0] >= VELOCITY_WINDOW_S:
            self._goals.popleft()
        then, old = self._goals[0]
        velocity = (goal - old) / (now - then) if now > then else np.zeros(3)
        self._goal_times.append(now)
        self._goal = goal
        self._data.ctrl[0::3] = goal
        self._data.ctrl[1::3] = velocity
        self._data.ctrl[2::3] = 0.0

    def set_torque_enabled(self, joint: int, enabled: bool) -> None:
        """Switch one servo's torque on or off (Torque Enable).

        Raises
        ------
        TypeError
            If ``joint`` is not an int.
        ValueError
            If ``joint`` is not 0, 1 or 2.
        """
        joint = check_number("joint", joint, integer=True, low=0, high=self.n_joints - 1)
        if enabled and self._goal is None:
            self._data.ctrl[3 * joint] = self._data.qpos[joint]
            self._data.ctrl[3 * joint + 1] = 0.0
        bit = 1 << int(joint)
        mask = self._model.opt.disableactuator
        self._model.opt.disableactuator = (mask & ~bit) if enabled else (mask | bit)

    def set_control(self, joint: int, registers) -> None:
        """Receive a servo's position-loop registers (``drivers.virtual.plant.Plant``).

        Interim: stored only; the MuJoCo servo model does not follow them yet.
        """
        self.control[joint] = dict(registers)

    def present_pwm(self) -> np.ndarray:
        """Drive output as a fraction of the supply, shape (3,).

        Interim stand-in: actuator torque over stall torque, clipped to [-1, 1].
        """
        stall = np.array([s.stall_torque_nm for s in self.config.servos])
        return np.clip(self._data.actuator_force / stall, -1.0, 1.0)

    def advance(self, dt_s: float) -> None:
        """Run the physics for ``dt_s`` seconds (rounded to whole time steps).

        Raises
        ------
        ValueError
            If ``dt_s`` is negative or not finite.
        SimulationError
            If a MuJoCo warning counter rises or a contact appears.
        """
        import mujoco

        if not np.isfinite(dt_s) or dt_s < 0:
            raise ValueError(f"Expected `dt_s` >= 0, got {dt_s!r}.")
        model, data = self._model, self._data
        t_from = self.time_s
        for _ in range(int(round(dt_s / self.config.timestep_s))):
            row = np.empty(13)
            row[0] = data.time
            row[1:4] = data.qpos
            row[4:7] = data.qvel
            row[10:13] = data.ctrl[0::3]
            mujoco.mj_step(model, data)
            row[7:10] = data.actuator_force
            self._log.append(row)
            if data.ncon:
                raise SimulationError(
                    f"{data.ncon} contact(s) inside the gimbal at t = {row[0]:.4f} s"
                )
        raise_on_new_warnings(self._warnings, data, t_from, self.time_s)

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present position (rad), velocity (rad/s) and current (A), each shape (3,).

        Current is the actuator torque over the servo's torque constant
        (stall torque / stall current, an approximation); 0 with torque off.
        """
        current = self._data.actuator_force / self._kt
        return self._data.qpos.copy(), self._data.qvel.copy(), current

    def report(self, trajectory):
        """Torque report on what the plant recorded while ``trajectory`` was streamed.

        The record is aligned so that the goal received ``len(trajectory)``
        goals before the end is the trajectory's first frame; steps before it
        are left out. The planned
        part of the check is computed from ``trajectory`` itself.

        Parameters
        ----------
        trajectory : JointTrajectory
            The stream that was sent.

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

        check_trajectory(trajectory)
        if not self._goal_times:
            raise SimError("no goal position was received: nothing to report")
        # The stream's frames are the last goals received (bring-up and the
        # approach come before them).
        first = self._goal_times[-min(len(trajectory), len(self._goal_times))]
        log = np.array(self._log).reshape(-1, 13)
        log = log[log[:, 0] >= first - 1e-12]
        if len(log) == 0:
            raise SimError("no physics step ran after the first goal: nothing to report")
        t = log[:, 0] - first + trajectory.t[0]
        record = SimRecord(
            t=t,
            q=log[:, 1:4],
            qd=log[:, 4:7],
            torque_nm=log[:, 7:10],
            setpoint=log[:, 10:13],
            planned=planned_path(trajectory, t),
            at_limit=at_torque_limit(self.config, log[:, 4:7], log[:, 7:10]),
            timestep_s=self.config.timestep_s,
        )
        return build_report(trajectory, self.config, record)
