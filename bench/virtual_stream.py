"""Wall time of a lock-step virtual stream: the simulated clock against the wall clock.

Streams the built-in example (the demo's motion) through the real driver,
dynamixel-sdk and pyserial to the virtual bus in lock-step, backed by the
MuJoCo gimbal, twice: with the stream's deadlines on a ``SimulatedClock`` (what
``trajgen stream --virtual`` does: no waiting, as fast as the simulation
allows) and on the wall clock (the peer: what it did before, waiting out the
motion's real time). Both runs must send the same goals and produce the same
torque report; the table gives wall time, CPU time, the speed against real
time and the ratio between the two, with the machine load.

Run: .venv/bin/python bench/virtual_stream.py
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.clock import WALL_CLOCK, SimulatedClock
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.keyframes import BUILTIN_EXAMPLE, load_keyframe_file
from trajgen.sim.model import gimbal_config_from_tables
from trajgen.sim.plant import GimbalPlant
from trajgen.stream import plan_joint_trajectory


def stream_once(kf, trajectory, clock):
    """Stream ``trajectory``; returns (wall s, cpu s, goals sent, torque report)."""
    joints = JointMap()
    plant = GimbalPlant(gimbal_config_from_tables(kf.tables, kf.path), initial_rad=trajectory.q[0])
    start_wall, start_cpu = time.perf_counter(), time.process_time()
    with VirtualBus(plant, lockstep_dt_s=1.0 / trajectory.rate_hz) as virtual:
        with ServoBus(virtual.port) as bus:
            bring_up(bus, joints, ("XM430-W350",) * 3, trajectory, configure=True)
            Streamer(bus, joints, clock=clock).run(trajectory)
        goals = np.array(virtual.goal_log)
    wall, cpu = time.perf_counter() - start_wall, time.process_time() - start_cpu
    return wall, cpu, goals, plant.report(trajectory)


def main() -> None:
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    rate = kf.rate_hz or 200.0
    trajectory = plan_joint_trajectory(kf.spline(), rate)
    motion_s = trajectory.t[-1] - trajectory.t[0]
    load_before = os.getloadavg()
    runs = {
        "simulated clock (trajgen stream --virtual)": stream_once(kf, trajectory, SimulatedClock()),
        "wall clock (peer: waits out the motion)": stream_once(kf, trajectory, WALL_CLOCK),
    }
    load_after = os.getloadavg()
    (fast, slow) = runs.values()
    same_goals = fast[2].shape == slow[2].shape and bool(np.all(fast[2] == slow[2]))
    print(f"# Lock-step virtual stream of the built-in example ({motion_s:.2f} s at {rate:g} Hz)")
    print()
    print(
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
        f"load average {load_before[0]:.2f} before, {load_after[0]:.2f} after"
    )
    print()
    print("| clock | wall s | cpu s | x real time | torque check | peak pan error deg |")
    print("|---|---:|---:|---:|---|---:|")
    for name, (wall, cpu, _, report) in runs.items():
        error = np.degrees(report.joints["pan"].max_tracking_error_rad)
        print(
            f"| {name} | {wall:.2f} | {cpu:.2f} | {motion_s / wall:.2f} | "
            f"{'OK' if report.ok else 'FAILED'} | {error:.3f} |"
        )
    print()
    print(
        f"wall-time ratio peer / simulated clock: {slow[0] / fast[0]:.2f}x; "
        f"same goals sent: {same_goals}"
    )


if __name__ == "__main__":
    main()
