"""Stream rate and jitter over the virtual bus with wire timing.

Streams a smooth 3-joint trajectory at 100, 500 and 1000 Hz through the real
driver, dynamixel-sdk and pyserial to the virtual bus on a pseudo-terminal,
which adds byte time at 1 and 4 Mbps (10 bits a byte), a 20 us servo
turnaround and Return Delay 0 (set by bring-up, asked with ``configure=True``).
The virtual bus runs in a process of its own, in real time (its servos on the
wall clock, as real ones are), at the priority `trajgen virtual-bus` serves at:
the stream's process holds only the driver, as it would on a real bus.
Telemetry (present current, velocity, position by fast sync read) every
frame, or every 10th frame; the probe before each stream may read back less
often, shown as "(probe)", where a read-back every frame does not fit the
period (at 1 Mbps, 1 kHz: 29 + 17 + 50 bytes are 0.96 ms of wire a frame), or
refuse a rate this host cannot keep: that row then holds its message.
``--telemetry csv`` also writes each stream's CSV telemetry (one row a frame).

Each frame's read goes out split-phase (its request after the goal, its reply
collected before the next goal, or behind it and the next few up to
``REPLY_WAIT_S`` past its wire end) and the polls in parts that fit a frame
(``drivers.frame_reads``). Peer, measured in the same run just before each
stream, on the same pty and emulator: 200 state reads at once, paced 2 ms
apart at the stream's priority, and what each took beyond its wire time
(request and reply bytes, 20 us turnaround): what the pty, the emulator and
the host add to every read (a frame whose reply comes more than half a period
late stalls). Second peer, the host alone, for as long as the stream: a loop at
the stream's priority that only waits for each deadline, its clock shifted by
the stream's stall rule: the rate this host keeps with no bus at all.

Prints a markdown table: achieved rate, period error p50 / p99 / max, overruns,
stalls (and of them, those of frames that woke on time and waited for the last
read's reply), state reads given to polls, goals sent behind a reply not in
hand yet (and of them, those after which the reply was still out and carried to
the next frame), the longest a reply a goal went behind was checked after its
computed wire end, deferred reads, collisions, communication errors, bytes per
cycle on the wire against the minimum from docs/dynamixel.md (sync write 29 B
+ fast sync read 17 + 50 B every N frames), the peer's figures, and the
machine load beside each row.

Run: .venv/bin/python bench/stream_rate.py [--seconds 3] [--rates 100 500 1000]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.clock import sleep_until
from trajgen.drivers.control_table import Register
from trajgen.drivers.errors import StreamLagging
from trajgen.drivers.priority import stream_priority
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus, WireTiming
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.servo_table import TURNAROUND_S
from trajgen.stream import JointTrajectory

SYNC_WRITE_B, READ_REQUEST_B, FAST_REPLY_B = 29, 17, 50
STATE = (Register.PRESENT_CURRENT, Register.PRESENT_VELOCITY, Register.PRESENT_POSITION)
PEER_READS, PEER_GAP_S = 200, 2e-3


def trajectory(rate_hz: float, seconds: float) -> JointTrajectory:
    """Sines on the three joints, from rest at 0."""
    t = np.arange(round(seconds * rate_hz) + 1) / rate_hz
    w = 2 * np.pi * np.array([0.5, 0.7, 0.3])
    q = 0.3 * (1 - np.cos(t[:, None] * w))
    qd = 0.3 * w * np.sin(t[:, None] * w)
    qdd = 0.3 * w**2 * np.cos(t[:, None] * w)
    return JointTrajectory(t, q, qd, qdd, rate_hz)


def serve(baud: int, conn) -> None:
    """The virtual bus process: serve until told to stop; answer (bytes on the wire,
    collisions) when asked."""
    plant = FirstOrderPlant(time_constant_s=0.01)
    with VirtualBus(plant, timing=WireTiming(baud=baud)) as virtual, stream_priority():
        conn.send(virtual.port)
        while conn.recv() == "count":
            conn.send((virtual.bytes_received + virtual.bytes_sent, virtual.collisions))


def read_beyond_wire(bus: ServoBus, ids, baud: int) -> tuple[float, float]:
    """The peer: p50 and p99 (s) of what a state read takes beyond its wire time."""
    wire_s = (READ_REQUEST_B + FAST_REPLY_B) * 10 / baud + TURNAROUND_S
    extra = []
    with stream_priority():
        deadline = time.monotonic()
        for _ in range(PEER_READS):
            deadline += PEER_GAP_S
            sleep_until(deadline)
            t0 = time.perf_counter()
            bus.read_block(ids, STATE)
            extra.append(time.perf_counter() - t0 - wire_s)
    p50, p99 = np.percentile(extra, [50, 99])
    return float(p50), float(p99)


def host_alone(rate_hz: float, seconds: float) -> tuple[float, int]:
    """The host's own floor: a loop at the stream's priority that only waits for each
    deadline, shifting its clock as the stream does where it wakes more than half a
    period late; returns its achieved rate (Hz) and those stalls."""
    period = 1.0 / rate_hz
    frames = round(seconds * rate_hz) + 1
    stalls, shift = 0, 0.0
    with stream_priority():
        start = time.monotonic() + period
        for k in range(frames):
            due = start + k * period + shift
            sleep_until(due)
            now = time.monotonic()
            if k == 0:
                first = now
            if now - due > 0.5 * period:
                stalls += 1
                shift += now - due
    return rate_hz * (frames - 1) * period / (now - first), stalls


def run(rate_hz: float, baud: int, read_every: int, seconds: float, telemetry: str | None) -> dict:
    """Stream once; returns the row of the table."""
    traj = trajectory(rate_hz, seconds)
    joints = JointMap()
    conn, child_conn = multiprocessing.get_context("fork").Pipe()
    server = multiprocessing.get_context("fork").Process(target=serve, args=(baud, child_conn))
    server.start()
    try:
        port = conn.recv()
        alone = host_alone(rate_hz, seconds)  # before bring-up sets the Bus Watchdog
        with ServoBus(port, baud=baud) as bus, tempfile.TemporaryDirectory() as tmp:
            bring_up(bus, joints, ("XM430-W350",) * 3, traj, configure=True)  # Return Delay 0
            peer = read_beyond_wire(bus, joints.ids, baud)
            path = None if telemetry is None else Path(tmp) / f"run.{telemetry}"
            streamer = Streamer(bus, joints, telemetry=path, telemetry_every=read_every)
            conn.send("count")
            before, collided = conn.recv()
            stats = streamer.run(traj)
            conn.send("count")
            # Includes the closing watchdog writes (a few dozen bytes in total).
            wire, collisions = np.subtract(conn.recv(), (before, collided))
    finally:
        conn.send("stop")
        server.join(timeout=10)
    return {
        "rate": rate_hz,
        "baud": baud,
        "every": read_every if stats.read_every == read_every else f"{stats.read_every} (probe)",
        "achieved": stats.achieved_rate_hz,
        "p50": stats.period_error_p50_s,
        "p99": stats.period_error_p99_s,
        "max": stats.period_error_max_s,
        "overruns": stats.overruns,
        "stalls": stats.stalls,
        "reply_stalls": stats.reply_stalls,
        "skipped": stats.reads_skipped,
        "deferred": stats.reads_deferred,
        "behind": stats.goals_behind,
        "carried": stats.replies_carried,
        "checked": stats.reply_check_max_s,
        "collisions": int(collisions),
        "peer": peer,
        "alone": alone,
        "frames": stats.frames_sent,
        "comm": stats.comm_errors,
        "bytes": wire / stats.frames_sent,
        "minimum": SYNC_WRITE_B + (READ_REQUEST_B + FAST_REPLY_B) / stats.read_every,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="stream length per run (s)")
    parser.add_argument(
        "--rates", type=float, nargs="+", default=[100.0, 500.0, 1000.0], help="rates (Hz)"
    )
    parser.add_argument("--telemetry", choices=["csv", "npz"], help="also write telemetry")
    args = parser.parse_args()
    print(
        f"virtual bus on a pty (its own process), {platform.machine()} "
        f"{platform.python_version()}, {os.cpu_count()} cores, {args.seconds:g} s per run, "
        f"telemetry file: {args.telemetry or 'none'}; period error = |actual - planned "
        "interval| between frames"
    )
    print()
    print(
        "| rate Hz | baud | read every | achieved Hz | p50 ms | p99 ms | max ms | overruns "
        "| stalls (waiting for a reply) | reads given to polls "
        "| goals behind a reply (carried a frame) | a reply checked after its wire end, max ms "
        "| reads deferred | collisions | comm errors | bytes/cycle "
        "| minimum | peer: a read beyond its wire, p50 / p99 ms "
        "| peer: the host alone, Hz (stalls) | achieved / host alone | load |"
    )
    print("|---" * 21 + "|")
    for rate in args.rates:
        for baud in (1_000_000, 4_000_000):
            for every in (1, 10):
                try:
                    r = run(rate, baud, every, args.seconds, args.telemetry)
                except StreamLagging as e:  # the probe refused the rate, or it fell behind
                    load = os.getloadavg()[0]
                    row = f"| {rate:g} | {baud / 1e6:g} M | {every} | {e} | {load:.1f} |"
                    print(row, flush=True)
                    continue
                print(
                    f"| {r['rate']:g} | {r['baud'] / 1e6:g} M | {r['every']} "
                    f"| {r['achieved']:.1f} | {1e3 * r['p50']:.3f} | {1e3 * r['p99']:.3f} "
                    f"| {1e3 * r['max']:.3f} | {r['overruns']}/{r['frames']} "
                    f"| {r['stalls']} ({r['reply_stalls']}) | {r['skipped']} "
                    f"| {r['behind']} ({r['carried']}) | {1e3 * r['checked']:.2f} "
                    f"| {r['deferred']} | {r['collisions']} | {r['comm']} "
                    f"| {r['bytes']:.1f} | {r['minimum']:.1f} "
                    f"| {1e3 * r['peer'][0]:.2f} / {1e3 * r['peer'][1]:.2f} "
                    f"| {r['alone'][0]:.1f} ({r['alone'][1]}) "
                    f"| {r['achieved'] / r['alone'][0]:.3f} "
                    f"| {os.getloadavg()[0]:.1f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
