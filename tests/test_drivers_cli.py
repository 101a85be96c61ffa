"""``trajgen stream`` / ``trajgen scan`` and the keyframe file's [bus] table."""

import argparse
import csv
import json
import math
import os
import signal

import numpy as np
import pytest

from trajgen.cli import scan, stream
from trajgen.drivers.config import BusConfig, bus_config_from_tables
from trajgen.drivers.control_table import Register
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant

keyframes = pytest.importorskip("trajgen.keyframes")

SHORT = [(0.0, 0, 0), (0.4, 10, 5), (0.8, 0, 0)]


def _write(path, extra=""):
    lines = [extra, "[stream]", "rate_hz = 100", ""]
    for t, pan, tilt in SHORT:
        lines += ["[[keyframes]]", f"t = {t}", f"pan = {pan}", f"tilt = {tilt}", ""]
    path.write_text("\n".join(lines))
    return path


def _run(argv):
    parser = argparse.ArgumentParser(prog="trajgen")
    sub = parser.add_subparsers()
    stream.register(sub)
    scan.register(sub)
    args = parser.parse_args([str(a) for a in argv])
    return args.func(args)


def test_bus_table_defaults_and_values():
    assert bus_config_from_tables({}, "f.toml") == BusConfig()
    config = bus_config_from_tables(
        {
            "bus": {
                "port": "/dev/ttyUSB1",
                "baud": 4_000_000,
                "ids": [4, 5, 6],
                "directions": [1, -1, 1],
                "zeros": [2048, 1024, 3000],
                "watchdog_s": 0.2,
            },
            "gimbal": {"servo": {"pan": "XM540-W270"}},
        },
        "f.toml",
    )
    assert config.port == "/dev/ttyUSB1" and config.baud == 4_000_000
    assert config.joints == JointMap((4, 5, 6), (1, -1, 1), (2048, 1024, 3000))
    assert config.models == ("XM540-W270", "XM430-W350", "XM430-W350")
    assert config.watchdog_s == 0.2


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ({"speed": 1}, r"f.toml: \[bus\]: unknown key 'speed' \(known: port, baud"),
        ({"baud": "fast"}, r"f.toml: \[bus\] baud: expected an integer, got 'fast'"),
        ({"ids": [1, 1, 2]}, r"\[bus\] ids: expected 3 distinct ids, got \[1, 1, 2\]"),
        (
            {"ids": [1, 2]},
            r"\[bus\] ids: expected a list of 3 integers, got \[1, 2\] "
            r"\(one per joint: pan, tilt, roll\)",
        ),
        ({"directions": [1, 0, 1]}, r"\[bus\] directions: expected \+1 or -1 each, got"),
        ({"models": "XM999"}, r"\[bus\] models: unknown model 'XM999' \(known: XM430-W350"),
        ({"watchdog_s": 5}, r"\[bus\] watchdog_s: expected a finite number in 0.02..2.54, got 5"),
        ({"port": 3}, r"\[bus\] port: expected a device path string, got 3"),
    ],
)
def test_bus_table_errors(table, match):
    with pytest.raises(keyframes.KeyframeFileError, match=match):
        bus_config_from_tables({"bus": table}, "f.toml")


def test_stream_virtual_end_to_end(tmp_path, capsys):
    # Pan peaks at 0.9 rad/s: with default gains the servo lags 3.1 deg (45 ms).
    path = _write(tmp_path / "short.toml", extra="[gimbal]\nmax_tracking_error_rad = 0.07\n")
    status = _run(
        [
            "stream",
            path,
            "--virtual",
            "--telemetry",
            tmp_path / "t.csv",
            "--json",
            tmp_path / "r.json",
        ]
    )
    out = capsys.readouterr().out
    assert status == 0, out
    # 33 lift frames first (the tilt's static gravity term, 0.33 s: trajgen.lift)
    assert out.startswith("frames sent: 81/81 (+0 approach, +33 lift, 0.330 s) at 100 Hz planned")
    assert "torque check: OK" in out
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["stream"]["frames_sent"] == 81 and result["stream"]["lift_frames"] == 33
    assert result["stream"]["fault"] == ""
    assert result["torque"]["ok"] is True and result["torque"]["lift_s"] == pytest.approx(0.33)
    with open(tmp_path / "t.csv", newline="") as f:
        phases = [r["phase"] for r in csv.DictReader(f)]
    assert phases == ["lift"] * 33 + ["stream"] * 81


