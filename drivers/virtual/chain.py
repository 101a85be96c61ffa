"""A chain of servos of which a plant drives some: the rest idle, as servos do.

A real bus carries more servos than the ones a stream drives: the other joints
of an arm, a gripper. ``ChainPlant`` puts a plant (the simulated gimbal, say)
behind some of the virtual bus's servos and a ``FirstOrderPlant`` behind the
others, so every servo answers, holds torque, moves to its goals and reports
present values as a servo does, whatever Operating Mode it is in (a gripper in
Current-based Position Mode follows its goal position like any other).

It is itself a ``Plant``: joint ``j`` is the bus's ``j``-th servo.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..errors import BadArgument
from .plant import FirstOrderPlant, Plant


class ChainPlant:
    """``plant`` behind the servos ``driven``; a ``FirstOrderPlant`` behind the rest.

    Parameters
    ----------
    plant : Plant
        Drives the servos at the indices ``driven``, in its own joint order.
    n_joints : int
        Servos on the chain.
    driven : sequence of int, shape (plant.n_joints,)
        Chain index of each of ``plant``'s joints, distinct, in 0..n_joints-1.
    idle_time_constant_s : float, optional
        Time constant (s) of the idle servos' first-order response.

    Raises
    ------
    ValueError
        If ``driven`` does not give one distinct chain index per plant joint.
    TypeError
        If ``plant`` is not a ``Plant``.

    Attributes
    ----------
    plant : Plant
    idle : FirstOrderPlant
        Behind the servos not in ``driven``, in chain order.
    """

    def __init__(
        self,
        plant: Plant,
        n_joints: int,
        driven: Sequence[int],
        *,
        idle_time_constant_s: float = 0.02,
    ) -> None:
        if not isinstance(plant, Plant):
            raise TypeError(f"Expected `plant` to be a Plant, got {type(plant).__name__}.")
        driven = tuple(int(j) for j in driven)
        if (
            len(driven) != plant.n_joints
            or len(set(driven)) != len(driven)
            or not all(0 <= j < n_joints for j in driven)
        ):
            raise BadArgument(
                f"Expected `driven` to give {plant.n_joints} distinct indices in "
                f"0..{n_joints - 1}, got {list(driven)}."
            )
        self.n_joints = n_joints
        self.plant = plant
        self.driven = driven
        self.rest = tuple(j for j in range(n_joints) if j not in driven)
        self.idle = FirstOrderPlant(max(len(self.rest), 1), time_constant_s=idle_time_constant_s)
        # Chain index -> (plant, its joint).
        self._route = {j: (plant, k) for k, j in enumerate(driven)}
        self._route.update({j: (self.idle, k) for k, j in enumerate(self.rest)})

    def set_goal(self, positions_rad: np.ndarray) -> None:
        """Goal angles (rad), shape (n_joints,)."""
        goal = np.asarray(positions_rad, dtype=float)
        self.plant.set_goal(goal[list(self.driven)])
        if self.rest:
            self.idle.set_goal(goal[list(self.rest)])

    def set_torque_enabled(self, joint: int, enabled: bool) -> None:
        """Torque on or off for one servo."""
        plant, k = self._route[joint]
        plant.set_torque_enabled(k, enabled)

    def set_control(self, joint: int, registers: Mapping[str, int]) -> None:
        """The position-loop registers of one servo (the driven plant may refuse them)."""
        plant, k = self._route[joint]
        plant.set_control(k, registers)

    def advance(self, dt_s: float) -> None:
        """Move time forward by ``dt_s`` seconds, for the plant and the idle servos."""
        self.plant.advance(dt_s)
        self.idle.advance(dt_s)

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Present position (rad), velocity (rad/s), current (A), each (n_joints,)."""
        out = [np.zeros(self.n_joints) for _ in range(3)]
        for part, index in ((self.plant, self.driven), (self.idle, self.rest)):
            if index:
                for whole, values in zip(out, part.read(), strict=True):
                    whole[list(index)] = np.asarray(values, dtype=float)[: len(index)]
        return out[0], out[1], out[2]

    def present_pwm(self) -> np.ndarray:
        """Drive output as a fraction of the supply, in [-1, 1], shape (n_joints,)."""
        out = np.zeros(self.n_joints)
        out[list(self.driven)] = self.plant.present_pwm()
        if self.rest:
            out[list(self.rest)] = self.idle.present_pwm()
        return out
