"""Excitation, identification from telemetry, and the virtual servo's own registers."""

import argparse
import contextlib

import numpy as np
import pytest
from conftest import quintic_trajectory
from serial import SerialException

from trajgen.cli import excite, identify
from trajgen.cli.identify import fitted_file_text
from trajgen.sim.excite import BAND_HZ, Multisine
from trajgen.sim.firmware import PULSES_PER_RAD, UnsupportedServoSetting
from trajgen.sim.identify import IdentifyError, load_telemetry
from trajgen.sim.plant import GimbalPlant
from trajgen.stream import plan_joint_trajectory


def _run(module, argv):
    parser = argparse.ArgumentParser(prog="trajgen")
    module.register(parser.add_subparsers())
    args = parser.parse_args([str(a) for a in argv])
    return args.func(args)


def test_multisine_is_rest_to_rest_in_its_band_and_plans_back_to_itself():
    motion = Multisine(center_rad=(0.4, 0.1, -0.2), seconds=5.0)
    assert BAND_HZ[0] <= motion.frequencies_hz.min() < motion.frequencies_hz.max() <= BAND_HZ[1]
    assert len(np.unique(motion.frequencies_hz.round(9))) == motion.frequencies_hz.size
    t = np.linspace(0.0, 5.0, 5001)
    q, qd, qdd = motion.joints(t)
    for end in (0, -1):
        np.testing.assert_allclose(q[end], [0.4, 0.1, -0.2], atol=1e-15)
        np.testing.assert_allclose(qd[end], 0.0, atol=1e-15)
        np.testing.assert_allclose(qdd[end], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(q - q[0]).max(axis=0), motion.amplitude_rad, rtol=1e-3)
    # Derivatives by central differences.
    np.testing.assert_allclose(np.gradient(q, t, axis=0)[1:-1], qd[1:-1], atol=2e-4)
    np.testing.assert_allclose(np.gradient(qd, t, axis=0)[1:-1], qdd[1:-1], atol=5e-3)
    # As an orientation path, planned like a keyframe file, it gives its joints back.
    trajectory = plan_joint_trajectory(motion, 200.0)
    q, qd, qdd = motion.joints(trajectory.t)
    np.testing.assert_allclose(trajectory.q, q, atol=1e-12)
    np.testing.assert_allclose(trajectory.qd, qd, atol=1e-12)
    np.testing.assert_allclose(trajectory.qdd, qdd, atol=1e-10)
    with pytest.raises(ValueError, match=r"`seconds` >= 3 \(two ramps and 1 s\), got 2.0"):
        Multisine(seconds=2.0)


def _write(path, extra=""):
    path.write_text(
        f"{extra}\n[stream]\nrate_hz = 200\n"
        "[[keyframes]]\nt = 0.0\npan = 10.0\ntilt = 5.0\n"
        "[[keyframes]]\nt = 1.0\npan = 20.0\n"
    )
    return path


TRUE = {  # non-default: heavier, stiffer, more friction than the model's defaults
    "pan": {"armature": 0.06, "frictionloss": 0.05, "damping": 0.05, "position_p_gain": 1000},
    "tilt": {"armature": 0.035, "frictionloss": 0.02, "damping": 0.1, "position_p_gain": 640},
    "roll": {"armature": 0.05, "frictionloss": 0.04, "damping": 0.03, "position_p_gain": 900},
}


