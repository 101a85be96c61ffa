"""``trajgen follow``: keyframe lines on a pipe change the stream to the virtual bus."""

import json
import math
import os
import re
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from trajgen import follower as follow
from trajgen import quat as Q
from trajgen.cli import main
from trajgen.drivers.session import Session
from trajgen.gimbal import forward
from trajgen.keyframes import BUILTIN_EXAMPLE, load_keyframe_file

RATE_HZ = 200.0
TICK_RAD = 2 * math.pi / 4096


def test_follow_virtual_with_lines_on_a_pipe(monkeypatch, tmp_path):
    read_end, write_end = os.pipe()
    monkeypatch.setattr(sys, "stdin", os.fdopen(read_end, "r"))
    seen = {}
    open_virtual = Session._open_virtual

    def spy_virtual(self, rate_hz):
        seen["virtual"] = open_virtual(self, rate_hz)
        return seen["virtual"]

    real_follow = Session.follow

    def spy_follow(self, follower, lines, **kwargs):
        seen["follower"] = follower
        return real_follow(self, follower, lines, **kwargs)

    monkeypatch.setattr(Session, "_open_virtual", spy_virtual)
    monkeypatch.setattr(Session, "follow", spy_follow)
    lines = [
        '{"in": 0.8, "pan": 20, "tilt": 5}',
        '{"in": 0.6, "pan": 10, "tilt": -5, "roll": 3}',
        '{"in": 0.1, "pan": 3}',  # too close: skipped
        '{"in": 0.9, "quat": [0.99, 0, 0.05, -0.1]}',
        '{"in": 0.7, "pan": -5, "mode": "extend"}',
    ]

    def stream_time():  # the last frame streamed (the plan is another process's)
        frames = seen["follower"]._frames if "follower" in seen else []
        return frames[-1].t if frames else -1.0

    ended = threading.Event()

    def writer():
        # Lines paced on the stream's own clock, not the wall clock: after a host stall
        # the stream shifts its clock (it never catches up), so wall time runs ahead.
        # Once the command has returned, the pipe is closed (whatever happened): the
        # reading thread then sees the end of its input instead of waiting on it.
        with os.fdopen(write_end, "w") as pipe:
            due = 0.5  # the stream is running: lines arrive mid-motion
            for line in lines:
                while stream_time() < due:
                    if ended.wait(0.005):
                        return
                pipe.write(line + "\n")
                pipe.flush()
                due = stream_time() + 0.35

    # The planner process (drivers/follow_process.py) is forked with a copy of every
    # descriptor: its copy of the pipe's write end is closed, else it never sees the end.
    planning = [True]
    os.register_at_fork(after_in_child=lambda: planning and os.close(write_end))
    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    out = tmp_path / "follow.json"
    # The built-in example, with a tracking budget for the servo's lag (45 ms x
    # speed with default gains) on the quick moves the lines ask for. No room for a
    # busy machine in the Bus Watchdog or a lateness bound: the stream runs on
    # simulated time, paced by the wall clock (slower on a slow host, never late).
    from trajgen import BUILTIN_EXAMPLE

    keys = tmp_path / "keys.toml"
    keys.write_text(
        BUILTIN_EXAMPLE.read_text().replace(
            "[gimbal]\n", "[gimbal]\nmax_tracking_error_rad = 0.15\n", 1
        )
        + "\n[bus]\nconfigure = true\n"  # Extended Position Mode
    )
    # The plan sent as it is (--lead none): the goals on the bus are the frames; the
    # led goals of follow are checked in test_lead_stream.py.
    argv = ["follow", str(keys), "--virtual", "--json", str(out)]
    try:
        status = main([*argv, "--lead", "none"])
    finally:
        planning.clear()
        ended.set()
        thread.join(timeout=5)
    assert status == 0, out.read_text() if out.exists() else "no report"
    run = json.loads(out.read_text())
    assert run["stream"]["fault"] == "" and "torque" in run
    result = run["follow"]
    assert result["accepted"] == 4 and result["skipped"] == 1
    assert "line 3" in result["skipped_lines"][0]
    assert result["latency_s"]["n"] == 4
    # Each change made within 0.5 s of stream time of its line's arrival (the frame
    # being streamed then), however busy the host: the stream waits for no wall clock.
    assert all(0 < k["at"] - k["now"] < 0.5 for k in result["keyframes"])
    assert set(result["simulated_time"]) == {"lag_max_s", "shifts", "behind_s", "behind_now_s"}
    assert run["stream"]["stalls"] == 0 and run["stream"]["lateness_max_s"] == 0.0

    f = seen["follower"]
    traj = f.trajectory()
    # Goals on the bus: the frames as streamed, with no step the planned speed does not allow.
    goals = np.array(seen["virtual"].goal_log[-len(traj) :], dtype=float)
    goal_rad = (goals - 2048) * TICK_RAD
    np.testing.assert_allclose(goal_rad, traj.q, atol=TICK_RAD)
    dt = 1.0 / RATE_HZ
    speed = np.maximum(np.abs(traj.qd[1:]), np.abs(traj.qd[:-1]))
    allowed = speed * dt + 0.5 * np.abs(traj.qdd).max(axis=0) * dt**2 + TICK_RAD
    assert (np.abs(np.diff(goal_rad, axis=0)) <= allowed).all()
    # Every keyframe still planned when it came is passed at its time.
    for i, kf in enumerate(f.keyframes):
        later = f.keyframes[i + 1 :]
        if any(k["mode"] == "retarget" and k["at"] < kf["t"] for k in later):
            continue
        j = int(np.argmin(np.abs(traj.t - kf["t"])))
        assert abs(traj.t[j] - kf["t"]) < 1e-9
        assert Q.distance(forward(traj.q[j]), np.array(kf["quat"])) < 1e-6
    # It ends at rest on the last keyframe.
    np.testing.assert_allclose(traj.qd[-1], 0.0, atol=1e-9)
    assert Q.distance(forward(traj.q[-1]), np.array(f.keyframes[-1]["quat"])) < 1e-6


