"""2 or 3 streamed joints on any ids, a servo model per joint: the [bus] table, the
session, telemetry named by the joints, each servo's state by id, on a virtual
bus (drivers side; the plant is the simple first-order one)."""

import csv
import math
import re

import numpy as np
import pytest

from trajgen import SmoothSpline
from trajgen.drivers.config import BusConfig, bus_config_from_tables
from trajgen.drivers.session import HOLDING, UNTOUCHED, Session
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.errors import KeyframeFileError
from trajgen.gimbal import GimbalKinematics

RATE_HZ = 100.0
OMX = (11, 12, 13, 14, 15, 16)  # an OMX-like arm: the wrist is 14 (flex), 15 (roll)


def _path(kin: GimbalKinematics, seconds: float = 1.0) -> SmoothSpline:
    """Rest, a move of every joint, rest again."""
    a = np.zeros((3, kin.n_joints))
    a[1] = np.radians([20.0, -15.0, 10.0][: kin.n_joints])
    if kin.sequence.kind == "proper-euler":
        a[:, 1] += math.pi / 2
    return SmoothSpline(kin.forward(a), [0.0, seconds / 2, seconds])


# -- the [bus] table -------------------------------------------------------------


def test_a_two_joint_file_takes_two_ids_and_names_its_joints():
    tables = {
        "gimbal": {"axes": "yx", "joints": ["flex", "roll"], "servo": "XL330-M288"},
        "bus": {"ids": [14, 15], "directions": [1, -1]},
    }
    config = bus_config_from_tables(tables, "wrist.toml")
    assert config.joints.ids == (14, 15)
    assert config.joints.directions == (1, -1) and config.joints.zeros == (2048, 2048)
    assert config.joint_names == ("flex", "roll")
    assert config.models == ("XL330-M288", "XL330-M288")


def test_models_per_joint_from_the_joint_tables_then_the_gimbal_servo():
    tables = {
        "gimbal": {
            "axes": "zyx",
            "servo": "XM430-W350",
            "tilt": {"servo": "xl330-m077"},
            "roll": {"servo": "XC330-M288"},
        }
    }
    config = bus_config_from_tables(tables, "f.toml")
    assert config.models == ("XM430-W350", "XL330-M077", "XC330-M288")
    assert config.joints.ids == (1, 2, 3)
    tables["bus"] = {"models": ["XL330-M288", "XL330-M288", "XL330-M288"]}  # [bus] wins
    assert bus_config_from_tables(tables, "f.toml").models == ("XL330-M288",) * 3


@pytest.mark.parametrize(
    "bus, message",
    [
        (
            {"ids": [11, 12, 13]},
            r"\[bus\] ids: expected a list of 2 integers, got \[11, 12, 13\] "
            r"\(one per joint: pan, tilt\)",
        ),
        ({"ids": [11, 11]}, r"\[bus\] ids: expected 2 distinct ids, got \[11, 11\]"),
        (
            {"zeros": [2048] * 3},
            r"\[bus\] zeros: expected a list of 2 integers.* \(one per joint: pan, tilt\)",
        ),
        ({"models": ["XL330-M288"] * 3}, r"\[bus\] models: expected a model name or a list of 2"),
    ],
)
def test_per_joint_lists_have_one_entry_per_joint(bus, message):
    tables = {"gimbal": {"axes": "zy"}, "bus": bus}
    with pytest.raises(KeyframeFileError, match=message):
        bus_config_from_tables(tables, "head.toml")


def test_bus_config_refuses_a_count_of_models_or_names_that_is_not_the_joints():
    with pytest.raises(ValueError, match=re.escape("Expected one of `models` per joint (2)")):
        BusConfig(joints=JointMap((11, 12)))
    with pytest.raises(ValueError, match=re.escape("Expected one of `joint_names` per joint")):
        BusConfig(joints=JointMap((11, 12)), models=("XL330-M288",) * 2)


# -- streaming 2 or 3 joints on any ids ----------------------------------------------


def _config(port, kin, ids, models="XL330-M288"):
    return BusConfig(
        port=port,
        joints=JointMap(ids),
        models=(models,) * len(ids),
        joint_names=kin.joints,
    )


