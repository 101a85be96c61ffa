"""Careless input on ``trajgen follow``'s stdin: does a bad line delay a frame?

A 200 Hz stream of a ``Follower``'s frames, paced on the monotonic clock, while
a second thread reads keyframe lines from a pipe that a third thread fills.
Inputs: a few good lines (the baseline); the same with a 50 MB line in the
middle; with 2 MB of binary noise. Readers: ``trajgen follow``'s
(``keyframe_lines.capped_lines`` on the pipe's bytes, a line longer than 64 KiB
refused unparsed) against the peer, the reader before it (a text-mode
``for line in stdin`` with every line parsed by ``json.loads`` whole), in the
same run. Printed per case: the longest frame lateness (ms), the lines
accepted, the bytes the reader held at once at most, and the wall time.

Run: .venv/bin/python bench/follow_input.py [--seconds 4]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import threading
import time

import numpy as np

from trajgen import quat as Q
from trajgen.drivers.clock import sleep_until
from trajgen.follower import Follower
from trajgen.keyframe_lines import capped_lines
from trajgen.online import OnlineSpline

RATE_HZ = 200.0
GOOD = [json.dumps({"in": 0.6, "pan": p}) for p in (10, -10, 15, 0)]


def inputs(seed: int = 3) -> dict[str, list[bytes]]:
    rng = np.random.default_rng(seed)
    good = [(line + "\n").encode() for line in GOOD]
    big = b'{"in": 1, "pan": ' + b"1" * (50 * 1024 * 1024) + b"}\n"
    noise = rng.integers(0, 256, 2 * 1024 * 1024, dtype=np.uint8).tobytes()
    return {
        "good lines only": good,
        "50 MB line": good[:2] + [big] + good[2:],
        "2 MB binary noise": good[:2] + [noise + b"\n"] + good[2:],
    }


def peer_read(follower: Follower, pipe) -> None:
    """The reader before: text-mode lines, each parsed whole (``Follower.feed``)."""
    try:
        for number, text in enumerate(io.TextIOWrapper(pipe, encoding="utf-8"), start=1):
            try:
                follower.feed(text, number)
            except ValueError as e:
                follower.skipped.append(str(e))
    except UnicodeDecodeError as e:  # it died here: no line after this one was read
        follower.skipped.append(str(e))
    finally:
        follower.spline.close()


def run(chunks: list[bytes], reader: str, seconds: float) -> dict:
    spline = OnlineSpline(Q.from_pan_tilt_roll(0.0, 0.0, 0.0))
    follower = Follower(spline, RATE_HZ)
    read_end, write_end = os.pipe()
    held = [0]

    def writer():
        with os.fdopen(write_end, "wb") as pipe:
            for chunk in chunks:
                time.sleep(0.4)
                try:
                    pipe.write(chunk)
                    pipe.flush()
                except BrokenPipeError:
                    return

    def read():
        pipe = os.fdopen(read_end, "rb")
        if reader != "trajgen follow":
            return peer_read(follower, pipe)

        def lines():
            for line in capped_lines(pipe):
                held[0] = max(held[0], len(line))
                yield line

        follower.read(lines())

    threading.Thread(target=writer, daemon=True).start()
    reading = threading.Thread(target=read, daemon=True)
    frames = follower.frames()
    late, started = [], time.monotonic()
    reading.start()
    for i, _ in enumerate(frames):
        due = started + i / RATE_HZ
        late.append(time.monotonic() - due)
        if i / RATE_HZ >= seconds:
            break
        sleep_until(started + (i + 1) / RATE_HZ)
    frames.close()
    return {
        "max_late_ms": 1e3 * max(late),
        "p99_late_ms": 1e3 * float(np.percentile(late, 99)),
        "accepted": len(follower.keyframes),
        "skipped": len(follower.skipped),
        "held_bytes": held[0] if reader == "trajgen follow" else None,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0, help="stream length per case (s)")
    options = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} (1, 5 min)")
    print("| input | reader | max lateness ms | p99 ms | lines accepted / skipped | held bytes |")
    print("|---|---|---|---|---|---|")
    for name, chunks in inputs().items():
        for reader in ("trajgen follow", "peer (text, whole lines)"):
            r = run(chunks, reader, options.seconds)
            print(
                f"| {name} | {reader} | {r['max_late_ms']:.1f} | {r['p99_late_ms']:.2f} | "
                f"{r['accepted']} / {r['skipped']} | "
                f"{'whole line' if r['held_bytes'] is None else format(r['held_bytes'], ',')} |"
            )
    print(f"load average {os.getloadavg()[0]:.2f} (1 min) at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