@pytest.fixture
def follower():
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    return follow.Follower(follow.online_spline(kf), RATE_HZ)


@pytest.mark.parametrize(
    "line, message",
    [
        ("not json", "line 1: invalid JSON"),
        ("[1, 2]", "line 1: expected a JSON object"),
        ('{"in": 1, "yaw": 2}', "line 1: unknown field 'yaw'"),
        ('{"t": 1, "in": 1, "pan": 2}', "line 1: give exactly one of 't'"),
        ('{"pan": 2, "mode": "extend"}', "line 1: field 'mode': a target without 't' or 'in'"),
        ('{"look_at": [0, 0, 0]}', "line 1: field 'look_at': the gimbal's origin"),
        ('{"in": 1, "pan": "x"}', "field 'pan': expected a finite number"),
        ('{"in": 1}', "no orientation"),
        ('{"in": 1, "pan": 1, "quat": [1, 0, 0, 0]}', "either 'quat' or pan/tilt/roll"),
        ('{"in": 1, "pan": 1, "mode": "jump"}', "field 'mode'"),
        ('{"in": 0.2, "pan": 1}', "must be at least 0.25 s ahead"),
        ('{"in": 1, "tilt": 85}', "within 10.0 deg of gimbal lock"),
        ('{"t": 5.0, "pan": 1, "mode": "extend"}', "must come after the last keyframe kept"),
    ],
)
def test_bad_lines_are_refused_and_the_plan_kept(follower, line, message):
    with pytest.raises(ValueError, match=message):
        follower.feed(line, 1)
    assert follower.spline.version == 1  # the file's plan only


def test_read_reports_bad_lines_and_goes_on(follower):
    told = []
    follower.on_skip = told.append
    follower.read(['{"in": 1, "yaw": 2}\n', "\n", '{"in": 1, "pan": 30}\n'])
    assert told == follower.skipped and told[0].startswith("stdin: line 1: unknown field 'yaw'")
    assert len(follower.keyframes) == 1 and follower.keyframes[0]["line"] == 3
    assert follower.spline.closed


def test_follow_bad_input_exit_2(tmp_path, capsys):
    with pytest.raises(SystemExit):  # refused by the parser, as on every command
        main(["follow", "--virtual", "--port", "/dev/null"])
    assert "argument --port: not allowed with argument --virtual" in capsys.readouterr().err
    natural = tmp_path / "natural.toml"
    text = BUILTIN_EXAMPLE.read_text().replace('boundary = "rest"', 'boundary = "natural"')
    natural.write_text(text)
    assert main(["follow", str(natural), "--virtual"]) == 2
    assert "[spline] boundary: follow needs 'rest'" in capsys.readouterr().err


