"""What the driver's own cycle costs per frame, against a minimal responder.

One frame of a stream to 3 servos: a Sync Write of Goal Position, a Fast Sync
Read of present current, velocity and position (126..135), the reply checks
(id, length, ERR byte: ``ServoBus.read_block`` and ``check_block``) and the
telemetry decoding the streamer does (``Streamer._read_state``'s arrays). The
responder is a separate process on the pty master that answers each frame's
46 request bytes with one precomputed 50-byte reply, so the host's figure is
the driver's cost, not an emulator's.

Peer, in the same run: the same bytes through the same pty with bare
``os.write``/``os.read`` of precomputed packets (the floor of a Python round
trip on this host). Reference: the wire time of the 96 bytes at 4 Mbps
(10 bits a byte: 240 us; docs/dynamixel.md). Prints per-frame wall and CPU
time (median, p90), their ratio to the wire time, and the machine load.

    .venv/bin/python bench/driver_cycle.py [--frames 3000]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
import tty

import numpy as np

from trajgen.drivers.bus import ServoBus
from trajgen.drivers.control_table import Register, model_named
from trajgen.drivers.protocol import encode_fast_sync_status
from trajgen.drivers.units import JointMap
from trajgen.servo_table import ZERO_TICK

IDS = (1, 2, 3)
STATE = (Register.PRESENT_CURRENT, Register.PRESENT_VELOCITY, Register.PRESENT_POSITION)
SYNC_WRITE_B, READ_REQUEST_B = 29, 17
BAUD = 4_000_000
READ_BYTES = 1 << 12  # most bytes the responder reads at once


def reply_bytes() -> bytes:
    """A fast sync read reply for IDS: current 0, velocity 0, position at the zero tick."""
    data = (0).to_bytes(2, "little") + (0).to_bytes(4, "little") + ZERO_TICK.to_bytes(4, "little")
    return encode_fast_sync_status([(0, i, data) for i in IDS])


def responder(master: int, request_b: int, reply: bytes) -> None:
    """Answer every ``request_b`` bytes read with ``reply``, until the pty closes."""
    pending = 0
    while True:
        try:
            data = os.read(master, READ_BYTES)
        except OSError:
            return
        if not data:
            return
        pending += len(data)
        while pending >= request_b:
            pending -= request_b
            os.write(master, reply)


def percentiles(values) -> tuple[float, float]:
    a = np.asarray(values)
    return float(np.median(a)), float(np.percentile(a, 90))


def driver_frames(port: str, frames: int) -> tuple[list[float], list[float]]:
    """Per-frame (wall, CPU) seconds of the driver's cycle."""
    joints = JointMap()
    model = model_named("XM430-W350")
    walls, cpus = [], []
    with ServoBus(port, baud=BAUD, latency_ms=50.0) as bus:  # a busy host: no timeouts
        for i in IDS:
            bus.add_servo(i, model)
        goal = dict.fromkeys(IDS, ZERO_TICK)
        models = [bus.models[i] for i in IDS]
        for k in range(frames + 100):  # the first 100 warm up
            w0, c0 = time.perf_counter(), time.process_time()
            bus.sync_write(Register.GOAL_POSITION, goal)
            block = bus.read_block(IDS, STATE, fast=True)
            bus.check_block(block, "streaming")
            raw = np.array(block.table, dtype=float)
            current = np.array([m.current_a(row[0]) for m, row in zip(models, block.table)])
            joints.to_rad(raw[:, 2]), joints.velocity_to_rad_s(raw[:, 1])
            joints.signed_joint(current)
            w1, c1 = time.perf_counter(), time.process_time()
            if k >= 100:
                walls.append(w1 - w0)
                cpus.append(c1 - c0)
    return walls, cpus


def bare_frames(slave: int, frames: int, request: bytes, reply_b: int) -> list[float]:
    """Per-frame wall seconds of bare os.write / os.read of the same bytes."""
    walls = []
    for k in range(frames + 100):
        w0 = time.perf_counter()
        os.write(slave, request)
        got = 0
        while got < reply_b:
            got += len(os.read(slave, reply_b - got))
        if k >= 100:
            walls.append(time.perf_counter() - w0)
    return walls


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3000)
    args = parser.parse_args(argv)
    reply = reply_bytes()
    wire_b = SYNC_WRITE_B + READ_REQUEST_B + len(reply)
    wire_s = wire_b * 10 / BAUD
    ctx = multiprocessing.get_context("fork")
    rows = []
    load_before = os.getloadavg()

    # The peer: bare bytes on a pty of its own.
    master, slave = os.openpty()
    tty.setraw(slave)
    proc = ctx.Process(target=responder, args=(master, SYNC_WRITE_B + READ_REQUEST_B, reply))
    proc.start()
    bare = bare_frames(slave, args.frames, bytes(SYNC_WRITE_B + READ_REQUEST_B), len(reply))
    os.close(slave)
    proc.terminate()
    proc.join()
    os.close(master)
    rows.append(("bare os.write/os.read (peer)", *percentiles(bare), None))

    master, slave = os.openpty()
    tty.setraw(slave)
    proc = ctx.Process(target=responder, args=(master, SYNC_WRITE_B + READ_REQUEST_B, reply))
    proc.start()
    try:
        walls, cpus = driver_frames(os.ttyname(slave), args.frames)
    finally:
        proc.terminate()
        proc.join()
        os.close(slave)
        os.close(master)
    rows.append(("driver: ServoBus + SDK + checks + telemetry", *percentiles(walls), cpus))

    print(f"# driver cycle, 3 servos, {args.frames} frames; load before {load_before}")
    print(f"wire time of the frame's {wire_b} bytes at {BAUD / 1e6:g} Mbps: {1e6 * wire_s:.0f} us")
    print()
    print("| path | wall p50 us | wall p90 us | CPU p50 us | CPU p90 us | CPU p50 / wire |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, p50, p90, cpu in rows:
        if cpu is None:
            print(f"| {name} | {1e6 * p50:.0f} | {1e6 * p90:.0f} | | | |")
            continue
        c50, c90 = percentiles(cpu)
        print(
            f"| {name} | {1e6 * p50:.0f} | {1e6 * p90:.0f} | {1e6 * c50:.0f} | {1e6 * c90:.0f} "
            f"| {c50 / wire_s:.2f} |"
        )
    print()
    print(f"driver wall p50 / peer wall p50: {rows[1][1] / rows[0][1]:.2f}")
    print(f"driver wall p50 / wire time: {rows[1][1] / wire_s:.2f} (goal: <= 1.5)")
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
