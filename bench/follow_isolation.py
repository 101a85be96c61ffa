"""Late frames of `trajgen follow --virtual` with and without the stream thread's priority.

Runs the command's own code (``trajgen.cli.follow.follow``) in this process:
the built-in keyframe file at 200 Hz on the wall clock against the lock-step
virtual bus (its MuJoCo plant steps in the stream thread's packets), CSV
telemetry written by the stream thread, and a keyframe line every
``--every`` s for ``--seconds`` (parsed and planned on the reader thread,
spliced between frames). Arms, in the same run and alternated: the stream
thread raised (``Streamer(realtime=True)``, the default: ``SCHED_FIFO`` where
permitted and a 0.5 ms GIL switch interval, ``drivers.priority``) and the peer
without (``realtime=False``, as before), each with 0 and with ``--hogs``
CPU-bound processes beside it.

Printed per arm: the exit status (1: the stream fell more than 1 s behind its
plan and stopped, ``StreamLagging``), frames streamed, frames later than 1 ms
/ half a period / a period past their deadline (``lateness_s`` of the
telemetry, after the stream's stall shifts), lateness p99 and max, the
stream's stalls (frames more than half a period late: the rest of the stream
shifted) and how far behind its plan it ended, how the thread was scheduled,
and the load.

    .venv/bin/python bench/follow_isolation.py [--seconds 6] [--hogs 2] [--rounds 1]
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
from trajgen.drivers.streamer import Streamer

RATE_HZ = 200.0


def keyframe_lines(seconds: float, every_s: float):
    """Retargeting lines in real time: pan and tilt to and fro, one every ``every_s``."""

    def lines(follower=None):
        end = time.monotonic() + seconds
        k = 0
        while time.monotonic() < end:
            time.sleep(every_s)
            pan, tilt = (25, 8) if k % 2 else (-25, -8)
            yield (json.dumps({"in": 0.6, "pan": pan, "tilt": tilt}) + "\n").encode()
            k += 1

    return lines


def one_run(realtime: bool, seconds: float, every_s: float) -> dict:
    defaults = Streamer.__init__.__kwdefaults__
    before = defaults["realtime"]
    defaults["realtime"] = realtime  # the only difference between the arms
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
                status = follow(args, keyframe_lines(seconds, every_s)(None))
        finally:
            defaults["realtime"] = before
        with open(log, newline="") as f:
            late = np.array(
                [float(r["lateness_s"]) for r in csv.DictReader(f) if r["phase"] == "stream"]
            )
        stream = json.loads(out.read_text())["stream"]
    return {"status": status, "late": late, "stream": stream}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0, help="keyframe lines for (s)")
    parser.add_argument("--every", type=float, default=0.1, help="one line every (s)")
    parser.add_argument(
        "--hogs", type=int, default=2, help="CPU-bound processes in the loaded arms"
    )
    parser.add_argument("--rounds", type=int, default=1)
    args = parser.parse_args()
    period = 1.0 / RATE_HZ
    print(
        f"# trajgen follow --virtual, 200 Hz, a line every {args.every:g} s for {args.seconds:g} s"
    )
    print(f"{os.cpu_count()} cores; load before {os.getloadavg()}")
    print()
    print(
        "| hogs | stream thread | load | exit | frames | late > 1 ms | > half period | > period "
        "| p99 ms | max ms | stalls | behind at the end s | scheduling |"
    )
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    ctx = multiprocessing.get_context("fork")
    for _ in range(args.rounds):
        for n_hogs in (0, args.hogs):
            hogs = [ctx.Process(target=hog, daemon=True) for _ in range(n_hogs)]
            for h in hogs:
                h.start()
            try:
                for realtime in (True, False):
                    r = one_run(realtime, args.seconds, args.every)
                    late, stream = r["late"], r["stream"]
                    name = "raised (realtime=True)" if realtime else "peer: as before"
                    if stream is None or not len(late):
                        print(f"| {n_hogs} | {name} | | {r['status']} | 0 (no frame streamed) |")
                        continue
                    print(
                        f"| {n_hogs} | {name} | {os.getloadavg()[0]:.1f} | {r['status']} "
                        f"| {len(late)} "
                        f"| {int(np.sum(late > 1e-3))} | {int(np.sum(late > period / 2))} "
                        f"| {int(np.sum(late > period))} | {1e3 * np.percentile(late, 99):.2f} "
                        f"| {1e3 * late.max():.2f} | {stream['stalls']} | {stream['delay_s']:.2f} "
                        f"| {stream.get('scheduling') or '-'} |",
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