@pytest.mark.parametrize(
    "axes, joints, ids",
    [
        ("zy", ("pan", "tilt"), (11, 12)),
        ("yx", ("wrist_flex", "wrist_roll"), (14, 15)),
        ("xyz", None, (21, 7, 30)),
        ("zxz", None, (4, 5, 6)),
    ],
)
def test_a_stream_of_any_axes_on_any_ids_sends_the_plan(tmp_path, answered_here, axes, joints, ids):
    kin = GimbalKinematics(axes=axes, joints=joints)
    path = _path(kin)
    start = kin.inverse(path.quats[:1])[0]  # the first keyframe's angles
    plant = FirstOrderPlant(len(ids), initial_rad=start, time_constant_s=0.0)
    telemetry = tmp_path / "run.csv"
    with VirtualBus(plant, ids=ids, models="XL330-M288", lockstep_dt_s=1 / RATE_HZ) as virtual:
        answered_here(virtual)
        session = Session(_config(virtual.port, kin, ids), telemetry=telemetry, max_delay_s=None)
        outcome = session.stream_path(path, RATE_HZ, kinematics=kin)
        goals = np.array(virtual.goal_log)
    assert outcome.ok, outcome.stopped_by
    assert outcome.servo_states == dict.fromkeys(ids, HOLDING)
    assert [o.joint for o in outcome.servos] == list(kin.joints)
    assert list(outcome.to_json_dict()["bring_up"]) == list(kin.joints)
    # What reached the servos is the plan, in ticks, joint by joint.
    want = JointMap(ids).to_ticks(outcome.trajectory.q)
    np.testing.assert_array_equal(goals[-len(want) :], want)
    with open(telemetry) as f:
        header = next(csv.reader(f))
    for name in kin.joints:
        assert f"goal_rad_{name}" in header and f"position_rad_{name}" in header
    assert not any(c.endswith("_roll") for c in header if axes == "zy")


def test_bring_up_checks_each_servos_model_number_against_its_joints(answered_here):
    kin = GimbalKinematics(axes="zy")
    models = ("XL330-M288", "XM430-W350")  # the tilt servo is not what the file says
    with VirtualBus(FirstOrderPlant(2), ids=(11, 12), models=models, lockstep_dt_s=0.01) as vb:
        answered_here(vb)
        config = _config(vb.port, kin, (11, 12))
        outcome = Session(config, max_delay_s=None).stream_path(_path(kin), RATE_HZ, kinematics=kin)
        assert vb.frames_received == 0
    assert outcome.stage == "bring-up" and outcome.refused
    assert outcome.stopped_by == (
        "servo 12: model number 1020 (XM430-W350), expected 1200 (XL330-M288); refusing to stream"
    )


def test_a_wrist_streams_beside_an_arm_and_a_gripper_it_leaves_alone(answered_here):
    """The OMX-like chain: the session drives the wrist (14, 15); the other servos of
    the chain, the gripper in Current-based Position (mode 5), are never written."""
    kin = GimbalKinematics(axes="yx", joints=("wrist_flex", "wrist_roll"))
    plant = FirstOrderPlant(2, time_constant_s=0.0)
    registers = {16: {"Operating Mode": 5}}
    with VirtualBus(
        plant,
        ids=OMX,
        plant_ids=(14, 15),
        models="XL330-M288",
        registers=registers,
        lockstep_dt_s=1 / RATE_HZ,
    ) as virtual:
        answered_here(virtual)
        session = Session(_config(virtual.port, kin, (14, 15)), max_delay_s=None)
        outcome = session.stream_path(_path(kin), RATE_HZ, kinematics=kin)
        others = {i: virtual.servos[i] for i in OMX if i not in (14, 15)}
        assert not any(s.torque_on for s in others.values())
        assert others[16].get("Operating Mode") == 5
        assert all(s.get("Return Delay Time") == 250 for s in others.values())
        flex, roll = plant.read()[0]
    assert outcome.ok, outcome.stopped_by
    assert outcome.servo_states == {14: HOLDING, 15: HOLDING}
    np.testing.assert_allclose([flex, roll], outcome.trajectory.q[-1], atol=2 * math.pi / 4096)


def test_a_session_that_cannot_open_leaves_every_servo_of_its_joints_untouched(tmp_path):
    kin = GimbalKinematics(axes="zy")
    config = _config(str(tmp_path / "no-such-port"), kin, (11, 12))
    outcome = Session(config).stream_path(_path(kin), RATE_HZ, kinematics=kin)
    assert outcome.stage == "open"
    assert outcome.servo_states == {11: UNTOUCHED, 12: UNTOUCHED}


