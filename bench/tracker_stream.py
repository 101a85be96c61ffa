"""A 60 s, 30 Hz noisy face stream through ``trajgen follow``'s Follower at 1 kHz.

A synthesised face (seeded): it walks between random places in front of the
camera (1.5-3 m away, +-50 deg across, +-20 deg up and down), each walk 0.5-2 s
with a smooth (minimum-jerk) profile, then stands still 0.5-3 s; the vision
pipeline reports its position 30 times a second with 1 cm Gaussian noise
(``{"look_at": [x, y, z]}`` lines). The lines go to a ``Follower`` (the file's
per-joint limits 3 rad/s, 20 rad/s^2, 200 rad/s^3 and the torque-speed envelope
of the default gimbal's servos, ``trajgen.sim.check.envelope_check``) while its
1 kHz stream runs on the simulated clock: each line is handed over when the
stream reaches its time, and the change is built in steps between frames, as
``trajgen follow`` does. After each frame the stream gives up the interpreter
(``time.sleep(0)``), as a paced stream does while it waits for its next deadline,
so that the thread that parses the lines keeps up with them.

Printed: frames beyond the speed, acceleration, jerk (difference of the
frames' exact accelerations) or envelope limits, counted on every frame
streamed (a change that were not C2 would show as an unbounded jerk there); the
lines taken, dead-banded, deferred; the tracking error (angle between the
camera's look axis and the direction to the noise-free face) from the earliest
arrival of the first target on, and while the face stands still; the per-target
cost. The peer is the same stream without target lines (frames beyond limits).
CPU per frame of both, split on the streaming thread (``time.thread_time``)
into the frames themselves (evaluation, kinematics, the stream's bookkeeping)
and the changes' steps (``Follower._step``, timed by wrapping it: the tracker's
search and checks, run between frames), and the whole process's.

``--realtime RATE``: also stream on the wall clock through a real bus: for each
run a ``trajgen virtual-bus`` of its own (real time, on a pty, a process of its
own) and ``trajgen follow --port <pty> --baud 4000000 --rate RATE`` against it,
with the face's lines written to its stdin at 30 Hz of wall time, then the same
file without lines (the peer); each run's frames sent, rate achieved, period
error, stalls and worst lateness side by side, with the load; ``--repeat N``
pairs, the run with lines first in every other pair. ``--lead`` is
passed on (default ``advance``: the model lead's MuJoCo inverse dynamics per
frame does not fit a 1 kHz period on this host, with or without lines).

Run: .venv/bin/python bench/tracker_stream.py [--seconds 60] [--seed 3] [--realtime 1000]
     [--lead advance] [--repeat 1]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from trajgen.follower import Follower
from trajgen.gimbal import forward
from trajgen.online import OnlineSpline
from trajgen.quat import rotate

LIMITS = np.array([[3.0] * 3, [20.0] * 3, [200.0] * 3])  # rad/s, rad/s^2, rad/s^3
RATE_HZ = 1000.0
LINE_HZ = 30.0
NOISE_M = 0.01


def face_stream(seconds: float, seed: int):
    """Times (N,) at 30 Hz, true face positions (N, 3) and the noisy reports (N, 3) (m)."""
    rng = np.random.default_rng(seed)

    def place():
        d, az, el = rng.uniform(1.5, 3.0), math.radians(rng.uniform(-50, 50)), rng.uniform(-20, 20)
        el = math.radians(el)
        return d * np.array(
            [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)]
        )

    t = np.arange(0.5, seconds, 1.0 / LINE_HZ)
    true = np.empty((len(t), 3))
    here, t0 = place(), 0.0
    plan = []  # (start, end, from, to) walks, standing between them
    while t0 < seconds:
        stand = rng.uniform(0.5, 3.0)
        walk = rng.uniform(0.5, 2.0)
        there = place()
        plan.append((t0 + stand, t0 + stand + walk, here, there))
        here, t0 = there, t0 + stand + walk
    for i, x in enumerate(t):
        pos = plan[0][2]
        for start, end, a, b in plan:
            if x < start:
                break
            s = min(1.0, (x - start) / (end - start))
            pos = a + (b - a) * (10 * s**3 - 15 * s**4 + 6 * s**5)
        true[i] = pos
    return t, true, true + rng.normal(0.0, NOISE_M, true.shape)


def run(seconds: float, seed: int, with_lines: bool, envelope):
    t_lines, true, noisy = face_stream(seconds, seed)
    spline = OnlineSpline(forward([0, 0, 0]), 0.0, k=2)
    f = Follower(spline, RATE_HZ, limits=LIMITS, envelope=envelope)
    if not with_lines:  # the peer: the same stream length, no targets
        spline.extend(forward([[0, 0, 0]]), [seconds], at=0.0)
        t_lines = t_lines[:0]
    errors, lines, i = [], queue.Queue(), 0

    def reader():  # one thread feeds the lines in order, as `trajgen follow` reads them
        while (item := lines.get()) is not None:
            try:
                f.feed(*item)
            except ValueError as e:
                errors.append(str(e))

    feeder = threading.Thread(target=reader)
    feeder.start()
    if not len(t_lines):
        lines.put(None)
    steps_cpu = [0.0]
    step = f._step

    def timed_step():  # the streaming thread's CPU in the changes' steps
        c = time.thread_time()
        step()
        steps_cpu[0] += time.thread_time() - c

    f._step = timed_step
    yielded = 0.0  # the streaming thread's CPU in time.sleep(0) (s)
    c0, t0 = time.process_time(), time.thread_time()
    for frame in f.frames():
        if i < len(t_lines) and frame.t >= t_lines[i]:
            lines.put((json.dumps({"look_at": noisy[i].round(4).tolist()}), i + 1))
            i += 1
            if i == len(t_lines):
                lines.put(None)
        # every line handed over and its change made: the plan is complete
        if not spline.closed and i == len(t_lines) and not feeder.is_alive():
            spline.close()
        # The interpreter to the lines' thread, as a paced stream gives it while it waits
        # for the next frame's deadline: on a stream that never waits, that thread would
        # get it only at the switch interval, and the lines would queue up behind. (Not
        # counted in the frames' CPU: a paced stream sleeps there.)
        c = time.thread_time()
        time.sleep(0)
        yielded += time.thread_time() - c
    cpu = {
        "process": time.process_time() - c0,
        "frames": time.thread_time() - t0 - steps_cpu[0] - yielded,
        "steps": steps_cpu[0],
    }
    return f, cpu, errors, (t_lines, true, noisy)


def beyond(traj, envelope) -> dict:
    jerk = np.abs(np.diff(traj.qdd, axis=0)) * RATE_HZ
    out = {
        "speed": int((np.abs(traj.qd) > LIMITS[0]).any(axis=1).sum()),
        "acceleration": int((np.abs(traj.qdd) > LIMITS[1]).any(axis=1).sum()),
        "jerk": int((jerk > LIMITS[2] * (1 + 1e-6)).any(axis=1).sum()),
        "envelope": int((~envelope(traj.q, traj.qd, traj.qdd)).sum()),
    }
    out["peaks"] = [
        np.abs(traj.qd).max(axis=0).round(3).tolist(),
        np.abs(traj.qdd).max(axis=0).round(2).tolist(),
        jerk.max(axis=0).round(1).tolist(),
    ]
    return out


def tracking(f, face):
    """Look-axis error (deg) to the noise-free face at every frame from the first target's
    earliest arrival on, and at the frames where the face has stood still for 0.5 s or
    more (the plan then settles on the noisy reports: what is left is the noise)."""
    t_lines, true, _ = face
    traj = f.trajectory()
    look = rotate(forward(traj.q), np.array([1.0, 0.0, 0.0]))
    m = traj.t >= f.keyframes[0]["t"]
    j = np.clip(np.searchsorted(t_lines, traj.t[m], side="right") - 1, 0, len(t_lines) - 1)
    d = true[j] / np.linalg.norm(true[j], axis=1)[:, None]
    err = np.degrees(np.arccos(np.clip((look[m] * d).sum(axis=1), -1.0, 1.0)))
    still = np.zeros(len(t_lines), bool)
    window = int(0.5 * LINE_HZ)
    moved = np.linalg.norm(np.diff(true, axis=0), axis=1) > 1e-9
    for i in range(window, len(t_lines)):
        still[i] = not moved[i - window : i].any()
    return err, err[still[j]]


REALTIME_FILE = """[limits]
speed_rad_s = 3.0
acceleration_rad_s2 = 20.0
jerk_rad_s3 = 200.0

