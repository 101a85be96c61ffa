"""A payload sweep of 100 simulations: ``mujoco.rollout`` on 2 threads against a Python loop.

Both run the built-in look-around (8 s, 200 Hz stream, 1 ms physics: 8,001 steps
per run) on 100 gimbals whose payload runs from 0 to 1 kg, with the controls
``trajgen sim`` sends (``sim.sweep.step_controls``). Timed: the simulation only
(models, controls and initial states are built before either clock starts).
The Python loop is the plain ``ctrl = ...; mj_step`` loop with the same
per-step records (qpos, qvel, actuator torque). The results are compared bit
for bit.

Usage::

    python bench/rollout_sweep.py [--runs 100] [--threads 2]
"""

from __future__ import annotations

import argparse
import os
import time

import mujoco
import numpy as np

from trajgen.keyframes import BUILTIN_EXAMPLE, load_keyframe_file
from trajgen.sim import GimbalConfig
from trajgen.sim.sweep import (
    initial_state,
    rollout_batch,
    scaled_trajectory,
    sensor_mjcf,
    step_controls,
)


def python_loop(models, ctrls, trajectory):
    """The same runs with ``mj_step`` in a Python loop; returns qpos, qvel, torque arrays."""
    n, k = len(models), len(ctrls[0])
    qpos = np.empty((n, k, 3))
    qvel = np.empty((n, k, 3))
    torque = np.empty((n, k, 3))
    for b, (model, ctrl) in enumerate(zip(models, ctrls, strict=True)):
        data = mujoco.MjData(model)
        data.qpos[:] = trajectory.q[0]
        data.time = trajectory.t[0]
        mujoco.mj_forward(model, data)
        for i in range(k):
            data.ctrl[:] = ctrl[i]
            mujoco.mj_step(model, data)
            qpos[b, i] = data.qpos
            qvel[b, i] = data.qvel
            torque[b, i] = data.sensordata
    return qpos, qvel, torque


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    keys = load_keyframe_file(BUILTIN_EXAMPLE)
    trajectory = scaled_trajectory(keys, 1.0, 200.0)
    configs = [GimbalConfig(payload_kg=float(m)) for m in np.linspace(0.0, 1.0, args.runs)]
    models = [mujoco.MjModel.from_xml_string(sensor_mjcf(c)) for c in configs]
    ctrls = [step_controls(trajectory, c, m)[1] for c, m in zip(configs, models, strict=True)]
    starts = [initial_state(m, trajectory) for m in models]
    states = np.stack([s for s, _ in starts])
    warm = np.stack([w for _, w in starts])
    controls = np.stack(ctrls)
    steps = controls.shape[0] * controls.shape[1]

    load_before = os.getloadavg()
    t0 = time.perf_counter()
    rolled = rollout_batch(models, states, warm, controls, threads=args.threads)
    t_rollout = time.perf_counter() - t0
    t0 = time.perf_counter()
    looped = python_loop(models, ctrls, trajectory)
    t_loop = time.perf_counter() - t0
    t0 = time.perf_counter()
    single = rollout_batch(models, states, warm, controls, threads=1)
    t_single = time.perf_counter() - t0
    load_after = os.getloadavg()
    same = all(np.array_equal(a, b) for a, b in zip(rolled, looped, strict=True)) and all(
        np.array_equal(a, b) for a, b in zip(single, looped, strict=True)
    )

    print(f"# Payload sweep: {args.runs} runs x {controls.shape[1]} steps = {steps:,} mj_step")
    print(
        f"load average (1, 5, 15 min) before: {load_before[0]:.2f} {load_before[1]:.2f} "
        f"{load_before[2]:.2f}; after: {load_after[0]:.2f} {load_after[1]:.2f} "
        f"{load_after[2]:.2f} (2 cores)"
    )
    print()
    print("| runner | wall time (s) | steps/s | vs Python loop |")
    print("|---|---:|---:|---:|")
    print(f"| Python loop (mj_step, 1 thread) | {t_loop:.3f} | {steps / t_loop:,.0f} | 1.00x |")
    print(
        f"| mujoco.rollout, 1 thread | {t_single:.3f} | {steps / t_single:,.0f} | "
        f"{t_loop / t_single:.2f}x |"
    )
    print(
        f"| mujoco.rollout, {args.threads} threads | {t_rollout:.3f} | "
        f"{steps / t_rollout:,.0f} | {t_loop / t_rollout:.2f}x |"
    )
    print()
    print(f"qpos, qvel and actuator torque identical bit for bit: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