def test_the_mcap_run_log_names_the_files_joints(tmp_path, answered_here):
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from trajgen.telemetry_mcap import GOAL, PLAN, PRESENT

    kin = GimbalKinematics(axes="yx", joints=("wrist_flex", "wrist_roll"))
    log = tmp_path / "run.mcap"
    with VirtualBus(
        FirstOrderPlant(2), ids=(14, 15), models="XL330-M288", lockstep_dt_s=0.01
    ) as vb:
        answered_here(vb)
        session = Session(_config(vb.port, kin, (14, 15)), telemetry=log, max_delay_s=None)
        assert session.stream_path(_path(kin), RATE_HZ, kinematics=kin).ok
    with open(log, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        names = {
            tuple(ros.name)
            for _, channel, _, ros in reader.iter_decoded_messages()
            if channel.topic in (GOAL, PRESENT, PLAN)
        }
    assert names == {("wrist_flex", "wrist_roll")}


# -- the command line ----------------------------------------------------------------


def _cli(argv) -> int:
    from trajgen.cli import main

    return main([str(a) for a in argv])


def test_stream_virtual_streams_the_pan_tilt_head_on_ids_11_and_12(tmp_path, capsys):
    import json

    report = tmp_path / "head.json"
    argv = ["stream", "examples/pan_tilt_head.toml", "--virtual", "--configure"]
    assert _cli([*argv, "--json", report, "--telemetry", tmp_path / "head.csv"]) == 0
    out = capsys.readouterr().out
    assert "pan (servo 11): torque on, holding its goal" in out
    assert "tilt (servo 12): torque on, holding its goal" in out
    assert "torque check: OK" in out
    result = json.loads(report.read_text())
    assert result["servos"] == {"11": "holding", "12": "holding"}
    assert list(result["bring_up"]) == ["pan", "tilt"]
    assert result["bring_up"]["pan"]["operating_mode"] == 4  # the pan turns past 180 deg
    with open(tmp_path / "head.csv") as f:
        header = next(csv.reader(f))
    assert "goal_rad_tilt" in header and not any("roll" in c for c in header)


def test_stream_virtual_streams_the_flex_roll_wrist(capsys):
    assert _cli(["stream", "examples/flex_roll_wrist.toml", "--virtual"]) == 0
    out = capsys.readouterr().out
    assert "wrist_flex (servo 14): torque on" in out and "wrist_roll (servo 15)" in out
    assert "torque check: OK" in out


def test_set_limits_names_the_files_own_joints(capsys):
    argv = ["stream", "examples/flex_roll_wrist.toml", "--virtual"]
    assert _cli([*argv, "--set-limits", "wrist_roll=-170:170"]) == 0
    out, err = capsys.readouterr()
    assert "torque check: OK" in out
    assert "servo 15 (wrist_roll): Min Position Limit 0 -> 114 (EEPROM): --set-limits" in err
    assert _cli([*argv, "--set-limits", "roll=-170:170"]) == 2
    err = capsys.readouterr().err
    assert err == (
        "trajgen stream: error: limits for 'roll': not a joint of this gimbal "
        "(one of wrist_flex, wrist_roll)\n"
    )


def test_stream_refuses_ids_that_are_not_one_per_joint(capsys):
    assert _cli(["stream", "examples/pan_tilt_head.toml", "--virtual", "--ids", "1,2,3"]) == 2
    err = capsys.readouterr().err
    assert err == "trajgen stream: error: --ids 1,2,3: expected 2 ids, one per joint (pan, tilt)\n"


@pytest.mark.parametrize(
    ("gimbal", "joints", "servos"),
    [
        ({}, ("pan", "tilt", "roll"), ("XM430-W350",) * 3),
        ({"servo": " xl330-m288 "}, ("pan", "tilt"), ("XL330-M288",) * 2),
        (
            {"servo": {"tilt": "XC330-M288"}},
            ("pan", "tilt", "roll"),
            ("XM430-W350", "XC330-M288", "XM430-W350"),
        ),
        (
            {"servo": "XM430-W350", "tilt": {"servo": "XL330-M077"}},
            ("pan", "tilt", "roll"),
            ("XM430-W350", "XL330-M077", "XM430-W350"),
        ),
        (
            {"servo": {"flex": "XL330-M288"}, "roll": {"servo": "XL330-M077"}},
            ("flex", "roll"),
            ("XL330-M288", "XL330-M077"),
        ),
    ],
)
def test_the_servo_of_each_joint_is_chosen_in_one_place(gimbal, joints, servos):
    """[gimbal.<joint>] servo, else [gimbal] servo (a name or a table by joint), else the
    default: trajgen.gimbal_servos, which the bus's default models and the simulated
    gimbal both are."""
    from trajgen.gimbal_servos import joint_servos

    assert joint_servos(gimbal, joints, "f.toml") == servos
    tables = {"gimbal": {**gimbal, "joints": list(joints), "axes": "zyx"[: len(joints)]}}
    assert bus_config_from_tables(tables, "f.toml").models == servos


@pytest.mark.parametrize(
    ("gimbal", "message"),
    [
        ({"servo": "XM999"}, "f.toml: [gimbal] servo: unknown model 'XM999' (known: XM430-W350"),
        ({"servo": 3}, "f.toml: [gimbal] servo: expected a model name or a table per joint, got 3"),
        ({"servo": {"yaw": "XM430-W350"}}, "f.toml: [gimbal] servo: unknown joint 'yaw'"),
        ({"servo": {"tilt": "XM9"}}, "f.toml: [gimbal] servo.tilt: unknown model 'XM9'"),
        ({"tilt": {"servo": 5}}, "f.toml: [gimbal.tilt] servo: expected a model name, got 5"),
    ],
)
def test_a_bad_servo_choice_is_refused_naming_the_key(gimbal, message):
    from trajgen.errors import KeyframeFileError
    from trajgen.gimbal_servos import joint_servos

    with pytest.raises(KeyframeFileError, match="^" + re.escape(message)):
        joint_servos(gimbal, ("pan", "tilt", "roll"), "f.toml")
