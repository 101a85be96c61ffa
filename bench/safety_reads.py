"""What the safety reads cost a stream: bytes on the wire and host time per frame.

Streams the same 2,000 frames twice through the real driver, dynamixel-sdk and
pyserial to a lock-step virtual bus on a simulated clock (no waiting, no wall-
clock limits): once with the default safety polls (status of Torque Enable,
Hardware Error Status and Bus Watchdog every ``poll_s`` = 50 ms, voltage and
temperature every ``health_s`` = 0.5 s) and once with both polls every 10^6 s
(the peer: only the per-frame goal write and state read). Prints bytes per
frame, their wire time at 1 and 4 Mbps (10 bits a byte), host CPU time per
frame (``time.process_time``), the ratio against the peer, and the machine load.

Run: .venv/bin/python bench/safety_reads.py [--frames 2000]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.clock import SimulatedClock
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.stream import JointTrajectory

RATE_HZ = 200.0


def trajectory(frames: int) -> JointTrajectory:
    """Slow sines on the three joints, from rest at 0."""
    t = np.arange(frames) / RATE_HZ
    w = 2 * np.pi * np.array([0.5, 0.7, 0.3])
    q = 0.3 * (1 - np.cos(t[:, None] * w))
    return JointTrajectory(t, q, np.zeros_like(q), np.zeros_like(q), RATE_HZ)


def run(frames: int, poll_s: float, health_s: float) -> tuple[float, float]:
    """(bytes per frame, host CPU seconds per frame) of one stream."""
    traj = trajectory(frames)
    with VirtualBus(FirstOrderPlant(time_constant_s=0.01), lockstep_dt_s=1 / RATE_HZ) as virtual:
        with ServoBus(virtual.port) as bus:
            setup = bring_up(bus, JointMap(), ("XM430-W350",) * 3, traj, configure=True)
            streamer = Streamer(
                bus,
                JointMap(),
                poll_s=poll_s,
                health_s=health_s,
                start_ticks=setup.present_ticks,
                power_limits=setup.power_limits,
                clock=SimulatedClock(),
            )
            before = virtual.bytes_received + virtual.bytes_sent
            cpu = time.process_time()
            stats = streamer.run(traj)
            cpu = time.process_time() - cpu
            wire = virtual.bytes_received + virtual.bytes_sent - before
    sent = stats.frames_sent + stats.approach_frames
    return wire / sent, cpu / sent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=2000, help="frames per stream")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    peer = run(args.frames, 1e6, 1e6)
    safe = run(args.frames, 0.05, 0.5)
    print("| stream | bytes/frame | wire at 1 Mbps | wire at 4 Mbps | host CPU/frame |")
    print("|---|---|---|---|---|")
    for name, (b, cpu) in (("peer: no polls", peer), ("default safety polls", safe)):
        print(
            f"| {name} | {b:.1f} | {b * 10 / 1e6 * 1e6:.0f} us | {b * 10 / 4e6 * 1e6:.0f} us "
            f"| {cpu * 1e6:.0f} us |"
        )
    print(f"ratio safety / peer: bytes {safe[0] / peer[0]:.3f}, host CPU {safe[1] / peer[1]:.3f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
