"""Torque chatter and peaks of the simulated servo on the built-in example.

Two runs of the same plan through the same servo model, in the same process:

- plant: ``sim.plant.GimbalPlant`` fed frame by frame with goals in whole
  ticks, as the virtual bus feeds it in lock-step (``trajgen stream --virtual``);
- sim: ``sim.run.simulate``, what ``trajgen sim`` runs.

Per joint: chatter, the RMS of the simulated torque minus its 25 ms moving
average (N m), and the peak simulated torque over the peak planned torque.
The two rows should agree (same servo); a plant that invents setpoint noise
shows up as chatter.

Run: .venv/bin/python bench/plant_chatter.py
"""

from __future__ import annotations

import os

import numpy as np

from trajgen import BUILTIN_EXAMPLE
from trajgen.sim.check import build_report, resolve_source
from trajgen.sim.plant import GimbalPlant
from trajgen.sim.run import goal_ticks_rad, simulate

WINDOW_STEPS = 25  # 25 ms at 1 ms physics


def chatter(torque: np.ndarray) -> np.ndarray:
    """RMS (N m) of ``torque`` (K, 3) minus its moving average, per joint."""
    kernel = np.ones(WINDOW_STEPS) / WINDOW_STEPS
    smooth = np.column_stack([np.convolve(torque[:, j], kernel, mode="same") for j in range(3)])
    residual = (torque - smooth)[WINDOW_STEPS:-WINDOW_STEPS]
    return np.sqrt(np.mean(residual**2, axis=0))


def main() -> None:
    trajectory, config = resolve_source(str(BUILTIN_EXAMPLE))
    plant = GimbalPlant(config, initial_rad=trajectory.q[0])
    for joint in range(3):
        plant.set_torque_enabled(joint, True)
    for frame in trajectory:
        plant.set_goal(goal_ticks_rad(frame.q))
        plant.advance(1.0 / trajectory.rate_hz)
    reports = {
        "plant (virtual bus, lock-step)": plant.report(trajectory),
        "sim (trajgen sim)": build_report(trajectory, config, simulate(trajectory, config)),
    }
    print("# Simulated torque chatter on the built-in example\n")
    print(f"load average {os.getloadavg()[0]:.2f} (figures do not depend on it)\n")
    print("| run | chatter pan / tilt / roll (N m) | peak sim / peak planned |")
    print("|---|---|---|")
    for name, report in reports.items():
        tau = report.record.torque_nm
        ratio = np.abs(tau).max(axis=0) / np.abs(report.planned_torque_nm).max(axis=0)
        print(
            f"| {name} | {' / '.join(f'{v:.4f}' for v in chatter(tau))} | "
            f"{' / '.join(f'{v:.2f}' for v in ratio)} |"
        )


if __name__ == "__main__":
    main()