def test_a_frame_the_gimbal_cannot_take_ends_the_stream_at_the_frame_before(follower):
    # A change made around the follower's checks, into gimbal lock.
    follower.spline.retarget(Q.from_pan_tilt_roll(0.0, np.radians(85), 0.0)[None], [0.8], at=0.3)
    follower.spline.close()
    frames = list(follower.frames())
    assert "gimbal lock" in follower.fault
    assert 0.3 < frames[-1].t < 0.8 and len(frames) == len(follower.trajectory())


def test_follow_stops_safely_on_sigterm_while_waiting_for_lines(tmp_path):
    import signal
    import subprocess

    example = Path(__file__).parents[1] / "examples" / "follow_target.toml"
    telemetry = tmp_path / "t.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "trajgen", "follow", str(example), "--virtual"]
        + ["--telemetry", str(telemetry)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    # stdin stays open: the stream holds at rest, waiting for lines. The telemetry file
    # (a row per frame, flushed) says when it streams.
    deadline = time.monotonic() + 120.0
    while not (telemetry.exists() and telemetry.read_text().count("\n") > 100):
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "trajgen follow: interrupted" in err and "hold their last goal" in err


def test_a_smooth_spline_file_is_followed_with_the_blending_spline(tmp_path, monkeypatch, capsys):
    import io

    keys = tmp_path / "smooth.toml"
    keys.write_text(
        '[spline]\nmethod = "smooth"\n\n'
        "[[keyframes]]\nt = 0.0\npan = 0.0\n\n[[keyframes]]\nt = 0.5\npan = 5.0\n"
    )
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))  # no lines: the file's plan, then rest
    assert main(["follow", str(keys), "--virtual", "--configure"]) == 0
    err = capsys.readouterr().err
    assert "follow plans with the blending spline" in err and "method = 'smooth'" in err


def test_the_stream_takes_the_interpreter_back_within_a_fraction_of_a_period(follower):
    """While following, a change built on the reading thread yields the interpreter to
    the streaming thread every SWITCH_INTERVAL_S; the setting is restored after."""
    before = sys.getswitchinterval()
    follower.spline.close()
    frames = follower.frames()
    next(frames)
    assert sys.getswitchinterval() == pytest.approx(min(before, follow.SWITCH_INTERVAL_S))
    for _ in frames:
        pass
    assert sys.getswitchinterval() == before


def queued(follower, timeout_s=10.0):
    """Wait until a line fed on another thread waits for the stream to build it."""
    deadline = time.monotonic() + timeout_s
    while not follower._jobs:
        assert time.monotonic() < deadline
        time.sleep(0.001)


def test_a_line_is_built_between_frames_by_the_streaming_thread(follower, monkeypatch):
    """While the stream runs, feed() parses the line and waits: the change is built
    and checked in steps, one per frame (no share of a period for more), by the
    thread that takes the frames."""
    monkeypatch.setattr(follower, "step_share", 0.0)
    frames = follower.frames()
    next(frames)
    fed = threading.Thread(target=follower.feed, args=('{"in": 0.6, "pan": 10}', 1))
    fed.start()
    queued(follower)
    time.sleep(0.2)  # a change costs a few ms: were it built here, it would be done
    assert fed.is_alive() and not follower.keyframes
    taken = 0
    while follower._jobs:  # until the streaming thread has run the change's last step
        next(frames)
        taken += 1
        assert taken < 50
    fed.join()
    assert taken >= 3  # the old path's jet, the new piece, the check (and the swap)
    assert len(follower.keyframes) == 1 and follower.spline.version == 2
    assert follower.change_steps_s[0] < follower.change_costs_s[0]  # more than one step


