"""The user's own gimbal model (MJCF, URDF) with trajgen's servos attached."""

import dataclasses
import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from trajgen.errors import KeyframeFileError
from trajgen.sim.check import check_torque
from trajgen.sim.model import GimbalConfig, build_model, gimbal_config_from_tables
from trajgen.sim.user_model import user_model

EXAMPLES = Path(__file__).parents[1] / "examples"
SHIPPED = EXAMPLES / "models" / "pan_tilt_roll_gimbal.xml"

KEYFRAMES = """
[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 1.0
pan = 40.0
tilt = 20.0
roll = -10.0

[[keyframes]]
t = 2.0
pan = -20.0
tilt = -15.0
"""

#: A two-link pan-tilt head: pan about z, tilt about y, camera along x.
HEAD_XML = """\
<mujoco model="head">
  <worldbody>
    <body name="pan_link" pos="0 0 0.05">
      <joint name="{pan_name}" type="{pan_type}" axis="0 0 1"/>
      <inertial pos="0 0 0.03" mass="0.1" diaginertia="{pan_inertia}"/>
      <body name="tilt_link" pos="0 0 0.06">
        <joint name="tilt" type="hinge" axis="{tilt_axis}"/>
        <geom name="camera" type="box" size="0.03 0.02 0.02" pos="{camera}" mass="0.15"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _head(tmp_path, name="head.xml", **fields):
    values = {
        "pan_name": "pan",
        "pan_type": "hinge",
        "pan_inertia": "4e-5 4e-5 2e-5",
        "tilt_axis": "0 1 0",
        "camera": "0.03 0 0",
        **fields,
    }
    model = tmp_path / name
    model.write_text(HEAD_XML.format(**values))
    return model


def _file(tmp_path, model, axes="zy", joints=("pan", "tilt"), extra="", name="shot.toml"):
    keyframes = KEYFRAMES if len(axes) == 3 else KEYFRAMES.replace("roll = -10.0\n", "")
    f = tmp_path / name
    f.write_text(
        f'[gimbal]\naxes = "{axes}"\njoints = {list(joints)!r}\nmodel = "{model}"\n'
        f'servo = "XL330-M288"\n{extra}\n' + keyframes
    )
    return f


def _config(f):
    from trajgen.keyframes import load_keyframe_file

    kf = load_keyframe_file(f)
    return gimbal_config_from_tables(kf.tables, kf.path, any_axes=True)


@pytest.mark.parametrize("example", ["raster.toml", "sim_too_fast.toml"])
def test_the_shipped_mjcf_reproduces_the_built_in_torque_report(example):
    built_in = check_torque(EXAMPLES / example)
    config = dataclasses.replace(built_in.config, model=SHIPPED)
    own = check_torque(EXAMPLES / example, config=config)
    np.testing.assert_allclose(own.planned_torque_nm, built_in.planned_torque_nm, atol=1e-6)
    np.testing.assert_allclose(own.record.torque_nm, built_in.record.torque_nm, atol=1e-6)
    assert own.ok == built_in.ok and own.reasons == built_in.reasons
    for name, joint in built_in.joints.items():
        mine = own.joints[name]
        for field in dataclasses.fields(joint):
            value = getattr(joint, field.name)
            if isinstance(value, float):
                assert getattr(mine, field.name) == pytest.approx(value, abs=1e-6), field.name
            else:
                assert getattr(mine, field.name) == value


def test_the_shipped_mjcf_compiles_to_the_built_in_dynamics():
    own = user_model(GimbalConfig(model=SHIPPED))
    ref = build_model(GimbalConfig())
    for name in ("dof_armature", "dof_damping", "dof_frictionloss", "actuator_gainprm",
                 "actuator_biasprm", "actuator_dynprm", "actuator_forcerange", "jnt_axis",
                 "actuator_group", "opt.timestep"):  # fmt: skip
        a, b = ref, own
        for part in name.split("."):
            a, b = getattr(a, part), getattr(b, part)
        np.testing.assert_array_equal(b, a, err_msg=name)
    moving = slice(2, None)  # the base body is fixed to the world
    np.testing.assert_array_equal(own.body_mass[moving], ref.body_mass[moving])
    np.testing.assert_allclose(own.body_inertia[moving], ref.body_inertia[moving], rtol=1e-12)


def test_a_tilted_axis_and_an_offset_camera_load_and_check(tmp_path):
    model = _head(tmp_path, tilt_axis="0 0.9962 0.0872", camera="0.05 0.02 -0.01")
    f = _file(tmp_path, model.name)
    report = check_torque(f)
    assert report.ok, report.reasons
    assert list(report.joints) == ["pan", "tilt"]
    # The offset camera loads the tilt servo against gravity more than a centred one.
    centred = check_torque(_file(tmp_path, _head(tmp_path, "c.xml").name, name="c.toml"))
    assert (
        report.joints["tilt"].peak_planned_torque_nm > centred.joints["tilt"].peak_planned_torque_nm
    )
    built = build_model(_config(f))
    data = mujoco.MjData(built)
    mujoco.mj_forward(built, data)
    axis = np.array([0, 0.9962, 0.0872])
    np.testing.assert_allclose(data.xaxis[1], axis / np.linalg.norm(axis), atol=1e-9)
    assert built.dof_armature[1] == _config(f).servos[1].armature
    assert built.nu == 2 and built.actuator(1).name == "tilt"


def test_the_models_actuators_are_replaced_and_contacts_turned_off(tmp_path):
    text = (
        _head(tmp_path)
        .read_text()
        .replace(
            "</mujoco>",
            '<actuator><motor joint="pan" name="theirs"/></actuator>\n</mujoco>',
        )
    )
    model = tmp_path / "head.xml"
    model.write_text(text)
    built = build_model(_config(_file(tmp_path, model.name)))
    assert [built.actuator(i).name for i in range(built.nu)] == ["pan", "tilt"]
    assert not built.geom_contype.any() and not built.geom_conaffinity.any()
    assert built.camera("overview").id >= 0


PAN_TILT = ("pan", "tilt")
MOMENTS = "body 'pan_link': inertia with principal moments"


@pytest.mark.parametrize(
    ("fields", "joints", "message"),
    [
        ({"pan_name": "yaw"}, PAN_TILT, "no joint 'pan' in the model (its joints: 'yaw', 'tilt')"),
        ({"pan_type": "slide"}, PAN_TILT, "joint 'pan' is a slide joint, not a hinge"),
        ({"pan_type": "ball"}, PAN_TILT, "joint 'pan' is a ball joint, not a hinge"),
        (
            {"pan_inertia": "4e-5 0 2e-5"},
            PAN_TILT,
            f"{MOMENTS} 4e-05, 0, 2e-05 kg m^2; each must be > 0",
        ),
        (
            {"pan_inertia": "4e-5 -1e-5 2e-5"},
            PAN_TILT,
            f"{MOMENTS} 4e-05, -1e-05, 2e-05 kg m^2; each must be > 0",
        ),
        (
            {},
            ("tilt", "pan"),
            "joints ['tilt', 'pan'] must be named base out, as the model has them: ['pan', 'tilt']",
        ),
        (
            {"tilt_axis": "0 0 1"},
            PAN_TILT,
            "joint 'tilt' turns about (0, 0, 1) in the gimbal's base frame, 90.0 deg from +y, its "
            "axis in [gimbal] axes = 'zy' (at most 15 deg, the same way round): fix the model's "
            "axis or the axes",
        ),
        (
            {"tilt_axis": "0 -1 0"},
            PAN_TILT,
            "joint 'tilt' turns about (0, -1, 0) in the gimbal's base frame, 180.0 deg from +y",
        ),
        (
            {"tilt_axis": "0 0.94 0.342"},  # 20 deg off
            PAN_TILT,
            "joint 'tilt' turns about (0, 0.94, 0.342) in the gimbal's base frame, 20.0 deg from",
        ),
    ],
)
def test_a_model_that_cannot_carry_the_servos_is_refused_in_one_line(
    tmp_path, capsys, fields, joints, message
):
    from trajgen.cli import main

    f = _file(tmp_path, _head(tmp_path, **fields).name, joints=joints)
    with pytest.raises(KeyframeFileError) as e:
        _config(f)
    assert str(e.value).startswith(f"{f}: [gimbal] model: head.xml: {message}")
    assert main(["sim", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"trajgen sim: error: {f}: [gimbal] model: head.xml: {message}")
    assert err.count("\n") == 1


def test_zero_mass_is_refused(tmp_path):
    text = _head(tmp_path).read_text().replace('mass="0.1"', 'mass="0"')
    (tmp_path / "zero.xml").write_text(text)
    with pytest.raises(KeyframeFileError, match=re.escape(
        "zero.xml: body 'pan_link': mass 0 kg; a moving link needs mass > 0"
    )):  # fmt: skip
        _config(_file(tmp_path, "zero.xml"))


def test_a_joint_the_gimbal_does_not_name_is_held_at_its_reference_pose(tmp_path, capsys):
    """A gripper finger on the tilt link, on a slide joint drawn 2 cm out (ref 0): welded
    where the file draws it, its mass carried by the tilt servo, and said by trajgen sim."""
    from trajgen.cli import main
    from trajgen.sim.user_model import held_joints

    finger = (
        '<body name="finger" pos="0.05 0 0.02"><joint name="gripper" type="slide" axis="1 0 0"/>'
        '<geom type="box" size="0.01 0.01 0.01" mass="0.08"/></body>'
    )
    camera = '<geom name="camera"'
    text = _head(tmp_path).read_text().replace(camera, finger + camera)
    (tmp_path / "gripper.xml").write_text(text)
    config = _config(_file(tmp_path, "gripper.xml"))
    assert held_joints(config) == ("gripper",)
    built = build_model(config)
    assert built.njnt == 2 and built.nq == 2  # the gimbal's own hinges only
    data = mujoco.MjData(built)
    mujoco.mj_kinematics(built, data)
    # the finger stays where the file draws it, on the tilt link
    np.testing.assert_allclose(data.xpos[built.body("finger").id], [0.05, 0, 0.13], atol=1e-12)
    plain = check_torque(_file(tmp_path, _head(tmp_path).name, name="plain.toml"))
    held = check_torque(_file(tmp_path, "gripper.xml", name="held.toml"))
    assert held.joints["tilt"].peak_planned_torque_nm > plain.joints["tilt"].peak_planned_torque_nm
    assert main(["sim", str(tmp_path / "held.toml"), "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "held: joint 'gripper' (not in [gimbal] joints) is welded at its reference pose" in out
    assert json.loads((tmp_path / "r.json").read_text())["held_joints"] == ["gripper"]


def test_a_gimbal_mounted_turned_in_the_world_checks_its_axes_from_its_base(tmp_path):
    """The base body turned 90 deg about x (a head on a wall): the hinge axes are the
    declared ones seen from the base, so the model loads; gravity acts as mounted."""
    text = _head(tmp_path).read_text()
    text = text.replace(
        '<body name="pan_link" pos="0 0 0.05">',
        '<body name="mount" euler="90 0 0"><body name="pan_link" pos="0 0 0.05">',
    ).replace("</worldbody>", "</body></worldbody>")
    (tmp_path / "wall.xml").write_text(text)
    assert _config(_file(tmp_path, "wall.xml")).names == ("pan", "tilt")


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ('"nope.xml"', "'nope.xml': no such file"),
        ('"head.obj"', "'head.obj': expected an MJCF (.xml) or URDF (.urdf) file"),
        ("3", "expected a file name, got 3"),
    ],
)
def test_a_bad_model_key_is_refused(tmp_path, value, message):
    (tmp_path / "head.obj").write_text("")
    f = tmp_path / "shot.toml"
    f.write_text(f"[gimbal]\nmodel = {value}\n" + KEYFRAMES)
    with pytest.raises(KeyframeFileError, match=re.escape(f"{f}: [gimbal] model: {message}")):
        _config(f)


def test_a_file_mujoco_cannot_read_is_refused_in_one_line(tmp_path):
    (tmp_path / "broken.xml").write_text("<mujoco><worldbody><body></mujoco>")
    with pytest.raises(KeyframeFileError) as e:
        _config(_file(tmp_path, "broken.xml"))
    assert str(e.value).startswith(
        f"{tmp_path / 'shot.toml'}: [gimbal] model: broken.xml: MuJoCo cannot read it: "
    )
    assert "\n" not in str(e.value)


URDF = """\
<?xml version="1.0"?>
<robot name="head">
  <link name="base"/>
  <link name="pan_link">
    <inertial><origin xyz="0 0 0.02"/><mass value="0.08"/>
      <inertia ixx="2e-5" iyy="2e-5" izz="1e-5" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="meshes/pan.stl"/></geometry></visual>
    <collision><geometry><mesh filename="meshes/pan.stl"/></geometry></collision>
  </link>
  <link name="tilt_link">
    <inertial><origin xyz="0.03 0 0"/><mass value="{mass}"/>
      <inertia ixx="1e-5" iyy="3e-5" izz="3e-5" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><box size="0.06 0.04 0.04"/></geometry></visual>
  </link>
  <joint name="pan" type="continuous"><parent link="base"/><child link="pan_link"/>
    <origin xyz="0 0 0.05"/><axis xyz="0 0 1"/></joint>
  <joint name="tilt" type="revolute"><parent link="pan_link"/><child link="tilt_link"/>
    <origin xyz="0 0 0.04"/><axis xyz="0 1 0"/>
    <limit lower="-1.5" upper="1.5" effort="1" velocity="5"/></joint>
