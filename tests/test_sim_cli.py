"""The ``trajgen sim`` command and the keyframe file's [gimbal] table."""

import argparse
import json
import re

import pytest

from trajgen.cli import main
from trajgen.cli.sim import run_sim
from trajgen.sim.model import GimbalConfig, JointParams, gimbal_config_from_tables

keyframes = pytest.importorskip("trajgen.keyframes")

LOOK_AROUND = [(0.0, 0, 0), (1.5, 40, 10), (3.0, 60, -15), (4.5, 0, 20), (6.0, -30, 0), (7.0, 0, 0)]


def _write_keyframes(path, time_scale=1.0, extra=""):
    lines = [extra]
    for t, pan, tilt in LOOK_AROUND:
        lines += ["[[keyframes]]", f"t = {t * time_scale}", f"pan = {pan}", f"tilt = {tilt}", ""]
    path.write_text("\n".join(lines))
    return path


def _sim(argv):
    return main(["sim", *map(str, argv)])


def test_gentle_file_passes_with_json_and_plot(tmp_path, capsys):
    # Pan peaks at 1.1 rad/s: with P 800 it lags 3 deg, over the default budget;
    # the gimbal's pan servo runs P 1600 (set on the servo and in the file).
    extra = "[stream]\nrate_hz = 100\n[gimbal.pan]\nposition_p_gain = 1600\n"
    path = _write_keyframes(tmp_path / "gentle.toml", extra=extra)
    status = _sim([path, "--json", tmp_path / "r.json", "--plot", tmp_path / "r.png"])
    out = capsys.readouterr().out
    assert status == 0
    assert out.startswith("torque check: OK (7.00 s at 100 Hz")
    assert f"plot: {tmp_path / 'r.png'}" in out
    assert (tmp_path / "r.png").stat().st_size > 10_000
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["ok"] is True and report["rate_hz"] == 100.0


def test_ten_times_faster_fails_with_status_1(tmp_path, capsys):
    path = _write_keyframes(tmp_path / "fast.toml", time_scale=0.1)
    assert _sim([path, "--rate", 200]) == 1
    out = capsys.readouterr().out
    assert out.startswith("torque check: FAILED")
    assert "x envelope" in out


def test_gimbal_table_changes_the_verdict(tmp_path, capsys):
    # At 0.3x the time the XM430-W350 (4.8 rad/s no load) keeps up; an XM540-W270
    # on pan has more torque but only 3.1 rad/s and fails. (The tracking budget
    # is wide open: the envelope decides.)
    budget = "[gimbal]\nmax_tracking_error_rad = 0.5\n"
    xm430 = _write_keyframes(tmp_path / "xm430.toml", time_scale=0.3, extra=budget)
    xm540 = _write_keyframes(
        tmp_path / "xm540.toml", time_scale=0.3, extra=budget + 'servo = {pan = "XM540-W270"}\n'
    )
    assert _sim([xm430]) == 0
    assert _sim([xm540]) == 1
    assert "pan   XM540-W270" in capsys.readouterr().out


@pytest.mark.parametrize("rate", ["-5", "nan", "fast"])
def test_bad_rate_exits_2(tmp_path, capsys, rate):
    path = _write_keyframes(tmp_path / "k.toml")
    with pytest.raises(SystemExit) as e:
        _sim([path, "--rate", rate])
    assert e.value.code == 2
    assert re.search(r"--rate: expected a number( > 0)?, got '" + rate, capsys.readouterr().err)