def test_at_low_rates_a_change_starts_late_enough_for_its_steps():
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    slow = follow.Follower(follow.online_spline(kf), 20.0)  # 50 ms per step
    with pytest.raises(ValueError, match=r"must be at least 0\.45 s ahead"):
        slow.feed('{"in": 0.3, "pan": 1}', 1)
    frames = slow.frames()
    next(frames)
    fed = threading.Thread(target=slow.feed, args=('{"in": 0.8, "pan": 1}', 2))
    fed.start()
    queued(slow)  # frames are taken unpaced here: not before the line waits for them
    while slow._jobs:
        next(frames)
    fed.join()
    assert [k["line"] for k in slow.keyframes] == [2]  # made before the stream reached it
    # Five periods (two steps to build, two to check, one spare) after the frame
    # streamed when its build started, a frame or two after the line arrived.
    lead = slow.keyframes[0]["at"] - slow.keyframes[0]["now"]
    assert 5 / 20.0 - 1e-9 <= lead <= 7 / 20.0 + 1e-9


def test_a_line_still_queued_when_the_stream_ends_is_reported_and_changes_nothing(follower):
    frames = follower.frames()
    next(frames)
    errors = []

    def feed():
        try:
            follower.feed('{"in": 0.6, "pan": 10}', 7)
        except ValueError as e:
            errors.append(str(e))

    fed = threading.Thread(target=feed)
    fed.start()
    queued(follower)
    frames.close()  # the stream ends (a stop signal, a fault) before the change's steps
    fed.join(timeout=10)
    assert errors == ["stdin: line 7: the stream ended before its change was made"]
    assert follower.spline.version == 1 and not follower.keyframes


# -- careless input on stdin --------------------------------------------------


def test_a_50_mb_line_is_read_in_bounded_pieces_and_the_next_line_kept():
    from trajgen.keyframe_lines import MAX_LINE_BYTES, capped_lines

    read_end, write_end = os.pipe()

    def writer():
        with os.fdopen(write_end, "wb") as pipe:
            pipe.write(b"[" * (50 * 1024 * 1024) + b"\n")
            pipe.write(b'{"in": 1, "pan": 30}\n')

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    with os.fdopen(read_end, "rb") as pipe:
        lines = list(capped_lines(pipe))
    thread.join()
    assert [len(x) for x in lines] == [MAX_LINE_BYTES + 1, 21]
    assert lines[1] == b'{"in": 1, "pan": 30}\n'


def test_a_long_line_is_refused_unparsed_and_counted(follower, monkeypatch):
    from trajgen import keyframe_lines
    from trajgen.keyframe_lines import MAX_LINE_BYTES

    parsed = []
    loads = keyframe_lines.json.loads
    monkeypatch.setattr(keyframe_lines.json, "loads", lambda s: parsed.append(len(s)) or loads(s))
    long = b'{"in": 1, "pan": ' + b"1" * MAX_LINE_BYTES
    follower.read([long, b'{"in": 1, "pan": 30}\n'])
    assert follower.skipped == [
        f"stdin: line 1: longer than {MAX_LINE_BYTES} bytes; a keyframe line is short"
    ]
    assert parsed == [21] and [k["line"] for k in follower.keyframes] == [2]


def test_binary_noise_is_refused_line_by_line_and_the_stream_goes_on(follower, rng):
    noise = rng.integers(0, 256, 20_000, dtype=np.uint8).tobytes()
    lines = [x + b"\n" for x in noise.split(b"\n")] + [b'{"in": 1, "pan": 30}\n']
    follower.read(lines)
    # Every line but the last refused, each under its own number (blank ones are no line).
    blank = {n for n, x in enumerate(lines, start=1) if not x.strip()}
    expected = [n for n in range(1, len(lines)) if n not in blank]
    assert [int(m.split(":")[1].split()[1]) for m in follower.skipped] == expected
    for message in follower.skipped:
        assert "not UTF-8 text" in message or "invalid JSON" in message or "expected" in message
    assert [k["line"] for k in follower.keyframes] == [len(lines)]


@pytest.mark.parametrize(
    "line, message",
    [
        ('{"in": "soon", "pan": 1}', "line 1: field 'in': expected a finite number, got 'soon'"),
        ('{"t": "soon", "pan": 1}', "line 1: field 't': expected a finite number, got 'soon'"),
        ('{"in": 1e999, "pan": 1}', "line 1: field 'in': expected a finite number, got inf"),
        (b'{"in": 1, "pan": "\xff"}', r"line 1: not UTF-8 text \(byte 0xff at column 19\)"),
        ("[" * 60_000, "line 1: invalid JSON: nested too deeply"),
        ('{"in": 1, "pan": ' + "1" * 5000 + "}", "line 1: invalid JSON: Exceeds the limit"),
        (
            '{"in": 1, "pan": "' + "x" * 5000 + '"}',
            r"^stdin: line 1: field 'pan': .*x\[\.\.\.\] \(50",
        ),
    ],
)
def test_a_line_names_its_field_and_number(follower, line, message):
    follower.read([line])
    assert len(follower.skipped) == 1
    assert re.search(message, follower.skipped[0]), follower.skipped[0]


