"""Reply time of `trajgen virtual-bus` (real time) as the official SDK sees it.

Starts `trajgen virtual-bus` (the built-in gimbal, MuJoCo behind it) as its own
process, enables torque on servo 1 and, through dynamixel-sdk's own
PortHandler and PacketHandler:

- reads Present Position back to back for a few seconds (steady polling);
- reads it once after pauses of 0.5, 1 and 2 s (the case where the old bus
  simulated the whole pause on arrival and answered after the SDK gave up).

Prints reply-time percentiles against the peer, the SDK's reply timeout for
that read (34 ms: LATENCY_TIMER 16 ms x 2 + 2 ms + byte time), the number of
failed reads, how far simulated time is from wall time at the end, and the
machine load.

Run: .venv/bin/python bench/virtual_bus_latency.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

PRESENT_POSITION, TORQUE_ENABLE = 132, 64


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="steady polling time (s)")
    args = parser.parse_args()
    trajgen = shutil.which("trajgen", path=os.path.dirname(sys.executable)) or "trajgen"
    proc = subprocess.Popen(
        [trajgen, "virtual-bus"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    load_before = os.getloadavg()
    try:
        port = PortHandler(proc.stdout.readline().strip())
        port.openPort()
        port.setBaudRate(57_600)
        ph = PacketHandler(2.0)
        ph.write1ByteTxRx(port, 1, TORQUE_ENABLE, 1)
        port.setPacketTimeout(4 + 11)
        timeout_ms = port.packet_timeout

        def read_ms() -> tuple[float, bool]:
            start = time.perf_counter()
            _, result, error = ph.read4ByteTxRx(port, 1, PRESENT_POSITION)
            return 1e3 * (time.perf_counter() - start), result == COMM_SUCCESS and error == 0

        steady, failed = [], 0
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            took, ok = read_ms()
            steady.append(took)
            failed += not ok
        after_pause = []
        for pause_s in (0.5, 1.0, 2.0):
            time.sleep(pause_s)
            took, ok = read_ms()
            after_pause.append((pause_s, took, ok))
        port.closePort()
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    load_after = os.getloadavg()
    steady = np.array(steady)
    simulated = [line for line in err.splitlines() if "stopped after" in line]
    print("# trajgen virtual-bus (real time): reply time of a Present Position read")
    print()
    print(
        f"{os.cpu_count()} cores; load average {load_before[0]:.2f} before, "
        f"{load_after[0]:.2f} after; peer: the SDK's reply timeout, {timeout_ms:.1f} ms"
    )
    print()
    print("| reads | p50 ms | p99 ms | max ms | max / SDK timeout | failed |")
    print("|---:|---:|---:|---:|---:|---:|")
    p50, p99, worst = np.percentile(steady, 50), np.percentile(steady, 99), steady.max()
    print(
        f"| {len(steady)} | {p50:.2f} | {p99:.2f} | {worst:.2f} | {worst / timeout_ms:.2f} "
        f"| {failed} |"
    )
    print()
    print("| after a pause of | reply ms | / SDK timeout | ok |")
    print("|---:|---:|---:|---|")
    for pause_s, took, ok in after_pause:
        print(f"| {pause_s:g} s | {took:.2f} | {took / timeout_ms:.2f} | {ok} |")
    print()
    print(simulated[0].removeprefix("trajgen: ") if simulated else "(no summary from the bus)")


if __name__ == "__main__":
    main()
