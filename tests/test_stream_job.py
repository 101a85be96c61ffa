"""trajgen.jobs.StreamJob: `trajgen stream` as a library call, equal to the command's report."""

import json
import signal
import subprocess
import sys

import pytest

from trajgen.cli import main
from trajgen.drivers.signals import StopSignals
from trajgen.jobs import LimitsRefused, NoPort, StreamJob, run_stream_file

SHORT = """\
[stream]
rate_hz = 100

[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 0.5
pan = 10.0
tilt = 5.0
"""


@pytest.fixture
def short(tmp_path):
    path = tmp_path / "short.toml"
    path.write_text(SHORT)
    return path


def test_the_library_run_gives_the_commands_json_report(short, tmp_path, capsys):
    out = tmp_path / "cli.json"
    assert main(["stream", str(short), "--virtual", "--json", str(out)]) == 0
    capsys.readouterr()
    result = run_stream_file(short, virtual=True)
    assert result.ok and result.exit_status == 0
    # Lock-step simulated time: the same frames, statistics and torque report.
    assert json.loads(json.dumps(result.to_json_dict())) == json.loads(out.read_text())
    assert result.torque is not None and result.torque.ok
    text = result.format()
    assert "servos: hold their last goal" in text
    assert "torque check: OK" in text


def test_a_job_is_planned_before_any_hardware(short):
    job = StreamJob.from_file(short, virtual=True, ids=(4, 5, 6), lead="none", rate_hz=50)
    assert job.rate_hz == 50 and job.lead == "none"
    assert job.config.joints.ids == (4, 5, 6)
    assert len(job.trajectory.t) == 26  # 0.5 s at 50 Hz, both ends
    with pytest.raises(NoPort, match=r"no serial port: give port=, set \[bus\] port"):
        StreamJob.from_file(short)


def test_a_port_that_does_not_open_is_exit_status_2(short, tmp_path):
    result = run_stream_file(short, port=str(tmp_path / "no-such-port"))
    assert result.port_failed and result.exit_status == 2
    assert set(result.outcome.servo_states.values()) == {"untouched"}
    assert result.torque is None


def test_a_stop_signal_is_128_plus_its_number(short):
    signals = StopSignals()
    signals.received = signal.SIGTERM  # arrived while planning: acted on at once
    result = StreamJob.from_file(short, virtual=True).run(stop_signals=signals)
    assert result.outcome.signal == signal.SIGTERM
    assert result.exit_status == 128 + signal.SIGTERM
    assert result.servos_left() == "no servo was touched"
    assert result.to_json_dict()["status"] == 143


def test_limits_the_registers_cannot_hold_name_the_joint(short):
    job = StreamJob.from_file(short, virtual=True, set_limits_rad={1: (-3.5, 0.2)})
    with pytest.raises(LimitsRefused, match=r"^tilt limits: ticks -\d+\.\.\d+ fall") as caught:
        job.run()
    assert caught.value.joint == 1 and caught.value.limits_rad == (-3.5, 0.2)


def test_importing_the_jobs_loads_neither_mujoco_nor_the_servo_sdk():
    code = (
        "import sys, trajgen.jobs; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('mujoco', 'dynamixel_sdk')))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
