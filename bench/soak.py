"""Soak: a long stream over the virtual bus, checking stalls, jitter and memory.

Streams a smooth 3-joint path at 1000 Hz and at 500 Hz, ``--minutes`` each,
through the real driver, dynamixel-sdk and pyserial to the virtual bus on a
pseudo-terminal, with wire timing at 4 Mbps (10 bits a byte, 20 us servo
turnaround, Return Delay 0 as bring-up sets it). Present state is read back
every ``--read-every`` frames (fast sync read). The frames are generated one
at a time (an iterable of ``JointFrame``, as an online source would give
them), so the plan itself takes no memory.

Prints, per rate: frames planned and sent, achieved rate and its ratio to the
planned one, stalls (the stream's clock shifted: see ``drivers.streamer``) and
how far behind the plan the stream ended, period error p50 / p99 / max,
resident memory (RSS) after bring-up and at the end, the growth per frame
against the 170 B a frame that unbounded per-frame lists cost, and the load
average before and after (the machine is shared: figures are noisy).

The Bus Watchdog is set to its longest, 2.54 s (``--watchdog``): on a shared
machine the host stalls for more than the command line's 100 ms, which would
(rightly) stop the stream; here the stalls are counted instead.

``--latency-ms`` widens the reply timeouts likewise (the driver's default on
a pseudo-terminal is 16 ms: a reply more than about 34 ms late is a retry,
three in a row a fault).

Run: .venv/bin/python bench/soak.py [--minutes 10] [--read-every 1] [--watchdog 2.54]
[--latency-ms 16]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

import numpy as np

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.errors import DriverError
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus, WireTiming
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.stream import JointFrame

BAUD = 4_000_000
UNBOUNDED_BYTES_PER_FRAME = 170  # two float lists + the virtual bus goal log (issue 7)
_W = 2 * np.pi * np.array([0.05, 0.07, 0.03])  # slow sines (rad/s)


class SinePath:
    """Frames of ``0.3 (1 - cos w t)`` per joint, generated lazily.

    Parameters
    ----------
    rate_hz : float
    seconds : float
    """

    def __init__(self, rate_hz: float, seconds: float) -> None:
        self.rate_hz = rate_hz
        self.n = round(seconds * rate_hz) + 1

    def __len__(self) -> int:
        return self.n

    def __iter__(self):
        for k in range(self.n):
            t = k / self.rate_hz
            q = 0.3 * (1 - np.cos(_W * t))
            yield JointFrame(k, t, q, 0.3 * _W * np.sin(_W * t), 0.3 * _W**2 * np.cos(_W * t))

    @property
    def t(self) -> np.ndarray:
        """First and last time (s): what bring-up's checks need of the plan."""
        return np.array([0.0, (self.n - 1) / self.rate_hz])

    @property
    def q(self) -> np.ndarray:
        """The path's extremes (rad), first row the first frame, for bring-up's checks."""
        return np.array([np.zeros(3), np.full(3, 0.6)])


def rss_mb() -> float:
    """Resident set size of this process (MB), from /proc."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return math.nan


def soak(
    rate_hz: float, minutes: float, read_every: int, watchdog_s: float, latency_ms: float
) -> dict:
    """One long stream; returns its row of figures."""
    path = SinePath(rate_hz, 60 * minutes)
    joints = JointMap()
    plant = FirstOrderPlant(time_constant_s=0.01)
    load_before = os.getloadavg()[0]
    with VirtualBus(
        plant, lockstep_dt_s=1 / rate_hz, timing=WireTiming(baud=BAUD), goal_log_size=1000
    ) as virtual:
        with ServoBus(virtual.port, baud=BAUD, latency_ms=latency_ms) as bus:
            bring_up(bus, joints, ("XM430-W350",) * 3, path, watchdog_s=watchdog_s, configure=True)
            streamer = Streamer(bus, joints, telemetry_every=read_every, max_delay_s=None)
            rss_start = rss_mb()
            start = time.monotonic()
            try:
                streamer.run(path)
            except DriverError:
                pass  # reported below: the stream's statistics up to the fault
            elapsed = time.monotonic() - start
            rss_end = rss_mb()
    stats = streamer.stats
    frames = stats.frames_sent
    return {
        "rate": rate_hz,
        "planned": stats.frames_planned,
        "sent": frames,
        "achieved": stats.achieved_rate_hz,
        "stalls": stats.stalls,
        "stall_max_ms": 1e3 * stats.stall_max_s,
        "delay_s": stats.delay_s,
        "p50": 1e3 * stats.period_error_p50_s,
        "p99": 1e3 * stats.period_error_p99_s,
        "max": 1e3 * stats.period_error_max_s,
        "comm": stats.comm_errors,
        "rss_start": rss_start,
        "rss_end": rss_end,
        "growth_b_per_frame": (rss_end - rss_start) * 2**20 / max(frames, 1),
        "elapsed": elapsed,
        "fault": stats.fault,
        "load": (load_before, os.getloadavg()[0]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="stream length per rate")
    parser.add_argument("--read-every", type=int, default=1, help="read back every N frames")
    parser.add_argument("--rates", type=float, nargs="+", default=[1000.0, 500.0])
    parser.add_argument(
        "--watchdog",
        type=float,
        default=2.54,
        help="Bus Watchdog (s); the longest by default, so that a stall of the shared host "
        "is counted rather than ending the soak (a stall past it stops the stream)",
    )
    parser.add_argument(
        "--latency-ms",
        type=float,
        default=16.0,
        help="adapter latency (ms) in the reply timeouts (timeout = wire time + 2 x this + 2 ms)",
    )
    args = parser.parse_args()
    rows = [
        soak(rate, args.minutes, args.read_every, args.watchdog, args.latency_ms)
        for rate in args.rates
    ]
    print(
        f"virtual bus on a pty, wire timing {BAUD / 1e6:g} Mbps, {platform.machine()} "
        f"{platform.python_version()}, {os.cpu_count()} cores; {args.minutes:g} min per rate, "
        f"read back every {args.read_every} frame(s), Bus Watchdog {args.watchdog:g} s, "
        f"reply timeouts with {args.latency_ms:g} ms latency; "
        "period error = |actual - planned interval|"
    )
    print()
    print(
        "| rate Hz | frames sent/planned | achieved Hz (x planned) | stalls | longest stall ms "
        "| behind plan at end s | p50 ms | p99 ms | max ms | comm errors | RSS start / end MB "
        "| growth B/frame (x 170 B unbounded) | load 1 min before / after |"
    )
    print("|" + "---|" * 13)
    for r in rows:
        growth = r["growth_b_per_frame"]
        print(
            f"| {r['rate']:g} | {r['sent']}/{r['planned']} | {r['achieved']:.2f} "
            f"({r['achieved'] / r['rate']:.3f}) | {r['stalls']} | {r['stall_max_ms']:.1f} "
            f"| {r['delay_s']:.3f} | {r['p50']:.3f} | {r['p99']:.3f} | {r['max']:.3f} "
            f"| {r['comm']} | {r['rss_start']:.1f} / {r['rss_end']:.1f} "
            f"| {growth:.2f} ({growth / UNBOUNDED_BYTES_PER_FRAME:.3f}) "
            f"| {r['load'][0]:.2f} / {r['load'][1]:.2f} |"
        )
    for r in rows:
        minutes = r["elapsed"] / 60
        print(f"\n{r['rate']:g} Hz: ran {minutes:.1f} min; ", end="")
        print(f"stopped by fault: {r['fault']}" if r["fault"] else "no fault")


if __name__ == "__main__":
    main()