</robot>
"""


def test_a_urdf_loads_without_its_meshes_and_checks(tmp_path):
    (tmp_path / "head.urdf").write_text(URDF.format(mass="0.1"))
    f = _file(tmp_path, "head.urdf")
    config = _config(f)
    model = build_model(config)
    assert model.nmesh == 0  # the missing collision mesh is dropped, the visual discarded
    np.testing.assert_allclose(model.body_mass[model.body("tilt_link").id], 0.1)
    report = check_torque(f)
    assert report.ok, report.reasons
    (tmp_path / "heavy.urdf").write_text(URDF.format(mass="-0.1"))
    with pytest.raises(KeyframeFileError, match=re.escape(
        "heavy.urdf: body 'tilt_link': mass -0.1 kg; a moving link needs mass > 0"
    )):  # fmt: skip
        _config(_file(tmp_path, "heavy.urdf"))


def test_a_missing_mesh_that_gives_a_body_its_mass_is_refused(tmp_path):
    text = (
        _head(tmp_path)
        .read_text()
        .replace(
            '<geom name="camera" type="box" size="0.03 0.02 0.02"',
            '<geom name="camera" type="mesh" mesh="cam"',
        )
        .replace("<worldbody>", '<asset><mesh name="cam" file="cam.stl"/></asset>\n  <worldbody>')
    )
    (tmp_path / "mesh.xml").write_text(text)
    with pytest.raises(KeyframeFileError, match=re.escape(
        "mesh.xml: mesh file 'cam.stl' not found, and body 'tilt_link' takes its mass from it"
    )):  # fmt: skip
        _config(_file(tmp_path, "mesh.xml"))


def test_the_plant_runs_on_the_users_model(tmp_path):
    from trajgen.sim.plant import GimbalPlant

    config = _config(_file(tmp_path, _head(tmp_path).name))
    plant = GimbalPlant(config)
    for j in range(2):
        plant.set_torque_enabled(j, True)
    plant.set_goal([0.2, 0.1])
    plant.advance(1.0)
    np.testing.assert_allclose(plant.read()[0], [0.2, 0.1], atol=0.05)
    assert mujoco.MjData(plant._model).qpos.shape == (2,)


def test_a_payload_beside_an_own_model_is_refused(tmp_path, capsys):
    from trajgen.cli import main

    f = _file(tmp_path, _head(tmp_path).name, extra="payload_kg = 0.2")
    with pytest.raises(KeyframeFileError, match=re.escape(
        f"{f}: [gimbal] payload_kg: your own model's payload is in its file "
        "(model = 'head.xml'); leave payload_kg out"
    )):  # fmt: skip
        _config(f)
    f = _file(tmp_path, _head(tmp_path).name)
    assert main(["sweep", str(f), "--offset-m", "0,0,0.1"]) == 2
    assert "--offset-m: the payload of your own model" in capsys.readouterr().err


def test_fit_refuses_to_write_beside_another_folder_than_the_model_it_names(tmp_path, capsys):
    from trajgen.cli import main

    f = _file(tmp_path, _head(tmp_path).name)
    elsewhere = tmp_path / "out"
    elsewhere.mkdir()
    assert main(["fit", str(f), "--out", str(elsewhere / "fit.toml")]) == 2
    assert capsys.readouterr().err == (
        f"trajgen fit: error: --out {elsewhere / 'fit.toml'}: the file's [gimbal] model = "
        "'head.xml' is relative to its folder; write the fitted file there\n"
    )
    assert not (elsewhere / "fit.toml").exists()
