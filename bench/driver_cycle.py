"""What the driver's own cycle costs per frame, against a minimal responder.

One frame of a stream to 3 servos: a Sync Write of Goal Position, a Fast Sync
Read of present current, velocity and position (126..135), the reply checks
(id, length, ERR byte: ``ServoBus.read_block`` and ``check_block``) and the
telemetry decoding the streamer does (``Streamer._read_state``'s arrays). The
responder is a separate process on the pty master that answers each frame's
46 request bytes with one precomputed 50-byte reply, so the host's figure is
the driver's cost, not an emulator's.

Peers, in the same run: the same bytes through the same pty with bare
``os.write``/``os.read`` of precomputed packets (the floor of a Python round
trip on this host), and the same cycle through the SDK's packet path (what the
driver did before ``drivers.frame_packets``). Reference: the wire time of the
96 bytes at 4 Mbps (10 bits a byte: 240 us; docs/dynamixel.md). Each pass
runs with 0, then 1 CPU-bound process beside it (``--hogs``), the driver and
the responder at the priority the streamer takes on the wall clock
(``drivers.priority``; ``--normal``: without). The driver's cycle is timed
twice: its read done at once, and split as the streamer does it (the request
after the goal, ``collect`` for the reply). Prints per-frame
wall and CPU time (p50, p90, p99), their ratio to the wire time, and the
machine load.

    .venv/bin/python bench/driver_cycle.py [--frames 3000] [--hogs 0 1]
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import time
import tty

import numpy as np

from trajgen.drivers.bus import ServoBus, reply_problem
from trajgen.drivers.control_table import Register, model_named
from trajgen.drivers.priority import stream_priority
from trajgen.drivers.protocol import BROADCAST_ID, encode_fast_sync_status
from trajgen.drivers.units import JointMap, to_signed
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


def percentiles(values) -> tuple[float, float, float]:
    """p50, p90, p99 of ``values``."""
    return tuple(float(v) for v in np.percentile(np.asarray(values), [50, 90, 99]))


def _telemetry(joints, models, table) -> None:
    """What ``Streamer._read_state`` makes of a read: the arrays of one telemetry row."""
    raw = np.array(table, dtype=float)
    current = np.array([m.current_a(row[0]) for m, row in zip(models, table, strict=True)])
    joints.to_rad(raw[:, 2]), joints.velocity_to_rad_s(raw[:, 1])
    joints.signed_joint(current)


def driver_frames(port: str, frames: int, split: bool = False) -> tuple[list[float], list[float]]:
    """Per-frame (wall, CPU) seconds of the driver's cycle (``split``: the read as the
    streamer does it, ``request_block`` after the goal and ``collect``)."""
    joints = JointMap()
    model = model_named("XM430-W350")
    walls, cpus = [], []
    with ServoBus(port, baud=BAUD, latency_ms=500.0) as bus:  # a busy host: no timeouts
        for i in IDS:
            bus.add_servo(i, model)
        goal = dict.fromkeys(IDS, ZERO_TICK)
        models = [bus.models[i] for i in IDS]
        for k in range(frames + 100):  # the first 100 warm up
            w0, c0 = time.perf_counter(), time.process_time()
            bus.sync_write(Register.GOAL_POSITION, goal)
            if split:
                block = bus.collect(bus.request_block(IDS, STATE, fast=True))
            else:
                block = bus.read_block(IDS, STATE, fast=True)
            bus.check_block(block, "streaming")
            _telemetry(joints, models, block.table)
            w1, c1 = time.perf_counter(), time.process_time()
            if k >= 100:
                walls.append(w1 - w0)
                cpus.append(c1 - c0)
    return walls, cpus


def sdk_frames(port: str, frames: int) -> tuple[list[float], list[float]]:
    """Per-frame (wall, CPU) seconds of the same cycle through the SDK's packet path.

    What ``ServoBus`` did before ``drivers.frame_packets``: ``syncWriteTxOnly``,
    ``syncReadTx`` + ``fastSyncReadRx``, the same reply checks (id, LEN, each
    part's id, ERR bytes) and decoding, the same telemetry arrays.
    """
    joints = JointMap()
    model = model_named("XM430-W350")
    length, block = 10, 14  # 126..135; ERR ID DATA CRC2 per servo
    walls, cpus = [], []
    with ServoBus(port, baud=BAUD, latency_ms=500.0) as bus:
        ph, sdk_port = bus._ph, bus._port
        models = [model] * len(IDS)
        param = []
        for i in IDS:
            param += [i, *ZERO_TICK.to_bytes(4, "little")]
        for k in range(frames + 100):
            w0, c0 = time.perf_counter(), time.process_time()
            assert ph.syncWriteTxOnly(sdk_port, 116, 4, list(param), len(param)) == 0
            assert ph.syncReadTx(sdk_port, 126, length, list(IDS), len(IDS), True) == 0
            data, result, _ = ph.fastSyncReadRx(sdk_port, BROADCAST_ID, block * len(IDS))
            assert reply_problem(ph.last_rx, BROADCAST_ID, 1 + block * len(IDS)) is None
            table = []
            for j, servo_id in enumerate(IDS):
                part = data[j * block : (j + 1) * block]
                assert result == 0 and part[1] == servo_id and part[0] == 0
                raw = bytes(part[2 : 2 + length])
                table.append(
                    [
                        to_signed(int.from_bytes(raw[a : a + n], "little"), n)
                        for a, n in ((0, 2), (2, 4), (6, 4))
                    ]
                )
            _telemetry(joints, models, table)
            w1, c1 = time.perf_counter(), time.process_time()
            if k >= 100:
                walls.append(w1 - w0)
                cpus.append(c1 - c0)
    return walls, cpus


def bare_frames(slave: int, frames: int, request: bytes, reply_b: int) -> tuple[list[float], None]:
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
    return walls, None


def hog() -> None:
    """A CPU-bound process (the load beside the bench)."""
    x = 0
    while True:
        x = (x * 1103515245 + 12345) & 0xFFFFFFFF


def raised_responder(master: int, request_b: int, reply: bytes) -> None:
    """``responder`` at the stream thread's priority: it stands for servos, not for the host."""
    with stream_priority():
        responder(master, request_b, reply)


def on_a_pty(ctx, reply: bytes, run, raised: bool):
    """``run(slave_fd, slave_name)`` against the responder process on a fresh pty."""
    master, slave = os.openpty()
    tty.setraw(slave)
    target = raised_responder if raised else responder
    proc = ctx.Process(target=target, args=(master, SYNC_WRITE_B + READ_REQUEST_B, reply))
    proc.start()
    try:
        with stream_priority() if raised else contextlib.nullcontext():
            return run(slave, os.ttyname(slave))
    finally:
        proc.terminate()
        proc.join()
        os.close(slave)
        os.close(master)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument(
        "--hogs", type=int, nargs="+", default=[0, 1], help="CPU-bound processes beside each pass"
    )
    parser.add_argument(
        "--normal",
        action="store_true",
        help="run at the normal priority (default: as the streamer runs on the wall clock, "
        "SCHED_FIFO where permitted, the responder too)",
    )
    args = parser.parse_args(argv)
    reply = reply_bytes()
    wire_b = SYNC_WRITE_B + READ_REQUEST_B + len(reply)
    wire_s = wire_b * 10 / BAUD
    ctx = multiprocessing.get_context("fork")
    request = bytes(SYNC_WRITE_B + READ_REQUEST_B)
    paths = (
        (
            "bare os.write/os.read (floor)",
            lambda fd, name: bare_frames(fd, args.frames, request, len(reply)),
        ),
        ("SDK packet path (before)", lambda fd, name: sdk_frames(name, args.frames)),
        (
            "driver: ServoBus (frame_packets) + checks + telemetry",
            lambda fd, name: driver_frames(name, args.frames),
        ),
        (
            "driver, split phase (request_block + collect)",
            lambda fd, name: driver_frames(name, args.frames, split=True),
        ),
    )
    print(f"# driver cycle, 3 servos, {args.frames} frames; load before {os.getloadavg()}")
    if args.normal:
        print("scheduling: normal")
    else:
        with stream_priority() as how:
            print(f"scheduling (driver and responder): {how}")
    print(f"wire time of the frame's {wire_b} bytes at {BAUD / 1e6:g} Mbps: {1e6 * wire_s:.0f} us")
    print()
    print(
        "| CPU hogs | path | load | wall p50 / p90 / p99 us | CPU p50 / p90 / p99 us "
        "| wall p50 / wire | CPU p50 / wire | CPU p90 / wire |"
    )
    print("|---:|---|---:|---|---|---:|---:|---:|")
    for n_hogs in args.hogs:
        hogs = [ctx.Process(target=hog, daemon=True) for _ in range(n_hogs)]
        for h in hogs:
            h.start()
        try:
            for name, run in paths:
                walls, cpus = on_a_pty(ctx, reply, run, raised=not args.normal)
                load = os.getloadavg()[0]
                w = percentiles(walls)
                walls_text = " / ".join(f"{1e6 * v:.0f}" for v in w)
                if cpus is None:
                    print(
                        f"| {n_hogs} | {name} | {load:.1f} | {walls_text} | "
                        f"| {w[0] / wire_s:.2f} | | |"
                    )
                    continue
                c = percentiles(cpus)
                cpus_text = " / ".join(f"{1e6 * v:.0f}" for v in c)
                print(
                    f"| {n_hogs} | {name} | {load:.1f} | {walls_text} | {cpus_text} "
                    f"| {w[0] / wire_s:.2f} | {c[0] / wire_s:.2f} | {c[1] / wire_s:.2f} |"
                )
        finally:
            for h in hogs:
                h.terminate()
                h.join()
    print()
    print("goal: driver CPU and wall within 1.5 x the wire time")
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