[bus]
watchdog_s = 0.5

[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = {end}
pan = 0.0
"""

#: Wall time (s) from starting `trajgen follow` to its first line: its bring-up.
BRING_UP_S = 3.0


def realtime(seconds: float, seed: int, rate_hz: float, lead: str, with_lines: bool) -> dict:
    """``trajgen follow --port`` on the wall clock against a ``trajgen virtual-bus`` of its
    own, with the face's lines written at 30 Hz (or none, the file's plan lasting as
    long): its JSON report's stream and follow figures, the load beside them."""
    t_lines, _, noisy = face_stream(seconds, seed)
    bin_dir = Path(sys.executable).parent  # the venv's commands
    with tempfile.TemporaryDirectory(prefix="tracker-stream-") as tmp:
        keys, out = Path(tmp) / "keys.toml", Path(tmp) / "out.json"
        keys.write_text(REALTIME_FILE.format(end=0.3 if with_lines else seconds))
        bus = subprocess.Popen(
            [str(bin_dir / "trajgen"), "virtual-bus"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            port = bus.stdout.readline().strip()
            argv = [str(bin_dir / "trajgen"), "follow", str(keys), "--port", port]
            argv += ["--baud", "4000000", "--rate", f"{rate_hz:g}", "--lead", lead]
            argv += ["--configure", "--max-delay", "60", "--json", str(out)]
            load = os.getloadavg()[0]
            proc = subprocess.Popen(
                argv, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
            )
            if with_lines:
                write_lines(proc, t_lines, noisy, time.monotonic() + BRING_UP_S)
            try:
                proc.stdin.close()
            except BrokenPipeError:
                pass
            err = proc.stderr.read().decode()
            proc.wait()
        finally:
            bus.send_signal(signal.SIGINT)
            try:
                bus_err = bus.communicate(timeout=30)[1]
            except subprocess.TimeoutExpired:
                bus.kill()
                bus_err = bus.communicate()[1]
        report = json.loads(out.read_text()) if out.exists() else {}
    why = report.get("stopped_by") or report.get("stream", {}).get("fault") or ""
    if proc.returncode and not why:
        why = " ".join(err.strip().splitlines()[-1:])
    return {
        "exit": proc.returncode,
        "stream": report.get("stream", {}),
        "follow": report.get("follow", {}),
        "why": why,
        "load": (load, os.getloadavg()[0]),
        "bus": " ".join(bus_err.strip().splitlines()[-1:]),
    }


def write_lines(proc, t_lines, noisy, start: float) -> None:
    """The face's reports as JSON lines on ``proc``'s stdin, each at ``start`` plus its
    time (s, wall clock)."""
    for t, p in zip(t_lines, noisy, strict=True):
        time.sleep(max(0.0, start + t - time.monotonic()))
        try:
            proc.stdin.write((json.dumps({"look_at": p.round(4).tolist()}) + "\n").encode())
            proc.stdin.flush()
        except BrokenPipeError:  # the stream stopped (its report says why)
            return


def show_realtime(runs: dict) -> None:
    """The runs' figures side by side, a column each."""

    def ms(s, key):
        v = s.get(key)
        return "n/a" if v is None else f"{1e3 * v:.2f} ms"

    rows = {
        "exit status": lambda r: str(r["exit"]),
        "frames sent": lambda r: str(r["stream"].get("frames_sent", "n/a")),
        "rate achieved": lambda r: f"{r['stream'].get('achieved_rate_hz') or math.nan:.1f} Hz",
        "period error p50": lambda r: ms(r["stream"], "period_error_p50_s"),
        "period error p99": lambda r: ms(r["stream"], "period_error_p99_s"),
        "period error max": lambda r: ms(r["stream"], "period_error_max_s"),
        "stalls": lambda r: str(r["stream"].get("stalls", "n/a")),
        "longest stall": lambda r: ms(r["stream"], "stall_max_s"),
        "worst lateness": lambda r: ms(r["stream"], "lateness_max_s"),
        "behind the plan at the end": lambda r: ms(r["stream"], "delay_s"),
        "read-back every": lambda r: f"{r['stream'].get('read_every', 'n/a')} frames",
        "lines accepted": lambda r: str(r["follow"].get("accepted", 0)),
        "longest step per change p50": lambda r: ms(r["follow"].get("change_step_s") or {}, "p50"),
        "longest step per change max": lambda r: ms(r["follow"].get("change_step_s") or {}, "max"),
        "load (start, end)": lambda r: f"{r['load'][0]:.2f}, {r['load'][1]:.2f}",
    }
    names = list(runs)
    print(f"  {'':30}" + "".join(f"{n:>20}" for n in names))
    for label, cell in rows.items():
        print(f"  {label:30}" + "".join(f"{cell(runs[n]):>20}" for n in names))
    for n in names:
        for what in ("why", "bus"):
            if runs[n][what]:
                print(f"  {n}: {runs[n][what]}")


def pct(x) -> str:
    if len(x) == 0:
        return "n/a"
    return f"p50 {np.median(x):.3f}  p95 {np.percentile(x, 95):.3f}  max {x.max():.3f} deg"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument(
        "--realtime",
        type=float,
        default=None,
        help="also run trajgen follow --port against trajgen virtual-bus at RATE Hz",
    )
    parser.add_argument(
        "--lead", default="advance", help="the --lead of those runs (default advance)"
    )
    parser.add_argument(
        "--repeat", type=int, default=1, help="pairs of real-time runs, each first in turn"
    )
    args = parser.parse_args()
    from trajgen.sim.check import envelope_check
    from trajgen.sim.model import GimbalConfig

    envelope = envelope_check(GimbalConfig())
    print(f"load average {os.getloadavg()[0]:.2f} (1 min)")
    f, cpu, errors, face = run(args.seconds, args.seed, True, envelope)
    traj = f.trajectory()
    n_lines = len(face[0])
    deferred = sum(k["at"] > k["now"] + 0.1 for k in f.keyframes)
    print(
        f"targets: {n_lines} lines at {LINE_HZ:g} Hz, {len(f.keyframes)} changed the plan, "
        f"{n_lines - len(f.keyframes) - len(errors)} within the dead band, {len(errors)} refused"
        f"{' (' + errors[0] + ')' if errors else ''}; {deferred} started > 0.1 s after the line"
    )
    print(f"frames: {len(traj.t)} at {RATE_HZ:g} Hz; beyond the limits: {beyond(traj, envelope)}")
    err, err_still = tracking(f, face)
    print(f"tracking error to the noise-free face (look axis), from the first arrival: {pct(err)}")
    print(f"  ... while the face stands still (0.5 s or more): {pct(err_still)}")
    print(
        f"  (reports carry {NOISE_M * 100:g} cm noise, about "
        f"{math.degrees(NOISE_M / 2.0):.2f} deg at 2 m; a target in the dead band changes nothing)"
    )
    costs = np.array(f.change_costs_s)
    print(
        f"per target (wall, on the streaming thread's steps): p50 {1e3 * np.median(costs):.2f} "
        f"p99 {1e3 * np.percentile(costs, 99):.2f} ms; longest step p99 "
        f"{1e3 * np.percentile(f.change_steps_s, 99):.2f} ms"
    )
    peer, cpu_peer, _, _ = run(args.seconds, args.seed, False, envelope)
    ptraj = peer.trajectory()
    print(f"peer, no targets: {len(ptraj.t)} frames, beyond the limits: {beyond(ptraj, envelope)}")
    n, n_peer = len(traj.t), len(ptraj.t)
    print(f"CPU per frame (us), load {os.getloadavg()[0]:.2f}:   with targets   peer   ratio")
    for key, label in (
        ("frames", "frames (streaming thread)"),
        ("steps", "changes' steps (streaming)"),
        ("process", "whole process"),
    ):
        a, b = 1e6 * cpu[key] / n, 1e6 * cpu_peer[key] / n_peer
        print(f"  {label:30} {a:12.1f} {b:6.1f} {a / b if b else math.inf:7.2f}x")
    if args.realtime is None:
        print("late frames in real time: not measured (give --realtime RATE)")
    else:
        print(
            f"real time: trajgen follow --port <trajgen virtual-bus pty> --baud 4000000 "
            f"--rate {args.realtime:g} --lead {args.lead}, {args.seconds:g} s each:"
        )
        for r in range(args.repeat):  # pairs, each run first in turn (the load drifts)
            pair = (("with the lines", True), ("peer, no lines", False))[:: 1 if r % 2 == 0 else -1]
            runs = {}
            for name, lines in pair:
                runs[name] = realtime(args.seconds, args.seed, args.realtime, args.lead, lines)
            print(f" pair {r + 1} of {args.repeat}:")
            show_realtime(runs)
    print(f"load average {os.getloadavg()[0]:.2f} (1 min) at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
