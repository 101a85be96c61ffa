"""`trajgen virtual-bus` (real time) serving a 1 kHz SDK client: missed and late replies.

Starts `trajgen virtual-bus` (the built-in gimbal, MuJoCo behind it, stepped in a
process of its own: ``VirtualBus(plant_process=True)``) as its own process and,
through the official dynamixel-sdk only (``GroupSyncWrite``,
``GroupSyncRead.fastSyncRead``), runs what a 1 kHz controller does: each
millisecond, one Sync Write of Goal Position to the 3 servos (a small sine
about the middle tick) and one Fast Sync Read of present current, velocity and
position (126..135). A cycle's reply is *missed* when the SDK's result is not
success (no status packet within its timeout, 34 ms, or a corrupt one), and
*late* when the cycle took longer than its period (1 ms): two separate counts.
Cycles are paced on deadlines; a cycle that starts more than a period after its
deadline is a *slip* of the client, and the slots already gone are skipped
(cycles done against 1 kHz slots says how many the server let through).

The client's settings, as a real-time controller on Linux would have them:
``SCHED_FIFO`` where permitted (``drivers.priority``), and the SDK's serial port
reading with a 1 ms timeout (``PortHandler.ser.timeout = 0.001`` after
``setBaudRate``) instead of the SDK's ``timeout=0``. The SDK's receive loop is
unchanged; with ``timeout=0`` it spins on non-blocking reads for up to its
34 ms, and a spinning ``SCHED_FIFO`` process starves the kernel's tty worker
(a normal-priority kworker that moves bytes through a pty, and through a USB
serial adapter's driver alike) on its core: the reply it waits for is then
held back until the SDK gives up. With a timeout the same loop sleeps in
``select`` until the bytes come. ``--spin`` runs the SDK's default
(``timeout=0``) to show it.

Peer, in the same run: the same client against a minimal responder process
on a pty that answers each cycle with one precomputed reply, at the priority
`trajgen virtual-bus` serves at (the client's own cost on this host, and what
a pty allows). Prints cycles, missed and late counts and shares, reply-time
percentiles, the bus's own summary (simulated against wall time, stale
replies) and the machine load.

Goal (issue 24): under 0.1 % missed replies over 10 s, and slots served and the
late share within about 1.2x of the peer's in the same run.

    .venv/bin/python bench/virtual_bus_1khz.py [--seconds 10] [--rate 1000] [--spin]
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import time
import tty

import numpy as np
from driver_cycle import responder  # bench/: the same minimal responder
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

from trajgen.drivers.priority import stream_priority
from trajgen.drivers.protocol import encode_fast_sync_status
from trajgen.servo_table import ZERO_TICK

IDS = (1, 2, 3)
TORQUE_ENABLE, GOAL_POSITION, BLOCK_START, BLOCK_LENGTH = 64, 116, 126, 10
SYNC_WRITE_B = 14 + 5 * len(IDS)  # header..CRC of a 4-byte sync write to 3 servos
READ_REQUEST_B = 14 + len(IDS)
MIDDLE_TICK, AMPLITUDE_TICKS = ZERO_TICK, 200
READ_TIMEOUT_S = 1e-3  # the SDK port's pyserial read timeout (the SDK's own is 0: spin)


def client(port_name: str, seconds: float, rate_hz: float, torque: bool, spin: bool) -> dict:
    """Run the 1 kHz client for ``seconds``; per-cycle results.

    The client runs as a real-time controller would (``drivers.priority``:
    SCHED_FIFO where permitted), so that the figures are the server's; its
    port reads with a timeout of ``READ_TIMEOUT_S`` unless ``spin``.
    """
    port = PortHandler(port_name)
    port.openPort()
    port.setBaudRate(4_000_000)
    if not spin:  # after setBaudRate, which opens the pyserial port with timeout=0
        port.ser.timeout = READ_TIMEOUT_S
    ph = PacketHandler(2.0)
    if torque:
        for i in IDS:
            ph.write1ByteTxRx(port, i, TORQUE_ENABLE, 1)
    writer = GroupSyncWrite(port, ph, GOAL_POSITION, 4)
    reader = GroupSyncRead(port, ph, BLOCK_START, BLOCK_LENGTH)
    for i in IDS:
        writer.addParam(i, list(MIDDLE_TICK.to_bytes(4, "little")))
        reader.addParam(i)
    period = 1.0 / rate_hz
    took, missed, slips = [], 0, 0
    with stream_priority() as scheduling:
        start = time.perf_counter() + 0.05
        k = 0
        while True:
            deadline = start + k * period
            now = time.perf_counter()
            if deadline - start >= seconds:
                break
            if now < deadline:
                time.sleep(deadline - now)  # no spinning (see the module docstring)
            elif now - deadline > period:
                slips += 1
            t0 = time.perf_counter()
            goal = round(MIDDLE_TICK + AMPLITUDE_TICKS * math.sin(2 * math.pi * 0.5 * k * period))
            for i in IDS:
                writer.changeParam(i, list(goal.to_bytes(4, "little")))
            ok = writer.txPacket() == COMM_SUCCESS
            ok = reader.fastSyncRead() == COMM_SUCCESS and ok
            ok = ok and all(reader.isAvailable(i, BLOCK_START, BLOCK_LENGTH) for i in IDS)
            took.append(time.perf_counter() - t0)
            missed += not ok
            k += 1
            if time.perf_counter() > start + k * period:  # behind: skip the slots already gone
                k = max(k, math.ceil((time.perf_counter() - start) / period))
    port.closePort()
    took = np.array(took)
    return {
        "cycles": len(took),
        "slots": round(seconds * rate_hz),
        "missed": missed,
        "late": int(np.sum(took > period)),
        "slips": slips,
        "took": took,
        "period": period,
        "scheduling": scheduling,
    }


def against_virtual_bus(seconds: float, rate_hz: float, spin: bool) -> tuple[dict, str]:
    trajgen = shutil.which("trajgen", path=os.path.dirname(sys.executable)) or "trajgen"
    proc = subprocess.Popen(
        [trajgen, "virtual-bus"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        result = client(proc.stdout.readline().strip(), seconds, rate_hz, torque=True, spin=spin)
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    summary = " ".join(line.split(": ", 1)[-1] for line in err.splitlines()[1:])
    return result, summary


def raised_responder(master: int, request_b: int, reply: bytes) -> None:
    """``responder`` at the priority `trajgen virtual-bus` serves at."""
    with stream_priority():
        responder(master, request_b, reply)


def against_responder(seconds: float, rate_hz: float, spin: bool) -> dict:
    data = (0).to_bytes(2, "little") + (0).to_bytes(4, "little") + MIDDLE_TICK.to_bytes(4, "little")
    reply = encode_fast_sync_status([(0, i, data) for i in IDS])
    master, slave = os.openpty()
    tty.setraw(slave)
    proc = multiprocessing.get_context("fork").Process(
        target=raised_responder, args=(master, SYNC_WRITE_B + READ_REQUEST_B, reply)
    )
    proc.start()
    try:
        return client(os.ttyname(slave), seconds, rate_hz, torque=False, spin=spin)
    finally:
        proc.terminate()
        proc.join()
        os.close(slave)
        os.close(master)


def row(name: str, r: dict, load: float) -> str:
    took_ms = 1e3 * r["took"]
    p50, p99 = np.percentile(took_ms, [50, 99])
    return (
        f"| {name} | {load:.1f} | {r['cycles']} / {r['slots']} "
        f"| {r['missed']} ({100 * r['missed'] / r['cycles']:.3f} %) "
        f"| {r['late']} ({100 * r['late'] / r['cycles']:.2f} %) | {r['slips']} | {p50:.3f} "
        f"| {p99:.3f} | {took_ms.max():.1f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=1000.0, help="client rate (Hz)")
    parser.add_argument(
        "--spin", action="store_true", help="the SDK's port as it opens it (timeout=0: spinning)"
    )
    args = parser.parse_args()
    reads = "spinning (timeout=0)" if args.spin else f"timeout {1e3 * READ_TIMEOUT_S:g} ms"
    print(
        f"# {args.rate:g} Hz SDK client: sync write + fast sync read of {len(IDS)} servos, "
        f"{args.seconds:g} s; port reads: {reads}"
    )
    print(f"{os.cpu_count()} cores; load before {os.getloadavg()}")
    print()
    print(
        "| served by | load | cycles / 1 kHz slots | missed | late (> period) | client slips "
        "| p50 ms | p99 ms | max ms |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    peer = against_responder(args.seconds, args.rate, args.spin)
    print(row("minimal responder (peer)", peer, os.getloadavg()[0]), flush=True)
    result, summary = against_virtual_bus(args.seconds, args.rate, args.spin)
    print(row("trajgen virtual-bus", result, os.getloadavg()[0]))
    print()
    print(f"bus: {summary}")
    print(f"client: {result['scheduling']}")
    share = 100 * result["missed"] / result["cycles"]
    print(
        f"missed replies: {share:.3f} % (goal < 0.1 %); 1 kHz slots served: "
        f"{result['cycles']} of {result['slots']}; load after {os.getloadavg()}"
    )


if __name__ == "__main__":
    main()
