"""``trajgen follow`` on gimbals other than pan-tilt-roll: lines by the file's joint
names, a two-axis head's quaternions and points to look at (the look direction exact),
untimed targets; through the Follower and through the CLI on a virtual bus."""

import csv
import io
import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from trajgen import follower as follow
from trajgen import quat as Q
from trajgen.axes import AxisSequence
from trajgen.cli import main
from trajgen.errors import KeyframeFileError
from trajgen.jobs.stream_job import kinematics_of
from trajgen.keyframe_lines import parse_line
from trajgen.keyframes import load_keyframe_file

EXAMPLES = Path(__file__).parents[1] / "examples"
RATE_HZ = 200.0


def _follower(name):
    kf = load_keyframe_file(EXAMPLES / name)
    return follow.Follower(follow.online_spline(kf), RATE_HZ, kinematics_of(kf))


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _angle(a, b):
    """Angle (rad) between two directions, accurate near 0."""
    a, b = _unit(a), _unit(b)
    return math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b)))


def test_a_heads_lines_by_joint_name_and_quat_pass_exactly():
    f = _follower("pan_tilt_head.toml")
    kin = f.kinematics
    # a quaternion with a turn about the look axis the head cannot make: its look kept
    q = _unit([0.9, 0.1, 0.2, -0.3])
    f.feed('{"in": 1.0, "pan": 20, "tilt": -5}', 1)
    f.feed(f'{{"t": 2.5, "quat": {q.tolist()}, "mode": "extend"}}', 2)
    f.spline.close()  # no more lines: the stream ends at the last keyframe
    frames = list(f.frames())
    t = np.array([x.t for x in frames])
    a = np.array([x.q for x in frames])
    assert a.shape[1] == 2 and [k["t"] for k in f.keyframes] == [1.0, 2.5]
    i, j = (int(np.argmin(np.abs(t - k))) for k in (1.0, 2.5))
    assert abs(t[i] - 1.0) < 1e-9 and abs(t[j] - 2.5) < 1e-9
    np.testing.assert_allclose(np.degrees(a[i]), [20.0, -5.0], atol=1e-9)
    assert _angle(kin.look_direction(a[j]), Q.rotate(q, AxisSequence("zy").look)) < 1e-9
    np.testing.assert_allclose(frames[-1].qd, 0.0, atol=1e-9)


def test_a_heads_untimed_point_is_looked_at_exactly():
    f = _follower("pan_tilt_head.toml")
    f.feed('{"look_at": [0.5, -2.0, -0.8]}', 1)  # reached as early as allowed
    f.spline.close()  # no more lines: the stream ends at the last keyframe
    frames = list(f.frames())
    assert f.keyframes[-1]["mode"] == "track"
    assert _angle(f.kinematics.look_direction(frames[-1].q), [0.5, -2.0, -0.8]) < 1e-9
    np.testing.assert_allclose(frames[-1].qd, 0.0, atol=1e-9)


def test_a_wrists_untimed_angles_by_name_are_reached_at_rest():
    f = _follower("flex_roll_wrist.toml")
    f.feed('{"wrist_flex": 30, "wrist_roll": -20, "max_speed": 90}', 1)
    f.spline.close()  # no more lines: the stream ends at the last keyframe
    frames = list(f.frames())
    np.testing.assert_allclose(np.degrees(frames[-1].q), [30.0, -20.0], atol=1e-9)
    speed = np.abs([x.qd for x in frames]).max()
    assert speed <= math.radians(90) + 1e-9
    assert f.trajectory().q.shape == (len(frames), 2)


@pytest.mark.parametrize(
    ("axes", "line", "message"),
    [
        (AxisSequence("zy"), '{"in": 1, "roll": 2}', "unknown field 'roll'"),
        (AxisSequence("zy"), '{"in": 1, "pan": 2, "quat": [1, 0, 0, 0]}', "either 'quat' or"),
        (AxisSequence("zy"), '{"in": 1, "pan": 2, "look": [1, 0, 0]}', "either 'look' or"),
        (AxisSequence("zy"), '{"in": 1, "look": [0, 0, 0]}', "field 'look': expected a non-zero"),
        (AxisSequence("yx", ("flex", "roll")), '{"flex": "x"}', "field 'flex': expected a finite"),
        (AxisSequence("yx", ("flex", "roll")), "{}", "a target: 'flex'/'roll', 'quat' or"),
        (AxisSequence("xyz"), '{"look_at": [1, 0, 0]}', "not axes 'xyz'; give 'quat' or joint1"),
    ],
)
def test_a_bad_line_names_the_gimbals_own_fields(axes, line, message):
    with pytest.raises(KeyframeFileError, match=r"^stdin: line 4: .*" + re.escape(message)):
        parse_line(line, "stdin: line 4", axes)


