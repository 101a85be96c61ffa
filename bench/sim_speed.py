"""How fast ``trajgen sim`` runs the built-in example, against a bare ``mj_step`` loop.

Timings on the same machine in the same run, each the best (and the median) of
``--repeat`` tries, interleaved so that every candidate sees the same load:

- peer: a bare ``mujoco.mj_step`` loop on the gimbal model (as built by
  ``sim.model.build_model``), as many steps as the example needs: MuJoCo's own
  speed on this model with nothing per step but the call;
- simulate: ``sim.run.simulate`` on the planned example: the stream through
  the servo model, every step recorded (inside MuJoCo: ``sim.run.run_batch``);
- check_torque: ``sim.check.check_torque`` on the example file, i.e. all of
  ``trajgen sim`` after imports (planning, simulation, inverse dynamics,
  verdict), with its parts timed alone: planning (``resolve_source``), the
  simulation with the progress reports ``trajgen sim`` asks for, and the
  judge (``build_report``: inverse dynamics and figures);
- the whole command ``trajgen sim`` as a process (Python start-up and imports
  included), and a process that only imports what it imports, for scale.

Prints markdown tables with "x real time", the ratio to the peer, and the
machine load.

Run: .venv/bin/python bench/sim_speed.py [--repeat 10] [--process-repeat 5]
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time

import mujoco
import numpy as np

from trajgen import BUILTIN_EXAMPLE
from trajgen.sim.check import build_report, check_torque, resolve_source
from trajgen.sim.model import build_model
from trajgen.sim.run import simulate


def interleaved(repeat: int, fns: dict) -> dict[str, np.ndarray]:
    """Wall times (s) of ``repeat`` calls of each of ``fns``, run in turn."""
    times = {name: [] for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: np.array(t) for name, t in times.items()}


def run(argv: list[str]) -> None:
    """Run ``argv`` as a process, its output discarded; raise if it fails."""
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--process-repeat", type=int, default=5)
    args = parser.parse_args()

    example = str(BUILTIN_EXAMPLE)
    trajectory, config = resolve_source(example)
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
    inproc = interleaved(
        args.repeat,
        {
            "bare mj_step loop (peer)": bare,
            "simulate (the stream through the servo model)": lambda: simulate(trajectory, config),
            "check_torque (all of trajgen sim after imports)": lambda: check_torque(example),
            "- planning (resolve_source)": lambda: resolve_source(example),
            "- simulate with progress reports, as trajgen sim": lambda: simulate(
                trajectory, config, progress=lambda fraction: None
            ),
            "- build_report (inverse dynamics, figures)": lambda: build_report(
                trajectory, config, record
            ),
        },
    )
    command = [os.path.join(os.path.dirname(sys.executable), "trajgen"), "sim"]
    imports = [sys.executable, "-c", "import trajgen.cli, trajgen.sim.check, mujoco"]
    process = interleaved(
        args.process_repeat,
        {
            "`trajgen sim` (whole process)": lambda: run(command),
            "imports alone": lambda: run(imports),
        },
    )
    load_after = os.getloadavg()

    print("# trajgen sim speed on the built-in example\n")
    print(
        f"{sim_seconds:.2f} s simulated, {n_steps} physics steps of "
        f"{config.timestep_s * 1e3:g} ms; best and median of {args.repeat} interleaved runs; "
        f"MuJoCo {mujoco.__version__}, numpy {np.__version__}, Python "
        f"{platform.python_version()}; load average {load_before[0]:.2f} before, "
        f"{load_after[0]:.2f} after ({os.cpu_count()} cores)\n"
    )
    print("| what | best (ms) | median (ms) | x real time (best) | ratio to bare mj_step (best) |")
    print("|---|---:|---:|---:|---:|")
    peer = inproc["bare mj_step loop (peer)"].min()
    for name, t in inproc.items():
        best = t.min()
        print(
            f"| {name} | {1e3 * best:.1f} | {1e3 * np.median(t):.1f} | "
            f"{sim_seconds / best:.0f} | {peer / best:.2f} |"
        )
    print(f"\nWhole process (`trajgen sim`), best and median of {args.process_repeat}:\n")
    print("| what | best (s) | median (s) |")
    print("|---|---:|---:|")
    for name, t in process.items():
        print(f"| {name} | {t.min():.2f} | {np.median(t):.2f} |")


if __name__ == "__main__":
    main()