def test_excite_then_identify_recovers_a_simulated_gimbal(tmp_path, capsys):
    tables = "".join(
        f"[gimbal.{joint}]\n" + "".join(f"{k} = {v}\n" for k, v in values.items())
        for joint, values in TRUE.items()
    )
    truth = _write(tmp_path / "truth.toml", tables)
    log = tmp_path / "excite.csv"
    status = _run(excite, ["excite", truth, "--virtual", "--telemetry", log, "--seconds", 4])
    out = capsys.readouterr().out
    assert status == 0, out
    assert "torque check: OK" in out and f"next: trajgen identify {truth} {log}" in out

    # Fit from the defaults (0.045, 0.03, 0.01, P 800), knowing only the servos.
    nominal = _write(tmp_path / "gimbal.toml", "# my gimbal\n[gimbal.pan]\narmature = 0.045\n")
    fitted = tmp_path / "fitted.toml"
    assert _run(identify, ["identify", nominal, log, "--out", fitted]) == 0
    out = capsys.readouterr().out
    assert out.startswith("joint parameter")
    assert f"fitted: {fitted}" in out
    from trajgen.keyframes import load_keyframe_file
    from trajgen.sim.model import gimbal_config_from_tables

    kf = load_keyframe_file(fitted)
    config = gimbal_config_from_tables(kf.tables, kf.path)
    tolerance = {"armature": 0.05, "frictionloss": 0.10, "damping": 0.25, "position_p_gain": 0.05}
    for j, joint in enumerate(("pan", "tilt", "roll")):
        for name, rel in tolerance.items():
            got, want = getattr(config.joints[j], name), TRUE[joint][name]
            assert got == pytest.approx(want, rel=rel), (joint, name, got, want)
    assert len(kf.times) == 2  # the keyframes kept, the old [gimbal.pan] replaced
    assert "# my gimbal" in fitted.read_text() and "# +- " in fitted.read_text()

    # A servo whose current reads 30 % high: --fit-current-scale finds the factor.
    import csv

    with open(log, newline="") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        for joint in ("pan", "tilt", "roll"):
            row[f"current_a_{joint}"] = str(1.3 * float(row[f"current_a_{joint}"]))
    scaled = tmp_path / "scaled.csv"
    with open(scaled, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    argv = ["identify", nominal, scaled, "--out", fitted, "--fit-current-scale"]
    assert _run(identify, argv) == 0
    out = capsys.readouterr().out
    scale = float(out.split("current scale ")[1].split()[0])
    assert scale == pytest.approx(1.3, rel=0.05)
    kf = load_keyframe_file(fitted)
    config = gimbal_config_from_tables(kf.tables, kf.path)
    for j, joint in enumerate(("pan", "tilt", "roll")):
        assert config.joints[j].position_p_gain == pytest.approx(
            TRUE[joint]["position_p_gain"], rel=0.05
        )


def test_a_gentle_move_does_not_excite_damping(tmp_path, capsys):
    # A slow pan-only move: tilt and roll never move, so nothing about them is known
    # (sent as planned: a led goal would move them a little against pan's coupling).
    path = _write(tmp_path / "gentle.toml")
    log = tmp_path / "gentle.csv"
    from trajgen.cli import stream

    argv = ["stream", path, "--virtual", "--telemetry", log, "--lead", "none"]
    assert _run(stream, argv) == 0
    capsys.readouterr()
    assert _run(identify, ["identify", path, log, "--out", tmp_path / "f.toml"]) == 0
    out = capsys.readouterr().out
    assert "tilt damping: not excited enough" in out
    assert "roll armature: not excited enough" in out


def test_fitted_file_replaces_only_the_joint_tables():
    source = (
        "[gimbal]\npayload_kg = 0.2\n\n[gimbal.tilt]  # old\ndamping = 0.5\n\n"
        "[[keyframes]]\nt = 0\npan = 0\n"
    )
    text = fitted_file_text(source, "[gimbal.tilt]\ndamping = 0.1\n", ("pan", "tilt", "roll"))
    assert "damping = 0.5" not in text and "# old" not in text
    assert text.index("payload_kg") < text.index("[[keyframes]]") < text.index("damping = 0.1")
    # a gimbal's own joint names: its tables go, any other [gimbal.x] table stays
    source = source.replace("gimbal.tilt", "gimbal.wrist_roll") + "\n[gimbal.tilt]\nx = 1\n"
    text = fitted_file_text(source, "[gimbal.wrist_roll]\ndamping = 0.1\n", ("wrist_roll",))
    assert "damping = 0.5" not in text and "[gimbal.tilt]\nx = 1" in text


def test_bad_logs_and_options_exit_2(tmp_path, capsys):
    path = _write(tmp_path / "k.toml")
    empty = tmp_path / "empty.csv"
    empty.write_text("frame,phase\n")
    assert _run(identify, ["identify", path, empty, "--out", tmp_path / "f.toml"]) == 2
    assert "empty.csv: not a telemetry log (no column 'frame')" in capsys.readouterr().err
    assert _run(identify, ["identify", path, empty, "--out", tmp_path / "f.txt"]) == 2
    assert "': expected a .toml file" in capsys.readouterr().err
    with pytest.raises(IdentifyError, match=r"no column 'frame'"):
        (tmp_path / "x.csv").write_text("a\n1\n")
        load_telemetry(tmp_path / "x.csv")
    assert _run(excite, ["excite", path, "--virtual", "--telemetry", tmp_path / "t.txt"]) == 2
    assert "': expected a .csv or .npz or .mcap file" in capsys.readouterr().err
    status = _run(
        excite, ["excite", path, "--virtual", "--telemetry", tmp_path / "t.csv", "--seconds", 2]
    )
    assert status == 2
    assert "--seconds: Expected `seconds` >= 3" in capsys.readouterr().err


def test_an_excitation_beyond_the_envelope_is_refused_before_streaming(tmp_path, capsys):
    path = _write(tmp_path / "k.toml", '[gimbal]\nservo = "XL430-W250"\npayload_kg = 1.0\n')
    argv = ["excite", path, "--virtual", "--telemetry", tmp_path / "t.csv", "--amplitude", 60]
    assert _run(excite, argv) == 2
    assert "the excitation leaves the torque envelope: tilt: planned torque" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "t.csv").exists()


