"""``follow``'s planner process and its ring of frames (drivers/follow_process.py,
trajgen/frame_ring.py): the frames it streams are the in-process follower's, it ends in a
stated safe stop when it fails, and it never outlives the stream's process."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from trajgen.drivers.config import BusConfig
from trajgen.drivers.follow_process import PLANNER_NAME
from trajgen.drivers.session import HOLDING, Session
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.follower import Follower
from trajgen.frame_ring import FrameRing, RingEmpty
from trajgen.online import OnlineSpline
from trajgen.stream import JointFrame

RATE_HZ = 100.0
HALF = 0.5 / RATE_HZ
NAME = PLANNER_NAME + b"\n"
TIMEOUT_S = 60.0  # generous: each wait ends as soon as its condition holds

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="the planner is forked")


def wait_until(condition, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"waited {TIMEOUT_S} s for {what}")
        time.sleep(0.001)


def frame(k: int, goals: bool) -> JointFrame:
    q = np.array([k, -k, 0.5 * k], float)
    return JointFrame(k, k / RATE_HZ, q, q + 1, q + 2, q + 3 if goals else None)


# -- the ring -------------------------------------------------------------------


@pytest.mark.parametrize("goals", [True, False])
def test_the_ring_wraps_around_and_says_full_and_empty(goals):
    ring = FrameRing(3, 4, goals=goals)
    with pytest.raises(RingEmpty):
        ring.take()
    k_put = k_taken = 0
    for batch in (4, 3, 4, 2, 4):  # 17 frames through 4 slots
        for _ in range(batch):
            ring.put(frame(k_put, goals))
            k_put += 1
        assert ring.room() == 4 - batch
        if batch == 4:
            with pytest.raises(OverflowError):
                ring.put(frame(k_put, goals))
        for _ in range(batch):
            got, want = ring.take(), frame(k_taken, goals)
            k_taken += 1
            assert (got.index, got.t) == (want.index, want.t)
            for name in ("q", "qd", "qdd"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
            assert (got.goal is None) == (not goals)
            if goals:
                np.testing.assert_array_equal(got.goal, want.goal)
        with pytest.raises(RingEmpty):
            ring.take()
    assert ring.taken == 17 and not ring.ended and not ring.stopped
    ring.end()
    ring.stop()
    assert ring.ended and ring.stopped


# -- the planner against the follower in process -------------------------------

SCRIPT = [  # (stream time, line): each line read once the plan reaches that time
    (0.3, '{"in": 0.8, "pan": 20, "tilt": 5}'),
    (0.6, "not json"),
    (0.9, '{"in": 0.6, "pan": -10, "roll": 3}'),
    (1.2, '{"in": 0.7, "tilt": -8, "mode": "extend"}'),
]


class GatedSpline(OnlineSpline):
    """An online plan that commits no frame past a script's line until that line is
    queued in ``follower`` (in whichever process plans): each line then reaches the
    follower at the same frame, whatever the host's timing."""

    follower = None

    def commit(self, t, version):
        f = self.follower
        for i, (due, _) in enumerate(SCRIPT):
            if t > due + HALF:
                wait_until(lambda i=i: len(f._jobs) + len(f.keyframes) + len(f.skipped) > i, "line")
        return super().commit(t, version)


def scripted_lines(follower):
    for due, line in SCRIPT:
        wait_until(lambda due=due: follower.spline.committed >= due - HALF, "the stream time")
        yield line


def follow(process: bool, spline_type=GatedSpline):
    spline = spline_type([1.0, 0, 0, 0])
    follower = Follower(spline, RATE_HZ)
    spline.follower = follower
    session = Session(BusConfig(configure=True), plant=FirstOrderPlant(), max_delay_s=None)
    return follower, session.follow(follower, scripted_lines, process=process)


def children() -> list[int]:
    pids = []
    for task in Path("/proc/self/task").iterdir():
        pids += [int(p) for p in (task / "children").read_text().split()]
    return pids


def test_the_planner_streams_the_frames_of_the_follower_in_process():
    before = children()
    inside, by_thread = follow(process=False)
    apart, by_process = follow(process=True)
    assert by_thread.ok and by_process.ok
    assert children() == before  # the planner was reaped
    a, b = by_thread.trajectory, by_process.trajectory
    assert len(a.t) > 150
    for name in ("t", "q", "qd", "qdd"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert apart.keyframes == inside.keyframes and len(apart.keyframes) == 3
    assert apart.skipped == inside.skipped and "line 2" in apart.skipped[0]
    assert len(apart.latencies_s) == 3 and all(x > 0 for x in apart.latencies_s)
    assert apart.summary()["accepted"] == 3


class FailingSpline(GatedSpline):
    def commit(self, t, version):
        if t > 0.5:
            raise RuntimeError("the plan broke")
        return super().commit(t, version)


def test_a_planner_that_fails_ends_the_stream_in_the_safe_stop_with_its_message():
    before = children()
    follower, outcome = follow(process=True, spline_type=FailingSpline)
    assert not outcome.ok and outcome.stage == "stream"
    assert outcome.stopped_by == "the planner process failed: RuntimeError: the plan broke"
    assert outcome.servo_states == dict.fromkeys((1, 2, 3), HOLDING)
    assert 0.4 < outcome.trajectory.t[-1] <= 0.5  # the frames it made before, no more
    assert follower.keyframes  # what it recorded came back
    assert children() == before


# -- the command: Ctrl-C, a killed parent, a refused line -----------------------


def start_follow(tmp_path):
    from trajgen import BUILTIN_EXAMPLE

    keys = tmp_path / "keys.toml"
    keys.write_text(BUILTIN_EXAMPLE.read_text() + "\n[bus]\nconfigure = true\n")
    command = Path(sys.executable).parent / "trajgen"
    proc = subprocess.Popen(
        [str(command), "follow", str(keys), "--virtual", "--lead", "none"],
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    wait_until(lambda: proc.poll() is not None or planner_of(proc.pid), "the planner")
    assert proc.poll() is None, proc.stderr.read().decode()
    return proc, planner_of(proc.pid)[0]


def planner_of(pid: int) -> list[int]:
    """The children of ``pid`` named as the planner (``PLANNER_NAME``)."""
    pids = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            children = [int(p) for p in (task / "children").read_text().split()]
            pids += [c for c in children if Path(f"/proc/{c}/comm").read_bytes() == NAME]
        except FileNotFoundError:  # a thread or a child that just ended
            pass
    return pids


def gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def test_ctrl_c_ends_follow_with_130_and_its_planner_with_it(tmp_path):
    proc, planner = start_follow(tmp_path)
    proc.stdin.write(b'{"in": 0.05, "pan": 3}\n')  # too close: refused at once, on stderr
    proc.stdin.flush()
    seen = b""
    while b"line 1" not in seen:
        line = proc.stderr.readline()
        assert line, seen.decode()
        seen += line
    assert proc.poll() is None  # the message came while the stream ran
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=TIMEOUT_S) == 130
    assert gone(planner)


def test_a_killed_follow_leaves_no_planner_behind(tmp_path):
    proc, planner = start_follow(tmp_path)
    proc.kill()
    proc.wait(timeout=TIMEOUT_S)
    wait_until(lambda: gone(planner), "the planner to exit")
