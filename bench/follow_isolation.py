"""Late frames of `trajgen follow --virtual`: on simulated time paced by the wall clock
(now) against the wall clock (before), with and without keyframe lines, with and without
CPU hogs beside it.

Runs the command's own code (``trajgen.cli.follow.follow``) in this process: the
built-in keyframe file at 200 Hz against the lock-step virtual bus (its MuJoCo
plant steps in the stream thread's packets), CSV telemetry written by the stream
thread, and, in the arms with changes, a keyframe line every ``--every`` s of wall
time for ``--seconds`` (a live source: parsed and planned on the reader thread,
spliced between frames); without changes, stdin stays open as long and sends
nothing. Arms, in the same run:

- now: ``Session.follow``'s default on a virtual bus, a ``drivers.clock.PacedClock``
  (simulated time, one period per frame, never ahead of the wall clock, shifted
  off when more than 50 ms behind it);
- before (the peer): the wall clock, the stream thread raised (``SCHED_FIFO`` where
  permitted, ``drivers.priority``), the probe before the first goal, the lateness
  bound (1 s): what ``follow --virtual`` did until this change.

Printed per arm: the exit status (1: the stream stopped, e.g. ``StreamLagging``),
frames streamed, frames reached later than 1 ms / half a period / a period after
their deadline on the wall clock (before: ``lateness_s`` of the telemetry, after
the stream's stall shifts; now: the paced clock's lag at each deadline, after its
shifts), p99 and max of that, the stream's stalls (before) or the clock's shifts
(now), how far behind the wall clock the stream ended (before: ``delay_s``, the
stalls' shifts; now: ``PacedClock.behind_now_s``), and the load.

    .venv/bin/python bench/follow_isolation.py [--seconds 5] [--hogs 2] [--rounds 1]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import multiprocessing
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from driver_cycle import hog  # bench/: the same CPU-bound process

from trajgen.cli import build_parser
from trajgen.cli.follow import follow
from trajgen.drivers.clock import WALL_CLOCK, PacedClock
from trajgen.drivers.session import Session

RATE_HZ = 200.0


class RecordingPacedClock(PacedClock):
    """The paced clock, recording its lag (s) behind the wall clock at every deadline."""

    def __init__(self) -> None:
        super().__init__()
        self.lags: list[float] = []

    def sleep_until(self, deadline_s: float) -> None:
        super().sleep_until(deadline_s)
        self.lags.append(self.lag_s)


def keyframe_lines(seconds: float, every_s: float, changes: bool):
    """Lines on the wall clock, as a live source: pan and tilt to and fro every
    ``every_s``; without ``changes``, none (the input stays open as long)."""
    end = time.monotonic() + seconds
    k = 0
    while time.monotonic() < end:
        time.sleep(every_s)
        if changes:
            pan, tilt = (25, 8) if k % 2 else (-25, -8)
            yield (json.dumps({"in": 0.6, "pan": pan, "tilt": tilt}) + "\n").encode()
            k += 1


def one_run(paced: bool, changes: bool, seconds: float, every_s: float) -> dict:
    clock = RecordingPacedClock() if paced else WALL_CLOCK
    real_follow = Session.follow

    def follow_on(self, follower, lines, **kwargs):
        return real_follow(self, follower, lines, clock=clock)

    Session.follow = follow_on  # the only difference between the arms
    with tempfile.TemporaryDirectory() as tmp:
        log, out = Path(tmp) / "t.csv", Path(tmp) / "out.json"
        args = build_parser().parse_args(
            ["follow", "--virtual", "--configure", "--telemetry", str(log), "--json", str(out)]
        )
        try:
            with (
                contextlib.redirect_stdout(io.StringIO()),
                contextlib.redirect_stderr(io.StringIO()),
            ):
                status = follow(args, keyframe_lines(seconds, every_s, changes))
        finally:
            Session.follow = real_follow
        with open(log, newline="") as f:
            late = np.array(
                [float(r["lateness_s"]) for r in csv.DictReader(f) if r["phase"] == "stream"]
            )
        report = json.loads(out.read_text())
    stream = report["stream"]
    if stream is None or not len(late):
        return {"status": status, "frames": 0}
    if paced:
        late = np.array(clock.lags[-len(late) :])  # the stream's deadlines (not the approach)
        jumps, behind = clock.shifts, clock.behind_now_s
    else:
        jumps, behind = stream["stalls"], stream["delay_s"]
    return {
        "status": status,
        "frames": len(late),
        "late": late,
        "jumps": jumps,
        "behind": behind,
        "accepted": report["follow"]["accepted"],
        "scheduling": stream.get("scheduling") or "-",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="lines (or none) for (s)")
    parser.add_argument("--every", type=float, default=0.1, help="one line every (s)")
    parser.add_argument(
        "--hogs", type=int, default=2, help="CPU-bound processes in the loaded arms"
    )
    parser.add_argument("--rounds", type=int, default=1)
    args = parser.parse_args()
    period = 1.0 / RATE_HZ
    print(
        f"# trajgen follow --virtual, 200 Hz, {args.seconds:g} s of input, with changes a "
        f"line every {args.every:g} s"
    )
    print(f"{os.cpu_count()} cores; load before {os.getloadavg()}")
    print()
    print(
        "| hogs | changes | clock | load | exit | frames | lines taken | late > 1 ms "
        "| > half period | > period | p99 ms | max ms | stalls / shifts "
        "| behind at the end s | scheduling |"
    )
    print("|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    ctx = multiprocessing.get_context("fork")
    for _ in range(args.rounds):
        for n_hogs in (0, args.hogs):
            hogs = [ctx.Process(target=hog, daemon=True) for _ in range(n_hogs)]
            for h in hogs:
                h.start()
            try:
                for changes in (True, False):
                    for paced in (True, False):
                        r = one_run(paced, changes, args.seconds, args.every)
                        name = "now: paced simulated" if paced else "before: wall (peer)"
                        lines = "yes" if changes else "no"
                        head = f"| {n_hogs} | {lines} | {name} | {os.getloadavg()[0]:.1f} "
                        if not r["frames"]:
                            print(f"{head}| {r['status']} | 0 (no frame streamed) |", flush=True)
                            continue
                        late = r["late"]
                        print(
                            f"{head}| {r['status']} | {r['frames']} | {r['accepted']} "
                            f"| {int(np.sum(late > 1e-3))} | {int(np.sum(late > period / 2))} "
                            f"| {int(np.sum(late > period))} "
                            f"| {1e3 * np.percentile(late, 99):.2f} | {1e3 * late.max():.2f} "
                            f"| {r['jumps']} | {r['behind']:.2f} | {r['scheduling']} |",
                            flush=True,
                        )
            finally:
                for h in hogs:
                    h.terminate()
                    h.join()
    print()
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