def test_follow_command_skips_noise_on_stdin_and_follows_the_good_lines(
    tmp_path, monkeypatch, capfd, rng
):
    # capfd: the refusals are printed by the planner process, on the descriptor it shares
    import io

    lines = rng.integers(0, 256, 3000, dtype=np.uint8).tobytes().replace(b"\n", b" ") + b"\n"
    lines += b"x" * 200_000 + b"\n" + b'{"in": 0.8, "pan": 10}\n'
    stdin = tmp_path / "stdin"
    stdin.write_bytes(lines)
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(open(stdin, "rb")))  # noqa: SIM115
    out = tmp_path / "follow.json"
    keys = tmp_path / "keys.toml"
    keys.write_text(BUILTIN_EXAMPLE.read_text() + "\n[bus]\nconfigure = true\n")
    assert main(["follow", str(keys), "--virtual", "--json", str(out)]) == 0
    err = capfd.readouterr().err
    assert "trajgen follow: stdin: line 1: not UTF-8 text" in err
    assert "trajgen follow: stdin: line 2: longer than 65536 bytes" in err
    result = json.loads(out.read_text())["follow"]
    assert result["accepted"] == 1 and result["keyframes"][0]["line"] == 3


def test_noise_prints_twenty_refusals_then_counts_the_rest(capsys):
    from trajgen.cli.follow import SHOWN_SKIPS, _skipped

    show = _skipped()
    for n in range(1, 100):
        show(f"stdin: line {n}: invalid JSON")
    err = capsys.readouterr().err.splitlines()
    assert len(err) == SHOWN_SKIPS + 1 and err[0].endswith("line 1: invalid JSON (line skipped)")
    assert err[-1] == "trajgen follow: 20 lines skipped; more are counted, not shown"


def test_capped_lines_reads_a_text_file_alike():
    import io

    from trajgen.keyframe_lines import capped_lines

    lines = list(capped_lines(io.StringIO("a\n" + "b" * 50 + "\nc"), max_bytes=10))
    assert lines == ["a\n", "b" * 11, "c"]


