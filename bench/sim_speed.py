"""How fast ``trajgen sim`` runs the built-in example, against a bare ``mj_step`` loop.

Three timings on the same machine in the same run, each the best of
``--repeat`` tries, interleaved:

- peer: a bare ``mujoco.mj_step`` loop on the gimbal model, as many steps as
  the example needs (MuJoCo's own speed on this model, no Python work per step
  beyond the call);
- simulate: ``sim.run.simulate`` on the planned example (what ``trajgen sim``
  adds per step: recording state and torque, goals per frame, the warning and
  contact checks);
- check: ``sim.check.check_torque`` on the example file, i.e. the whole of
  ``trajgen sim`` after imports (planning, inverse dynamics, simulation, verdict).

Prints a markdown table with each as "x real time" and as a ratio to the peer,
and the machine load beside it.

Run: .venv/bin/python bench/sim_speed.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

import mujoco
import numpy as np

from trajgen import BUILTIN_EXAMPLE
from trajgen.sim.check import check_torque, resolve_source
from trajgen.sim.model import build_model
from trajgen.sim.run import simulate


def best_of(repeat: int, *fns) -> list[float]:
    """Shortest wall time (s) of ``repeat`` calls of each of ``fns``, interleaved.

    Interleaving exposes every candidate to the same machine load.
    """
    best = [math.inf] * len(fns)
    for _ in range(repeat):
        for i, fn in enumerate(fns):
            start = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10)
    args = parser.parse_args()

    trajectory, config = resolve_source(str(BUILTIN_EXAMPLE))
    record = simulate(trajectory, config)
    n_steps = len(record.t)
    sim_seconds = n_steps * config.timestep_s
    model = build_model(config)

    def bare():
        data = mujoco.MjData(model)
        data.qpos[:] = trajectory.q[0]
        data.ctrl[:] = trajectory.q[0]
        for _ in range(n_steps):
            mujoco.mj_step(model, data)

    load_before = os.getloadavg()
    peer, sim, check = best_of(
        args.repeat,
        bare,
        lambda: simulate(trajectory, config),
        lambda: check_torque(str(BUILTIN_EXAMPLE)),
    )
    load_after = os.getloadavg()

    print("# trajgen sim speed on the built-in example\n")
    print(
        f"{sim_seconds:.2f} s simulated, {n_steps} physics steps of "
        f"{config.timestep_s * 1e3:g} ms; best of {args.repeat}; MuJoCo {mujoco.__version__}, "
        f"numpy {np.__version__}, Python {platform.python_version()}, "
        f"load average {load_before[0]:.2f} before, {load_after[0]:.2f} after "
        f"({os.cpu_count()} cores)\n"
    )
    print("| what | wall time (ms) | x real time | ratio to bare mj_step |")
    print("|---|---:|---:|---:|")
    for name, seconds in (
        ("bare mj_step loop (peer)", peer),
        ("simulate (the stream through the servo model)", sim),
        ("check_torque (all of trajgen sim after imports)", check),
    ):
        print(
            f"| {name} | {1e3 * seconds:.1f} | {sim_seconds / seconds:.0f} | {peer / seconds:.2f} |"
        )


if __name__ == "__main__":
    main()
