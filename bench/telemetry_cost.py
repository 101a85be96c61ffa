"""What telemetry costs the stream: MCAP (writer process) against CSV (in the stream's thread).

Two measurements, each against CSV telemetry measured in the same run:

1. The stream thread's cost per row: ``TelemetryWriter.write`` timed over
   ``--rows`` rows (CSV encodes and flushes each row itself; MCAP only queues
   it), and how long the MCAP writer process then takes to encode and finish
   the file (``close``), as rows per second.
   Then the report added to the MCAP file after the stream (a copy), timed.
2. Timing of a real stream: the same 200 Hz trajectory streamed through the
   driver, dynamixel-sdk and pyserial to the virtual bus on a pseudo-terminal
   (first-order servos, wall clock) with no telemetry, CSV and MCAP, in
   alternating rounds; period error p50 / p99 / max, overruns and stalls.

Run: .venv/bin/python bench/telemetry_cost.py [--rows 20000] [--seconds 3] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.telemetry import TelemetryWriter, add_report, telemetry_columns
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.stream import JointTrajectory

JOINTS = ("pan", "tilt", "roll")


def rows(n: int) -> list[list]:
    """``n`` telemetry rows of random values, by column."""
    rng = np.random.default_rng(0)
    columns = telemetry_columns(JOINTS)
    bookkeeping = {"frame": 0, "phase": "stream", "t_s": 0.0, "sent_s": 0.0, "lateness_s": 1e-5}
    out = []
    for k in range(n):
        row = []
        for c in columns:
            if c == "frame":
                row.append(k)
            elif c in ("t_s", "sent_s", "clock_s"):
                row.append(k / 200)
            elif c in bookkeeping:
                row.append(bookkeeping[c])
            elif c.startswith("goal_tick_"):
                row.append(int(rng.integers(1000, 3000)))  # any goal register value
            else:
                row.append(float(rng.normal()))
        out.append(row)
    return out


def write_cost(path: Path, data: list[list]) -> tuple[float, float]:
    """Seconds per ``write`` on the caller's thread, and seconds ``close`` took."""
    writer = TelemetryWriter(path, JOINTS)
    start = time.perf_counter()
    for row in data:
        writer.write(row)
    per_row = (time.perf_counter() - start) / len(data)
    start = time.perf_counter()
    writer.close()
    return per_row, time.perf_counter() - start


def trajectory(rate_hz: float, seconds: float) -> JointTrajectory:
    t = np.arange(round(seconds * rate_hz) + 1) / rate_hz
    w = 2 * np.pi * np.array([0.5, 0.7, 0.3])
    q = 0.3 * (1 - np.cos(t[:, None] * w))
    return JointTrajectory(t, q, 0.3 * w * np.sin(t[:, None] * w), 0.3 * w**2 * q, rate_hz)


def stream(telemetry: Path | None, seconds: float) -> dict:
    traj = trajectory(200.0, seconds)
    joints = JointMap()
    with VirtualBus(FirstOrderPlant(time_constant_s=0.01), lockstep_dt_s=1 / 200) as virtual:
        with ServoBus(virtual.port) as bus:
            bring_up(bus, joints, ("XM430-W350",) * 3, traj)
            streamer = Streamer(bus, joints, telemetry=telemetry, max_delay_s=None)
            stats = streamer.run(traj)
    return {
        "p50": stats.period_error_p50_s,
        "p99": stats.period_error_p99_s,
        "max": stats.period_error_max_s,
        "overruns": stats.overruns,
        "stalls": stats.stalls,
        "frames": stats.frames_sent,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=20_000)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    print(f"# Telemetry cost ({platform.processor() or platform.machine()}, {os.cpu_count()} cpus)")
    print()
    data = rows(args.rows)
    with tempfile.TemporaryDirectory() as folder:
        print(f"load before: {os.getloadavg()[0]:.2f}")
        print()
        print("| writer | write() on the stream's thread (us/row) | close (s) | encoded rows/s |")
        print("|---|---:|---:|---:|")
        costs = {}
        for suffix in (".csv", ".mcap"):
            per_row, close_s = write_cost(Path(folder) / f"t{suffix}", data)
            costs[suffix] = per_row
            rate = f"{args.rows / close_s:,.0f}" if suffix == ".mcap" else "(in write)"
            print(f"| {suffix} | {1e6 * per_row:.2f} | {close_s:.3f} | {rate} |")
        print()
        ratio = costs[".mcap"] / costs[".csv"]
        print(f"MCAP / CSV write() cost on the stream's thread: {ratio:.2f}")
        size = (Path(folder) / "t.mcap").stat().st_size
        print(f"MCAP file: {size / args.rows:.0f} B/row (zstd, 16 KiB chunks)")
        report = {"status": 0, "stopped_by": "", "on_stop": "hold", "stop_errors": []}
        report["stream"] = {"frames_sent": args.rows, "frames_planned": args.rows}
        start = time.perf_counter()
        add_report(Path(folder) / "t.mcap", report)
        copy_s = time.perf_counter() - start
        print(f"add_report (after the stream, copies the file): {copy_s:.2f} s")
        print(f"load after: {os.getloadavg()[0]:.2f}")
        print()
        print(f"Streams of {args.seconds:g} s at 200 Hz, {args.rounds} rounds, alternating:")
        print()
        print("| telemetry | round | p50 (ms) | p99 (ms) | max (ms) | overruns | stalls | load |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        for k in range(args.rounds):
            for suffix in (None, ".csv", ".mcap"):
                path = None if suffix is None else Path(folder) / f"s{k}{suffix}"
                r = stream(path, args.seconds)
                print(
                    f"| {suffix or 'none'} | {k + 1} | {1e3 * r['p50']:.3f} | {1e3 * r['p99']:.3f} "
                    f"| {1e3 * r['max']:.3f} | {r['overruns']} | {r['stalls']} "
                    f"| {os.getloadavg()[0]:.2f} |"
                )


if __name__ == "__main__":
    main()