def test_untimed_step_targets_keep_the_files_limits_and_envelope(tmp_path, monkeypatch):
    """[limits] and the servos' envelope reach the tracker through the CLI: a 30 deg step
    (that the spline's minimum lead alone would take at about 4 rad/s) and a second
    target replacing it in mid-motion keep them on every frame streamed; the goals sent
    are the tracker's frames led as every follow frame is (the model lead)."""
    import csv
    import io

    from trajgen.gimbal import GimbalKinematics
    from trajgen.sim.check import envelope_check
    from trajgen.sim.lead import Leader
    from trajgen.sim.model import gimbal_config_from_tables

    seen = {}
    real_follow = Session.follow

    def spy_follow(self, follower, lines, **kwargs):
        seen["follower"] = follower
        return real_follow(self, follower, lines, **kwargs)

    monkeypatch.setattr(Session, "follow", spy_follow)
    limits = (1.0, 8.0, 100.0)  # rad/s, rad/s^2, rad/s^3
    keys = tmp_path / "limited.toml"
    keys.write_text(
        "[limits]\nspeed_rad_s = {}\nacceleration_rad_s2 = {}\njerk_rad_s3 = {}\n\n"
        "[[keyframes]]\nt = 0.0\npan = 0.0\n\n[[keyframes]]\nt = 0.3\npan = 0.0\n".format(*limits)
    )
    monkeypatch.setattr(sys, "stdin", io.StringIO('{"pan": 30}\n{"pan": -10, "tilt": 12}\n'))
    out, log = tmp_path / "follow.json", tmp_path / "follow.csv"
    # 50 Hz: fewer frames to check; the tracker plans on the stream's rate.
    rate = 50.0
    argv = ["follow", str(keys), "--virtual", "--configure"]
    argv += ["--rate", f"{rate:g}"]
    assert main([*argv, "--json", str(out), "--telemetry", str(log)]) == 0
    assert json.loads(out.read_text())["follow"]["accepted"] == 2
    f = seen["follower"]
    traj = f.trajectory()
    speed, accel = np.abs(traj.qd).max(axis=0), np.abs(traj.qdd).max(axis=0)
    # jerk checked at the frames; between two, the mean may exceed it a little
    jerk = np.abs(np.diff(traj.qdd, axis=0)).max(axis=0) * rate
    assert (speed <= limits[0]).all() and (accel <= limits[1]).all()
    assert (jerk <= limits[2] * 1.1).all()
    assert speed[0] > 0.5 * limits[0] or accel[0] > 0.5 * limits[1]  # the limits bind
    kf = load_keyframe_file(keys)
    within = envelope_check(gimbal_config_from_tables(kf.tables, kf.path))
    assert within(traj.q, traj.qd, traj.qdd).all()
    # both targets reached: the second in mid-motion of the first, ending at rest on it
    np.testing.assert_allclose(np.degrees(traj.q[-1]), [-10, 12, 0], atol=1e-6)
    np.testing.assert_allclose(traj.qd[-1], 0.0, atol=1e-9)
    # the goals on the bus: the tracker's frames through the same lead as any follow frame
    with open(log, newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["phase"] == "stream"]
    joints = ("pan", "tilt", "roll")
    plan = np.array([[float(r[f"plan_rad_{j}"]) for j in joints] for r in rows])
    goal = np.array([[float(r[f"goal_rad_{j}"]) for j in joints] for r in rows])
    np.testing.assert_array_equal(plan, traj.q)
    leader = Leader(gimbal_config_from_tables(kf.tables, kf.path), "model")
    led = leader.frames(iter(traj), rate, np.array(GimbalKinematics().limits_rad))
    np.testing.assert_allclose(goal, [f.goal for f in led], atol=1e-12)
    assert np.abs(goal - plan).max() > 0.005  # led: ahead of the plan while it moves


def test_follow_on_a_virtual_bus_is_the_same_on_a_host_slower_than_real_time(tmp_path):
    """``Session.follow`` on a virtual bus runs on simulated time paced by the wall clock:
    a plant that takes 10 ms of wall time per 5 ms period cannot keep real time, and the
    stream is still the same, frame for frame and row for row (times included), with no
    stall; how far simulated time fell behind the wall clock is said instead."""
    from trajgen.drivers.clock import PacedClock
    from trajgen.drivers.config import BusConfig
    from trajgen.drivers.virtual.plant import FirstOrderPlant

    class SlowPlant(FirstOrderPlant):
        def advance(self, dt_s):
            time.sleep(0.01)
            super().advance(dt_s)

    keys = tmp_path / "keys.toml"
    keys.write_text("[[keyframes]]\nt = 0.0\npan = 0.0\n\n[[keyframes]]\nt = 0.5\npan = 5.0\n")
    runs = {}
    for name, plant in (("quick", FirstOrderPlant()), ("slow", SlowPlant())):
        f = follow.Follower(follow.online_spline(load_keyframe_file(keys)), RATE_HZ)
        log = tmp_path / f"{name}.csv"
        config = BusConfig(configure=True)  # Extended Position Mode: follow's whole range
        outcome = Session(config, plant=plant, telemetry=log).follow(f, [])
        assert outcome.ok, outcome.stopped_by
        assert isinstance(outcome.clock, PacedClock)
        assert outcome.stats.stalls == 0 and outcome.stats.lateness_max_s == 0.0
        runs[name] = (outcome, log.read_text())
    (quick, quick_rows), (slow, slow_rows) = runs["quick"], runs["slow"]
    assert slow_rows == quick_rows and quick_rows.count("\n") > 100
    np.testing.assert_array_equal(slow.trajectory.q, quick.trajectory.q)
    # At least 5 ms behind per frame, less the 50 ms caught up: said, not failed.
    assert slow.clock.shifts >= 1 and slow.clock.behind_now_s > 0.4
    assert "behind the wall clock" in slow.clock.format()
