"""The simulated gimbal on 2 or 3 joints in any axis order, a servo per joint."""

import math

import mujoco
import numpy as np
import pytest

from trajgen.axes import AxisSequence
from trajgen.errors import KeyframeFileError
from trajgen.sim.check import check_torque
from trajgen.sim.limits import check_limits, limits_from_tables
from trajgen.sim.model import GimbalConfig, build_model, gimbal_config_from_tables, gimbal_mjcf
from trajgen.sim.plant import GimbalPlant
from trajgen.sim.servos import servo_by_name
from trajgen.stream import plan_joint_trajectory

SEQUENCES = [
    "xyz", "xzy", "yxz", "yzx", "zxy", "zyx",
    "xyx", "xzx", "yxy", "yzy", "zxz", "zyz",
    "xy", "xz", "yx", "yz", "zx", "zy",
]  # fmt: skip

HEAD = """\
[gimbal]
axes = "zy"
joints = ["yaw", "pitch"]
servo = "XL330-M288"

[[keyframes]]
t = 0.0
yaw = 0.0

[[keyframes]]
t = 1.5
yaw = 50.0
pitch = 20.0

[[keyframes]]
t = 3.0
look = [1.0, -2.0, 0.5]
"""


def _pose(model, angles):
    data = mujoco.MjData(model)
    data.qpos[:] = angles
    mujoco.mj_forward(model, data)
    return data


def _same_rotation(p, q):
    return min(np.abs(p - q).max(), np.abs(p + q).max())


@pytest.mark.parametrize("axes", SEQUENCES)
def test_the_last_link_turns_as_the_kinematics_say(axes, rng):
    config = GimbalConfig(axes=axes)
    model = build_model(config)
    seq = config.axes
    assert (model.nq, model.nv, model.nu) == (seq.n, seq.n, seq.n)
    assert [model.joint(j).name for j in range(seq.n)] == list(seq.joints)
    assert [model.actuator(j).name for j in range(seq.n)] == list(seq.joints)
    assert list(model.actuator_group) == list(range(seq.n))
    last = model.body(f"{seq.joints[-1]}_link").id
    kinematics = config.kinematics()
    for angles in rng.uniform(-1.2, 1.2, size=(20, seq.n)):
        data = _pose(model, angles)
        assert _same_rotation(data.xquat[last], kinematics.forward(angles)) < 1e-12
        assert data.ncon == 0
    # The camera's look axis is the sequence's: body x for three axes.
    camera = _pose(model, np.zeros(seq.n)).site_xmat[model.site("camera").id].reshape(3, 3)
    lens = model.geom("lens").pos
    np.testing.assert_allclose(lens / np.linalg.norm(lens) @ camera, seq.look, atol=0.5)
    assert int(np.argmax(np.abs(model.geom("camera").pos))) == int(np.argmax(seq.look))


@pytest.mark.parametrize("axes", ["zy", "yx", "xyz", "zxz"])
def test_each_hinge_turns_about_its_letter_as_the_joints_before_carry_it(axes, rng):
    model = build_model(GimbalConfig(axes=axes))
    seq = AxisSequence(axes)
    angles = rng.uniform(-1.0, 1.0, seq.n)
    data = _pose(model, angles)
    from trajgen.axes import AXIS_LETTERS

    frame = np.eye(3)
    for j, letter in enumerate(axes):
        axis = frame[:, AXIS_LETTERS.index(letter)]
        np.testing.assert_allclose(data.xaxis[j], axis, atol=1e-12)
        frame = frame @ _rotation(letter, angles[j])


def _rotation(letter, angle):
    c, s = math.cos(angle), math.sin(angle)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[letter]


def test_a_servo_per_joint_sets_its_motor_armature_and_housing():
    config = GimbalConfig(axes="zy", servos=("XM430-W350", "XL330-M288"))
    model = build_model(config)
    spec = mujoco.MjSpec.from_string(gimbal_mjcf(config))
    for j, name in enumerate(("XM430-W350", "XL330-M288")):
        servo = servo_by_name(name)
        assert model.dof_armature[j] == servo.armature
        assert model.actuator_gainprm[j, 7] == servo.voltage_v
        assert spec.geom(f"{config.names[j]}_servo").mass == servo.mass_kg
        # The housing's depth lies along the joint's own axis.
        size = model.geom(f"{config.names[j]}_servo").size
        assert size[config.axes.indices[j]] == pytest.approx(servo.size_m[2] / 2)