def test_stream_virtual_from_a_pose_away_from_zero_and_across_180_deg(tmp_path, capsys):
    # The simulated gimbal powers up at the first frame: no approach move in the record,
    # so the torque report compares the stream with itself, not with a move from 0 rad.
    path = tmp_path / "offset.toml"
    path.write_text(
        "[stream]\nrate_hz = 100\n"
        "[gimbal]\nmax_tracking_error_rad = 0.15\n"  # pan at 1.6 rad/s lags 45 ms x speed
        "[[keyframes]]\nt = 0.0\npan = 30.0\ntilt = 10.0\n"
        "[[keyframes]]\nt = 2.0\npan = 100.0\ntilt = 5.0\n"
        "[[keyframes]]\nt = 4.0\npan = 200.0\n"
    )
    # Across 180 deg: Extended Position Mode, an EEPROM change, made only when asked.
    status = _run(["stream", path, "--virtual", "--json", tmp_path / "r.json"])
    assert status == 1
    assert "Operating Mode (register 11) is 3 (position control)" in capsys.readouterr().err
    status = _run(["stream", path, "--virtual", "--configure", "--json", tmp_path / "r.json"])
    out = capsys.readouterr().out
    assert status == 0, out
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["torque"]["ok"] is True
    assert result["torque"]["joints"]["pan"]["max_tracking_error_rad"] < 0.15


def test_stream_to_a_port_and_wrong_model(tmp_path, capsys, answered_here):
    with answered_here(VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01)) as virtual:
        ok = _write(tmp_path / "ok.toml")
        assert _run(["stream", ok, "--port", virtual.port, "--torque-off"]) == 0
        assert "frames sent: 81/81" in capsys.readouterr().out
        assert not any(servo.torque_on for servo in virtual.servos.values())
        wrong = _write(tmp_path / "wrong.toml", extra='[bus]\nmodels = "XL430-W250"\n')
        assert _run(["stream", wrong, "--port", virtual.port]) == 1
    err = capsys.readouterr().err
    assert err.startswith("trajgen: stream failed: servo 1: model number 1020 (XM430-W350), ")
    assert "refusing to stream" in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "no serial port: give --port, set [bus] port, or use --virtual"),
        (["--port", "/dev/x", "--plot", "p.png"], "--plot needs --virtual"),
        (
            ["--virtual", "--telemetry", "t.txt"],
            "--telemetry 't.txt': expected a .csv or .npz or .mcap file",
        ),
        (
            ["--virtual", "--telemetry", "/no/dir/t.csv"],
            "--telemetry '/no/dir/t.csv': no such folder",
        ),
        (["--port", "/nonexistent/tty"], "/nonexistent/tty: cannot open at 1000000 baud"),
    ],
)
def test_stream_bad_input_exits_2_with_one_line(tmp_path, capsys, argv, message):
    path = _write(tmp_path / "k.toml")
    assert _run(["stream", path, *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("trajgen: error: ") and message in err


def test_stream_missing_file_exits_2(tmp_path, capsys):
    assert _run(["stream", tmp_path / "none.toml", "--virtual"]) == 2
    assert "no such file" in capsys.readouterr().err


def test_port_and_virtual_exclude_each_other_in_the_parser(capsys):
    with pytest.raises(SystemExit):
        _run(["stream", "--port", "/dev/x", "--virtual"])
    assert "argument --virtual: not allowed with argument --port" in capsys.readouterr().err


def test_ids_flag_is_checked(capsys):
    with pytest.raises(SystemExit):
        _run(["stream", "--virtual", "--ids", "1,1,2"])
    assert "expected distinct ids in 0..252, got '1,1,2'" in capsys.readouterr().err


def test_scan_lists_servos(capsys):
    with VirtualBus(FirstOrderPlant(), ids=(4, 7, 9), models="XL430-W250") as virtual:
        assert _run(["scan", "--port", virtual.port]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == [f"id {i:3d}  model  1060 (XL430-W250)  firmware 48" for i in (4, 7, 9)]


def test_scan_bad_port_exits_2(capsys):
    assert _run(["scan", "--port", "/nonexistent/tty"]) == 2
    assert capsys.readouterr().err.startswith("trajgen: error: /nonexistent/tty: cannot open")


# -- issue 7: stops, signals, installed settings ------------------------------


class _SignalAtFrame(FirstOrderPlant):
    """A plant that sends this process ``signum`` on its ``frame``-th read.

    A read, not a goal: a signal sent the instant a goal arrives would land, every
    time, in the few microseconds between the goal leaving the driver and the
    driver counting it, which a signal from outside hits almost never.
    """

    def __init__(self, frame, signum):
        super().__init__(time_constant_s=0.01)
        self.frame, self.signum, self.reads = frame, signum, 0

    def read(self):
        self.reads += 1
        if self.reads == self.frame:
            os.kill(os.getpid(), self.signum)
        return super().read()


@pytest.mark.parametrize(
    ("signum", "status", "torque_off"),
    [(signal.SIGTERM, 143, True), (signal.SIGHUP, 129, False), (signal.SIGINT, 130, True)],
    ids=["SIGTERM", "SIGHUP", "SIGINT"],
)
def test_stop_signal_stops_safely_and_keeps_every_record(
    tmp_path, capsys, answered_here, signum, status, torque_off
):
    path = _write(tmp_path / "k.toml")
    argv = ["stream", path, "--telemetry", tmp_path / "t.npz", "--json", tmp_path / "r.json"]
    argv += ["--torque-off"] if torque_off else []
    with answered_here(VirtualBus(_SignalAtFrame(150, signum), lockstep_dt_s=0.01)) as virtual:
        assert _run([*argv, "--port", virtual.port]) == status
        torque = [servo.torque_on for servo in virtual.servos.values()]
        watchdog = [servo.get(Register.BUS_WATCHDOG) for servo in virtual.servos.values()]
        received = virtual.frames_received
    captured = capsys.readouterr()
    name = signal.Signals(signum).name
    state = (
        "the servos were released (torque off)" if torque_off else "the servos hold their last goal"
    )
    assert f"trajgen: interrupted: interrupted by {name}; {state}" in captured.err
    assert torque == [not torque_off] * 3
    if not torque_off:
        assert watchdog == [0, 0, 0]  # held goals are not dropped by a watchdog later
    assert 20 <= received < 151  # stopped mid-stream (bring-up reads too)
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["status"] == status and result["stopped_by"] == f"interrupted by {name}"
    assert result["on_stop"] == ("torque_off" if torque_off else "hold")
    # Each servo's state as read back after the safe stop.
    assert result["servos"] == dict.fromkeys("123", "released" if torque_off else "holding")
    # stopped after the lift (trajgen.lift: the tilt's static term brought in first)
    assert result["stream"]["frames_sent"] + result["stream"]["lift_frames"] == received
    assert len(np.load(tmp_path / "t.npz")["frame"]) == received


def test_torque_off_at_the_end_says_released(tmp_path, capsys, answered_here):
    with answered_here(VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01)) as virtual:
        assert _run(["stream", _write(tmp_path / "k.toml"), "--port", virtual.port]) == 0
        assert "servos: hold their last goal" in capsys.readouterr().out
        assert _run(["stream", tmp_path / "k.toml", "--port", virtual.port, "--torque-off"]) == 0
        assert "servos: were released (torque off)" in capsys.readouterr().out


def test_command_line_uses_the_tested_bring_up(tmp_path, capsys, monkeypatch, answered_here):
    from trajgen.drivers import bringup

    calls = []
    real = bringup.bring_up

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr("trajgen.drivers.bringup.bring_up", spy)
    with answered_here(VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01)) as virtual:
        assert _run(["stream", _write(tmp_path / "k.toml"), "--port", virtual.port]) == 0
    assert len(calls) == 1 and calls[0]["max_approach_rad"] == pytest.approx(math.radians(45))


def test_installed_limits_refuse_then_set_limits_writes_them(tmp_path, capsys, answered_here):
    path = _write(tmp_path / "k.toml")  # tilt goes to 5 deg (tick 2105) at t = 0.4 s
    limits = {Register.MIN_POSITION_LIMIT: 2000, Register.MAX_POSITION_LIMIT: 2080}
    with answered_here(
        VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01, registers={2: limits})
    ) as virtual:
        assert _run(["stream", path, "--port", virtual.port, "--json", tmp_path / "r.json"]) == 1
        err = capsys.readouterr().err
        assert virtual.frames_received == 0
        assert not any(servo.torque_on for servo in virtual.servos.values())
        tilt = virtual.servos[2]
        assert (tilt.get(Register.MIN_POSITION_LIMIT), tilt.get(Register.MAX_POSITION_LIMIT)) == (
            2000,
            2080,
        )
        assert _run(["stream", path, "--port", virtual.port, "--set-limits", "tilt=-20:20"]) == 0
        assert (tilt.get(Register.MIN_POSITION_LIMIT), tilt.get(Register.MAX_POSITION_LIMIT)) == (
            2048 - 228,
            2048 + 228,
        )
    assert err.startswith("trajgen: stream failed: tilt leaves its position limits at t = 0.")
    assert "past the Max Position Limit 2080 (2.8 deg) of servo 2" in err
    assert err.rstrip().endswith("bring-up refused before torque on: no servo was moved")
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["status"] == 1 and result["stream"] is None