def test_missing_sysid_is_named(monkeypatch, tmp_path, capsys):
    import mujoco.sysid

    monkeypatch.delattr(mujoco.sysid, "optimize")
    path = _write(tmp_path / "k.toml")
    log = tmp_path / "l.csv"
    log.write_text(
        "frame,phase,t_s,goal_rad_pan,goal_rad_tilt,goal_rad_roll,position_rad_pan,"
        "position_rad_tilt,position_rad_roll,velocity_rad_s_pan,velocity_rad_s_tilt,"
        "velocity_rad_s_roll\n"
        + "".join(f"{i},stream,{i / 200},0,0,0,0,0,0,0,0,0\n" for i in range(20))
    )
    assert _run(identify, ["identify", path, log, "--out", tmp_path / "f.toml"]) == 2
    assert "pip install 'trajgen[sysid]'" in capsys.readouterr().err


def _sdk_port(virtual):
    from dynamixel_sdk import PacketHandler, PortHandler

    port = PortHandler(virtual.port)
    assert port.openPort() and port.setBaudRate(1_000_000)
    return port, PacketHandler(2.0)


def test_virtual_servo_runs_the_gains_written_to_it():
    from trajgen.drivers.virtual.bus import VirtualBus

    plant = GimbalPlant()
    with VirtualBus(plant, lockstep_dt_s=0.005) as virtual:
        port, packets = _sdk_port(virtual)
        try:
            # Position P Gain (84) and PWM Limit (36, EEPROM: torque is off) of servo 1.
            assert packets.write2ByteTxRx(port, 1, 84, 1600)[:2] == (0, 0)
            assert packets.write2ByteTxRx(port, 1, 36, 442)[:2] == (0, 0)
        finally:
            port.closePort()
    assert plant.loops[0].p_gain == 1600 and plant.loops[0].pwm_cap == 442
    assert plant.loops[1].p_gain == 800
    kp = plant._model.actuator_gainprm[:, 4]
    assert kp[0] == pytest.approx(2 * kp[1])
    assert plant._model.actuator_gainprm[0, 7] == pytest.approx(12.0 * 442 / 885)

    # And the motion follows: twice the gain, half the lag.
    def lag(p_gain):
        plant = GimbalPlant()
        plant.set_control(0, {"Position P Gain": p_gain})
        plant.set_torque_enabled(0, True)
        trajectory = quintic_trajectory([0.5, 0.0, 0.0], 1.0)
        for frame in trajectory:
            plant.set_goal(np.round(frame.q * PULSES_PER_RAD) / PULSES_PER_RAD)
            plant.advance(0.005)
        return plant.report(trajectory).joints["pan"].max_tracking_error_rad

    assert lag(1600) == pytest.approx(lag(800) / 2, rel=0.1)