def test_brackets_scale_with_the_servo_they_hold():
    big = mujoco.MjSpec.from_string(gimbal_mjcf(GimbalConfig(axes="zy", servos="XM430-W350")))
    small = mujoco.MjSpec.from_string(gimbal_mjcf(GimbalConfig(axes="zy", servos="XL330-M288")))
    ratio = servo_by_name("XL330-M288").size_m[0] / servo_by_name("XM430-W350").size_m[0]
    assert ratio < 1
    for name, across in (("pan_bracket_left", [0, 2]), ("pan_bracket_bottom", [0, 1])):
        # Plates keep their 2 mm thickness and scale across.
        np.testing.assert_allclose(
            small.geom(name).size[across], big.geom(name).size[across] * ratio
        )
        assert small.geom(name).mass == pytest.approx(big.geom(name).mass * ratio**2)
    assert small.body("tilt_link").pos[2] == pytest.approx(big.body("tilt_link").pos[2] * ratio)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"axes": "zy", "servos": ("XL330-M288",) * 3}, r"2 servos \(pan, tilt\)"),
        ({"axes": "yx", "joints": ({},) * 3}, r"2 entries \(joint1, joint2\)"),
        ({"axes": AxisSequence("zyx", ("a", "b", "c")), "servos": ("XL330-M288",)}, "3 servos"),
    ],
)
def test_config_wants_one_entry_per_joint(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GimbalConfig(**kwargs)


def test_the_default_camera_sits_along_the_look_axis():
    assert GimbalConfig().payload_offset_m == (0.03, 0.0, 0.0)
    assert GimbalConfig(axes="yx").payload_offset_m == (0.0, 0.0, 0.03)
    assert GimbalConfig(axes="zx").payload_offset_m == (0.0, 0.03, 0.0)


def test_gimbal_table_by_joint_name_with_a_servo_per_joint():
    table = {
        "axes": "yx",
        "joints": ["wrist_flex", "wrist_roll"],
        "servo": "XM430-W350",
        "wrist_roll": {"servo": "XL330-M288", "damping": 0.02},
    }
    config = gimbal_config_from_tables({"gimbal": table}, "w.toml", any_axes=True)
    assert config.names == ("wrist_flex", "wrist_roll")
    assert [s.name for s in config.servos] == ["XM430-W350", "XL330-M288"]
    assert config.joints[1].damping == 0.02
    assert config.joints[1].armature == servo_by_name("XL330-M288").armature
    by_table = gimbal_config_from_tables(
        {"gimbal": {**table, "servo": {"wrist_roll": "XL330-M288"}, "wrist_roll": {}}},
        "w.toml",
        any_axes=True,
    )
    assert by_table.servos == config.servos


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"axes": "zy", "roll": {}}, "[gimbal]: unknown key 'roll' (known: "),
        ({"axes": "zy", "servo": {"roll": "XL330-M288"}}, "[gimbal] servo: unknown joint 'roll'"),
        ({"axes": "zy", "tilt": {"servo": "XM999"}}, "[gimbal.tilt] servo: unknown model 'XM999'"),
        ({"axes": "zy", "tilt": {"servo": 3}}, "[gimbal.tilt] servo: expected a model name, got 3"),
    ],
)
def test_gimbal_table_errors_name_the_joint(table, message):
    with pytest.raises(KeyframeFileError) as e:
        gimbal_config_from_tables({"gimbal": table}, "h.toml", any_axes=True)
    assert str(e.value).startswith("h.toml: " + message)


def test_a_caller_for_pan_tilt_roll_only_refuses_other_axes():
    with pytest.raises(
        KeyframeFileError,
        match=r"^h\.toml: \[gimbal\] axes = 'zy': 2-axis gimbals: this caller takes pan-tilt-roll "
        r"\(axes = 'zyx'\) only \(any_axes=False\); pass any_axes=True for a caller that takes "
        r"any axes, as every trajgen command does$",
    ):
        gimbal_config_from_tables({"gimbal": {"axes": "zy"}}, "h.toml")


def test_a_two_axis_head_plans_simulates_and_reports_by_joint_name(tmp_path):
    f = tmp_path / "head.toml"
    f.write_text(HEAD)
    report = check_torque(f)
    assert report.ok, report.reasons
    assert list(report.joints) == ["yaw", "pitch"]
    assert report.record.q.shape[1] == 2
    assert {j.servo for j in report.joints.values()} == {"XL330-M288"}
    assert "5 V envelope" in report.format()
    # The plan's look direction is the kinematics': the trajectory is 2-axis.
    assert report.trajectory.q.shape[1] == 2
    # A heavier payload beyond what an XL330 holds fails, naming the joint.
    heavy = check_torque(
        f,
        config=GimbalConfig(
            axes=AxisSequence("zy", ("yaw", "pitch")), servos="XL330-M288", payload_kg=3.0
        ),
    )
    assert not heavy.ok
    assert any(r.startswith("pitch:") for r in heavy.reasons)