def test_set_limits_bad_values(tmp_path, capsys):
    path = _write(tmp_path / "k.toml")
    assert _run(["stream", path, "--virtual", "--set-limits", "tilt=-200:10"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("trajgen: error: --set-limits tilt=-200:10: ticks -228..2162 fall")
    assert _run(["stream", path, "--virtual", "--set-limits", "yaw=1:2"]) == 2
    err = capsys.readouterr().err
    assert "limits for 'yaw': not a joint of this gimbal (one of pan, tilt, roll)" in err
    with pytest.raises(SystemExit):
        _run(["stream", path, "--virtual", "--set-limits", "9x=1:2"])
    assert "expected a joint name, got '9x'" in capsys.readouterr().err


def test_fast_sync_read_fallback_is_said_on_stderr(tmp_path, capsys, answered_here):
    path = _write(tmp_path / "k.toml")
    with answered_here(
        VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01, fast_sync_read=False)
    ) as virtual:
        assert _run(["stream", path, "--port", virtual.port, "--json", tmp_path / "r.json"]) == 0
    err = capsys.readouterr().err
    assert "trajgen: warning: fast sync read failed (servos [1, 2, 3]: " in err
    assert "reading back by sync read for this stream" in err
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["stream"]["read_method"] == "sync read"
    assert "There is no status packet" in result["stream"]["read_fallback"]