def test_a_profile_written_to_a_virtual_servo_stops_the_bus_with_the_reason():
    from trajgen.drivers.virtual.bus import VirtualBus

    plant = GimbalPlant()
    with VirtualBus(plant, lockstep_dt_s=0.005) as virtual:
        port, packets = _sdk_port(virtual)
        try:
            # The bus stops: the SDK sees no reply, or the port going away.
            with contextlib.suppress(SerialException):
                packets.write4ByteTxRx(port, 2, 112, 100)  # Profile Velocity
        finally:
            port.closePort()
        assert isinstance(virtual.error, UnsupportedServoSetting)
        assert "tilt: Profile Velocity 100 is not simulated" in str(virtual.error)


def test_file_gains_reach_the_virtual_servos():
    # What `trajgen stream --virtual` does: the servos power up with the file's gains.
    from trajgen.drivers.virtual.bus import VirtualBus
    from trajgen.sim.model import GimbalConfig

    plant = GimbalPlant(GimbalConfig(joints=({}, {}, {"position_p_gain": 1234})))
    registers = dict(zip((1, 2, 3), plant.initial_registers(), strict=True))
    with VirtualBus(plant, lockstep_dt_s=0.005, registers=registers) as virtual:
        port, packets = _sdk_port(virtual)
        try:
            value, result, error = packets.read2ByteTxRx(port, 3, 84)
        finally:
            port.closePort()
    assert (value, result, error) == (1234, 0, 0)
    assert [loop.p_gain for loop in plant.loops] == [800, 800, 1234]


def test_trajgen_sim_and_the_virtual_stream_agree(tmp_path, capsys):
    import json

    from trajgen.cli import sim, stream

    path = _write(tmp_path / "k.toml", "[gimbal.tilt]\nposition_p_gain = 1500\n")
    assert _run(sim, ["sim", path, "--json", tmp_path / "sim.json"]) == 0
    assert _run(stream, ["stream", path, "--virtual", "--json", tmp_path / "bus.json"]) == 0
    capsys.readouterr()
    offline = json.loads((tmp_path / "sim.json").read_text())["joints"]
    virtual = json.loads((tmp_path / "bus.json").read_text())["torque"]["joints"]
    # Equal but for the start: `trajgen sim` starts the servos at their frictionless
    # sag under the first goal, the virtual ones have dropped to a rest inside the
    # Coulomb band (frictionloss / kp) around it while they held it through bring-up.
    # (The previous plant differed by 2-4x in peak torque.)
    from trajgen.keyframes import load_keyframe_file
    from trajgen.sim.lead import lead_params
    from trajgen.sim.model import gimbal_config_from_tables

    kf = load_keyframe_file(path)
    params = lead_params(gimbal_config_from_tables(kf.tables, kf.path))
    bands = params.frictionloss_nm / params.kp_nm_rad
    for joint, band in zip(("pan", "tilt", "roll"), bands, strict=True):
        for key in ("peak_torque_nm", "rms_torque_nm"):
            assert virtual[joint][key] == pytest.approx(offline[joint][key], rel=1e-2)
        error = virtual[joint]["max_tracking_error_rad"]
        assert error == pytest.approx(offline[joint]["max_tracking_error_rad"], abs=band)