def test_the_plant_runs_two_joints_and_refuses_three_goals():
    config = GimbalConfig(axes="zy", servos="XL330-M288")
    plant = GimbalPlant(config)
    assert plant.n_joints == 2
    with pytest.raises(ValueError, match="2 finite numbers"):
        plant.set_goal([0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="joint"):
        plant.set_torque_enabled(2, True)
    plant.set_torque_enabled(0, True)
    plant.set_torque_enabled(1, True)
    plant.set_goal([0.3, -0.2])
    plant.advance(1.0)
    position, velocity, current = plant.read()
    assert position.shape == velocity.shape == current.shape == (2,)
    # Within the static offset gravity and friction leave with default gains.
    np.testing.assert_allclose(position, [0.3, -0.2], atol=0.05)
    assert plant.present_pwm().shape == (2,)


def test_the_plant_report_matches_simulate_on_two_joints(tmp_path):
    f = tmp_path / "head.toml"
    f.write_text(HEAD)
    from trajgen.keyframes import load_keyframe_file
    from trajgen.sim.lead import sagged_start
    from trajgen.sim.run import simulate, simulation_model

    kf = load_keyframe_file(f)
    config = gimbal_config_from_tables(kf.tables, f, any_axes=True)
    trajectory = plan_joint_trajectory(kf.spline(), 100.0, config.kinematics())
    # where `simulate` starts: sagged under the first goal (the XL330 tilt by 37 mrad)
    start = sagged_start(trajectory, config, simulation_model(config))
    plant = GimbalPlant(config, initial_rad=start)
    for j in range(2):
        plant.set_torque_enabled(j, True)
    for goal in trajectory.q:
        plant.set_goal(np.round(goal * 4096 / (2 * math.pi)) * (2 * math.pi) / 4096)
        plant.advance(0.01)
    report = plant.report(trajectory)
    record = simulate(trajectory, config)
    np.testing.assert_allclose(report.record.q, record.q, atol=1e-9)


def test_limits_by_joint_name():
    tables = {
        "gimbal": {"axes": "zy", "joints": ["yaw", "pitch"]},
        "limits": {"speed_rad_s": {"pitch": 0.1}},
    }
    limits = limits_from_tables(tables, "h.toml")
    assert limits.joints == ("yaw", "pitch")
    assert limits.speed_rad_s == (math.inf, 0.1)
    with pytest.raises(KeyframeFileError, match=r"speed_rad_s: unknown joint 'roll'"):
        limits_from_tables({**tables, "limits": {"speed_rad_s": {"roll": 1.0}}}, "h.toml")


def test_limits_check_names_the_joint(tmp_path):
    f = tmp_path / "head.toml"
    f.write_text(HEAD + "\n[limits]\nspeed_rad_s = {pitch = 0.05}\n")
    from trajgen.keyframes import load_keyframe_file

    kf = load_keyframe_file(f)
    config = gimbal_config_from_tables(kf.tables, f, any_axes=True)
    trajectory = plan_joint_trajectory(kf.spline(), 100.0, config.kinematics())
    reasons = check_limits(trajectory, limits_from_tables(kf.tables, f))
    assert len(reasons) == 1 and reasons[0].startswith("pitch: speed ")


def test_trajgen_sim_takes_a_two_axis_file(tmp_path, capsys):
    from trajgen.cli import main

    f = tmp_path / "head.toml"
    f.write_text(HEAD)
    assert main(["sim", str(f), "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "torque check: OK" in out
    assert "\nyaw   XL330-M288" in out and "\npitch XL330-M288" in out


def test_the_timing_fit_retimes_a_two_axis_head(tmp_path):
    from trajgen.sim.fit import fit_timing

    f = tmp_path / "head.toml"
    f.write_text(HEAD)
    result = fit_timing(f)
    fitted = check_torque(result.path, config=gimbal_config_from_tables(
        {"gimbal": {"axes": "zy", "joints": ["yaw", "pitch"], "servo": "XL330-M288"}},
        f,
        any_axes=True,
    ))  # fmt: skip
    assert fitted.ok, fitted.reasons
    assert list(fitted.joints) == ["yaw", "pitch"]
    assert result.times[-1] - result.times[0] < 3.0  # faster than the file's 3 s


def test_identify_recovers_a_simulated_two_axis_gimbal(tmp_path):
    pytest.importorskip("mujoco.sysid", exc_type=ImportError)
    from trajgen.sim.identify import identify, load_telemetry

    names = ("yaw", "pitch")
    axes = AxisSequence("zy", names)
    true = (
        {"armature": 0.05, "frictionloss": 0.04, "damping": 0.05, "position_p_gain": 1000},
        {"armature": 0.035, "frictionloss": 0.02, "damping": 0.1, "position_p_gain": 640},
    )
    plant = GimbalPlant(GimbalConfig(axes=axes, joints=true), initial_rad=[0.0, 0.0])
    for j in range(2):
        plant.set_torque_enabled(j, True)
    rate, seconds = 200.0, 4.0
    t = np.arange(int(rate * seconds)) / rate
    window = np.sin(np.pi * t / seconds)[:, None] ** 2
    goals = window * np.column_stack(
        [0.4 * np.sin(2 * np.pi * 0.7 * t) + 0.2 * np.sin(2 * np.pi * 2.3 * t),
         0.3 * np.sin(2 * np.pi * 1.1 * t) + 0.15 * np.sin(2 * np.pi * 3.1 * t)]
    )  # fmt: skip
    goals = np.round(goals * 4096 / (2 * np.pi)) * (2 * np.pi) / 4096
    rows = []
    for i, goal in enumerate(goals):
        q, qd, current = plant.read()
        rows.append([i, t[i], *goal, *q, *qd, *current])
        plant.set_goal(goal)
        plant.advance(1.0 / rate)
    header = ["frame", "t_s"] + [
        f"{p}_{j}" for p in ("goal_rad", "position_rad", "velocity_rad_s", "current_a")
        for j in names
    ]  # fmt: skip
    log = tmp_path / "log.csv"
    log.write_text(
        ",".join(header) + "\n" + "\n".join(",".join(str(float(v)) for v in r) for r in rows)
    )
    fit = identify(GimbalConfig(axes=axes), [load_telemetry(log, names)], max_iter=20)
    assert list(fit.joints) == list(names)
    for joint, want in zip(fit.joints.values(), true, strict=True):
        assert joint.values["armature"] == pytest.approx(want["armature"], rel=0.1)
        assert joint.values["position_p_gain"] == pytest.approx(want["position_p_gain"], rel=0.1)
    assert fit.config.n_joints == 2 and "[gimbal.pitch]" in fit.toml()


def test_trajgen_sweep_takes_a_two_axis_file_by_joint_name(tmp_path, capsys):
    from trajgen.cli import main

    f = tmp_path / "head.toml"
    f.write_text(HEAD)
    args = ["sweep", str(f), "--servo", "pitch=XL330-M288,XM430-W350", "--time-scale", "1"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "servos (yaw/pitch)" in out
    assert "XL330-M288/XM430-W350" in out and "2 of 2 variants pass" in out


@pytest.mark.parametrize(
    ("axes", "center"),
    [
        ("zy", (0.3, -0.2)),
        ("yx", (-0.4, 0.5)),
        ("xyz", (0.2, -0.3, 0.4)),
        ("zxz", (0.3, 1.2, -0.2)),  # proper Euler: away from its lock at 0
        ("zyx", (0.4, 0.1, -0.2)),
    ],
)
def test_a_multisine_on_any_axes_plans_back_to_its_own_joints(axes, center):
    """The excitation's orientation path and its angular rates (the general dJ/dt qd term)
    give its joint motion back through the gimbal's inverse kinematics: each joint moves
    by its own sines, none is lost to the look axis of a two-axis gimbal."""
    from trajgen.gimbal import GimbalKinematics
    from trajgen.sim.excite import Multisine, default_amplitude_rad

    kin = GimbalKinematics(axes=axes)
    motion = Multisine(center_rad=center, seconds=4.0, kinematics=kin)
    assert motion.amplitude_rad == default_amplitude_rad(kin.n_joints)
    assert motion.frequencies_hz.shape == (kin.n_joints, 5)
    trajectory = plan_joint_trajectory(motion, 200.0, kin)
    q, qd, qdd = motion.joints(trajectory.t)
    np.testing.assert_allclose(trajectory.q, q, atol=1e-12)
    np.testing.assert_allclose(trajectory.qd, qd, atol=1e-11)
    np.testing.assert_allclose(trajectory.qdd, qdd, atol=1e-9)
    with pytest.raises(ValueError, match=rf"`center_rad` to be {kin.n_joints} finite numbers"):
        Multisine(center_rad=(0.0,) * (5 - kin.n_joints), kinematics=kin)