def test_bad_files_exit_2_with_one_line(tmp_path, capsys):
    bad_servo = _write_keyframes(tmp_path / "bad.toml", extra='[gimbal]\nservo = "XM999"\n')
    assert _sim([bad_servo]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"trajgen sim: error: {bad_servo}: [gimbal] servo: unknown model 'XM999' "
        "(known: XM430-W350, XL430-W250, XH430-W350, XM540-W270, XH540-W270, "
        "XL330-M288, XL330-M077, XC330-M288, 2XL430-W250)"
    )
    assert _sim([tmp_path / "missing.toml"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("trajgen sim: error: ") and len(err.splitlines()) == 1


def test_ctrl_c_exits_130_and_still_writes_the_json(monkeypatch, tmp_path):
    def interrupted(*args, progress, **kwargs):
        progress(0.25)
        raise KeyboardInterrupt

    monkeypatch.setattr("trajgen.sim.check.check_torque", interrupted)
    out = tmp_path / "r.json"
    args = argparse.Namespace(
        file=str(keyframes.BUILTIN_EXAMPLE), rate=None, json=str(out), plot=None, video=None
    )
    assert run_sim(args) == 130
    done = json.loads(out.read_text())
    assert done["interrupted"] is True and done["ok"] is None
    assert done["stage"] == "simulating" and done["simulated_fraction"] == 0.25
    assert done["rate_hz"] == 200.0 and done["duration_s"] == 8.0


def test_gimbal_table_parses_every_field():
    tables = {
        "gimbal": {
            "servo": {"pan": "XM540-W270", "roll": "xl430-w250"},
            "payload_kg": 0.3,
            "payload_offset_m": [0.02, 0.0, 0.01],
            "torque_margin": 0.7,
            "max_tracking_error_rad": 0.02,
            "p_divisor": 256,
            "tilt": {"armature": 0.05, "frictionloss": 0.02, "damping": 0.1},
            "roll": {"position_p_gain": 1200},
        }
    }
    config = gimbal_config_from_tables(tables, "f.toml")
    assert config.p_divisor == 256.0
    assert config.joints[0] == JointParams.of(config.servos[0])
    assert config.joints[1] == JointParams(0.05, 0.02, 0.1, 800)
    assert config.joints[2] == JointParams.of(config.servos[2], position_p_gain=1200)
    assert config.joints[2].position_d_gain == 4000  # the XL430-W250's default
    assert [s.name for s in config.servos] == ["XM540-W270", "XM430-W350", "XL430-W250"]
    assert config.payload_kg == 0.3
    assert config.payload_offset_m == (0.02, 0.0, 0.01)
    assert config.torque_margin == 0.7
    assert config.max_tracking_error_rad == 0.02
    assert gimbal_config_from_tables({}, "f.toml") == GimbalConfig()


@pytest.mark.parametrize(
    ("gimbal", "message"),
    [
        ({"servo": "XM999"}, "[gimbal] servo: unknown model 'XM999' (known: XM430-W350, "),
        ({"servo": {"yaw": "XM430-W350"}}, "[gimbal] servo: unknown joint 'yaw' (known: pan, "),
        ({"servo": {"tilt": 3}}, "[gimbal] servo.tilt: expected a model name, got 3"),
        ({"servo": 3}, "[gimbal] servo: expected a model name or a table per joint, got 3"),
        (
            {"payload_kg": "abc"},
            "[gimbal] payload_kg: expected a finite number in 0..100, got 'abc'",
        ),
        ({"payload_kg": -1}, "[gimbal] payload_kg: expected a finite number in 0..100, got -1"),
        ({"torque_margin": 2}, "[gimbal] torque_margin: expected a finite number in (0, 1], got 2"),
        (
            {"torque_margin": float("nan")},
            "[gimbal] torque_margin: expected a finite number in (0, 1], got nan",
        ),
        (
            {"payload_offset_m": [0, 0]},
            "[gimbal] payload_offset_m: expected a list of 3 numbers, got [0, 0]",
        ),
        ({"payload": 1}, "[gimbal]: unknown key 'payload' (known: servo, payload_kg, "),
        ({"pan": 3}, "[gimbal.pan]: expected a table, got 3"),
        ({"tilt": {"stiffness": 3}}, "[gimbal.tilt]: unknown key 'stiffness' (known: armature, "),
        ({"roll": {"armature": 0}}, "[gimbal.roll] armature: expected a finite number > 0, got 0"),
        (
            {"roll": {"damping": "x"}},
            "[gimbal.roll] damping: expected a finite number >= 0, got 'x'",
        ),
        (
            {"pan": {"position_p_gain": 80.5}},
            "[gimbal.pan] position_p_gain: expected an integer in 0..16383, got 80.5",
        ),
        (
            {"pan": {"position_p_gain": 20000}},
            "[gimbal.pan] position_p_gain: expected an integer in 0..16383, got 20000",
        ),
        ({"p_divisor": 0}, "[gimbal] p_divisor: expected a finite number > 0, got 0"),
    ],
)
def test_gimbal_table_errors_name_file_table_and_field(gimbal, message):
    with pytest.raises(keyframes.KeyframeFileError) as e:
        gimbal_config_from_tables({"gimbal": gimbal}, "shots/f.toml")
    text = str(e.value)
    assert text.startswith("shots/f.toml: " + message)
    assert "\n" not in text


def test_gimbal_must_be_a_table():
    with pytest.raises(keyframes.KeyframeFileError, match=r"^f.toml: \[gimbal\]: expected a table"):
        gimbal_config_from_tables({"gimbal": 3}, "f.toml")


def test_trajgen_main_runs_the_builtin_example_and_fails_a_fast_file(tmp_path, capsys):
    from trajgen.cli import main

    assert main(["sim"]) == 0
    assert "torque check: OK" in capsys.readouterr().out
    fast = _write_keyframes(tmp_path / "fast.toml", time_scale=0.1)
    assert main(["sim", str(fast)]) == 1


def test_progress_line_appears_only_on_long_runs():
    import io

    from trajgen.cli.common import Progress

    quick = Progress("trajgen sim: simulating", stream=io.StringIO())
    quick(0.5)
    assert quick.stream.getvalue() == ""
    slow = Progress("trajgen sim: simulating", stream=io.StringIO())
    slow.start -= 5.0  # as if the run began 5 s ago
    slow(0.5)
    slow(1.0)
    expected = "\rtrajgen sim: simulating  50%\rtrajgen sim: simulating 100%\n"
    assert slow.stream.getvalue() == expected


def test_the_cli_module_imports_without_mujoco_or_matplotlib():
    import subprocess
    import sys

    code = (
        "import sys, trajgen.cli.sim\nprint('mujoco' in sys.modules, 'matplotlib' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