def test_a_three_axis_gimbals_quat_and_angles_agree():
    axes = AxisSequence("xyz", ("a", "b", "c"))
    angles = np.radians([10.0, -20.0, 30.0])
    _, by_name, _, _ = parse_line('{"in": 1, "a": 10, "b": -20, "c": 30}', "x", axes)
    _, by_quat, _, _ = parse_line(
        f'{{"in": 1, "quat": {axes.forward(angles).tolist()}}}', "x", axes
    )
    assert Q.distance(by_name, axes.forward(angles)) < 1e-12
    assert Q.distance(by_quat, by_name) < 1e-12


def _run_follow(monkeypatch, tmp_path, name, lines, gimbal=""):
    made = []

    class Recorded(follow.Follower):
        """The command's follower, kept for the checks."""

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr("trajgen.cli.follow.Follower", Recorded)
    # A tracking budget for the lag of quick moves and the first frames' gravity sag,
    # room in the Bus Watchdog for stalls of a busy machine; 50 Hz leaves each frame
    # room for the virtual bus's read-back there.
    keys = tmp_path / name
    keys.write_text(
        (EXAMPLES / name)
        .read_text()
        .replace("[gimbal]\n", f"[gimbal]\nmax_tracking_error_rad = 0.15\n{gimbal}", 1)
        .replace("[bus]\n", "[bus]\nwatchdog_s = 0.5\n", 1)
    )
    monkeypatch.setattr(sys, "stdin", io.StringIO("".join(f"{x}\n" for x in lines)))
    out, log = tmp_path / "follow.json", tmp_path / "follow.csv"
    argv = ["follow", str(keys), "--virtual", "--configure", "--max-delay", "60", "--rate", "50"]
    status = main([*argv, "--json", str(out), "--telemetry", str(log)])
    assert status == 0, out.read_text() if out.exists() else "no report"
    with open(log, newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["phase"] == "stream"]
    (follower,) = made
    return json.loads(out.read_text()), follower, rows


def test_follow_cli_streams_a_pan_tilt_head_to_a_point_on_the_virtual_bus(monkeypatch, tmp_path):
    point = [1.0, 1.0, -0.5]
    run, f, rows = _run_follow(
        monkeypatch,
        tmp_path,
        "pan_tilt_head.toml",
        ['{"pan": 40, "tilt": 10}', json.dumps({"look_at": point})],
        # The camera on the tilt axis: the example's, 30 mm ahead, makes the simulated
        # tilt fall while its torque is off, and bring-up, reading it in real time on a
        # busy machine, may see it still moving after torque on and refuse to start.
        gimbal="payload_offset_m = [0.0, 0.0, 0.0]\n",
    )
    assert run["follow"]["accepted"] == 2 and run["stream"]["fault"] == ""
    assert run["torque"]["ok"]
    traj = f.trajectory()
    assert _angle(f.kinematics.look_direction(traj.q[-1]), point) < 1e-9
    # the telemetry's columns are the file's joints; its plan is what was streamed
    plan = np.array([[float(r[f"plan_rad_{j}"]) for j in ("pan", "tilt")] for r in rows])
    np.testing.assert_array_equal(plan, traj.q)
    assert "plan_rad_roll" not in rows[0]


def test_follow_cli_streams_a_flex_roll_wrist_by_joint_name(monkeypatch, tmp_path):
    run, f, _ = _run_follow(
        monkeypatch,
        tmp_path,
        "flex_roll_wrist.toml",
        ['{"wrist_flex": 30, "wrist_roll": -20}', '{"in": 1, "wrist_roll": 15, "mode": "extend"}'],
    )
    assert run["follow"]["accepted"] == 2 and run["torque"]["ok"]
    traj = f.trajectory()
    np.testing.assert_allclose(np.degrees(traj.q[-1]), [0.0, 15.0], atol=1e-6)
    np.testing.assert_allclose(traj.qd[-1], 0.0, atol=1e-9)
