"""A payload sweep of 100 simulations: ``mujoco`` batches on 2 threads against a Python loop.

Both run the built-in look-around (8 s, 200 Hz stream, 1 ms physics: 8,005 steps
per run) on 100 gimbals whose payload runs from 0 to 1 kg, with the controls
``trajgen sim`` sends (``sim.run.step_controls``), through ``sim.run.run_batch``
(``mujoco.batch.Batch.rollout``; the gimbal without payload has one geom fewer,
so it runs in a batch of its own). Timed: the simulation only (models and
controls are built before either clock starts).
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
from trajgen.sim.run import run_batch, simulation_model, step_controls
from trajgen.sim.sweep import scaled_trajectory


def python_loop(models, ctrl, trajectory):
    """The same runs with ``mj_step`` in a Python loop; returns q, qd, torque arrays.

    ``q`` and ``qd`` at the start of each step, ``torque`` during it, as ``run_batch``.
    """
    n, k = len(models), len(ctrl)
    q = np.empty((n, k, 3))
    qd = np.empty((n, k, 3))
    torque = np.empty((n, k, 3))
    for b, model in enumerate(models):
        data = mujoco.MjData(model)
        data.qpos[:] = trajectory.q[0]
        data.time = trajectory.t[0]
        mujoco.mj_forward(model, data)
        for i in range(k):
            q[b, i] = data.qpos
            qd[b, i] = data.qvel
            data.ctrl[:] = ctrl[i]
            mujoco.mj_step(model, data)
            torque[b, i] = data.actuator_force
    return q, qd, torque


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    keys = load_keyframe_file(BUILTIN_EXAMPLE)
    trajectory = scaled_trajectory(keys, 1.0, 200.0)
    configs = [GimbalConfig(payload_kg=float(m)) for m in np.linspace(0.0, 1.0, args.runs)]
    models = [simulation_model(c) for c in configs]
    step_t, ctrl = step_controls(trajectory, configs[0].timestep_s)
    controls = np.stack([ctrl] * len(models))
    steps = controls.shape[0] * controls.shape[1]

    def batched(threads):
        return run_batch(models, trajectory.q[0], step_t[0], step_t, controls, threads=threads)

    load_before = os.getloadavg()
    t0 = time.perf_counter()
    rolled = batched(args.threads)
    t_rollout = time.perf_counter() - t0
    t0 = time.perf_counter()
    looped = python_loop(models, ctrl, trajectory)
    t_loop = time.perf_counter() - t0
    t0 = time.perf_counter()
    single = batched(1)
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
        f"| run_batch (mujoco.batch), 1 thread | {t_single:.3f} | {steps / t_single:,.0f} | "
        f"{t_loop / t_single:.2f}x |"
    )
    print(
        f"| run_batch (mujoco.batch), {args.threads} threads | {t_rollout:.3f} | "
        f"{steps / t_rollout:,.0f} | {t_loop / t_rollout:.2f}x |"
    )
    print()
    print(f"qpos, qvel and actuator torque identical bit for bit: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
