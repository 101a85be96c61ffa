"""Stream rate and jitter over the virtual bus with wire timing.

Streams a smooth 3-joint trajectory at 100, 500 and 1000 Hz through the real
driver, dynamixel-sdk and pyserial to the virtual bus on a pseudo-terminal,
which adds byte time at 1 and 4 Mbps (10 bits a byte), a 20 us servo
turnaround and Return Delay 0 (set by bring-up, asked with ``configure=True``).
Telemetry (present current, velocity, position by fast sync read) every
frame, or every 10th frame.

Prints a markdown table: achieved rate, period error p50 / p99 / max, overruns,
communication errors, and bytes per cycle on the wire against the minimum from
docs/dynamixel.md (sync write 29 B + fast sync read 17 + 50 B every N frames).

Run: .venv/bin/python bench/stream_rate.py [--seconds 3]
"""

from __future__ import annotations

import argparse
import platform

import numpy as np

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus, WireTiming
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.stream import JointTrajectory

SYNC_WRITE_B, READ_REQUEST_B, FAST_REPLY_B = 29, 17, 50


def trajectory(rate_hz: float, seconds: float) -> JointTrajectory:
    """Sines on the three joints, from rest at 0."""
    t = np.arange(round(seconds * rate_hz) + 1) / rate_hz
    w = 2 * np.pi * np.array([0.5, 0.7, 0.3])
    q = 0.3 * (1 - np.cos(t[:, None] * w))
    qd = 0.3 * w * np.sin(t[:, None] * w)
    qdd = 0.3 * w**2 * np.cos(t[:, None] * w)
    return JointTrajectory(t, q, qd, qdd, rate_hz)


def run(rate_hz: float, baud: int, read_every: int, seconds: float) -> dict:
    """Stream once; returns the row of the table."""
    traj = trajectory(rate_hz, seconds)
    joints = JointMap()
    plant = FirstOrderPlant(time_constant_s=0.01)
    timing = WireTiming(baud=baud)
    with VirtualBus(plant, lockstep_dt_s=1 / rate_hz, timing=timing) as virtual:
        with ServoBus(virtual.port, baud=baud) as bus:
            bring_up(bus, joints, ("XM430-W350",) * 3, traj, configure=True)  # Return Delay 0
            streamer = Streamer(bus, joints, telemetry_every=read_every)
            before = virtual.bytes_received + virtual.bytes_sent
            stats = streamer.run(traj)
            # Includes the closing watchdog writes (a few dozen bytes in total).
            wire = virtual.bytes_received + virtual.bytes_sent - before
    return {
        "rate": rate_hz,
        "baud": baud,
        "every": read_every,
        "achieved": stats.achieved_rate_hz,
        "p50": stats.period_error_p50_s,
        "p99": stats.period_error_p99_s,
        "max": stats.period_error_max_s,
        "overruns": stats.overruns,
        "frames": stats.frames_sent,
        "comm": stats.comm_errors,
        "bytes": wire / stats.frames_sent,
        "minimum": SYNC_WRITE_B + (READ_REQUEST_B + FAST_REPLY_B) / read_every,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="stream length per run (s)")
    args = parser.parse_args()
    print(
        f"virtual bus on a pty, {platform.machine()} {platform.python_version()}, "
        f"{args.seconds:g} s per run; period error = |actual - planned interval| between frames"
    )
    print()
    print(
        "| rate Hz | baud | read every | achieved Hz | p50 ms | p99 ms | max ms | overruns "
        "| comm errors | bytes/cycle | minimum |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for rate in (100.0, 500.0, 1000.0):
        for baud in (1_000_000, 4_000_000):
            for every in (1, 10):
                r = run(rate, baud, every, args.seconds)
                print(
                    f"| {r['rate']:g} | {r['baud'] / 1e6:g} M | {r['every']} "
                    f"| {r['achieved']:.1f} | {1e3 * r['p50']:.3f} | {1e3 * r['p99']:.3f} "
                    f"| {1e3 * r['max']:.3f} | {r['overruns']}/{r['frames']} | {r['comm']} "
                    f"| {r['bytes']:.1f} | {r['minimum']:.1f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
