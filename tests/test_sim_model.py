"""The MJCF gimbal: trajgen's joint convention, no contacts, masses, configuration."""

import math

import mujoco
import numpy as np
import pytest

from trajgen import quat
from trajgen.sim.model import GimbalConfig, build_model, gimbal_mjcf
from trajgen.sim.servos import XL430_W250, XM540_W270


def _pose(model, angles):
    data = mujoco.MjData(model)
    data.qpos[:] = angles
    mujoco.mj_forward(model, data)
    return data


def _same_rotation(p, q):
    return min(np.abs(p - q).max(), np.abs(p + q).max())


def test_zero_pose_is_identity_and_camera_looks_along_x():
    model = build_model()
    data = _pose(model, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(data.xquat[model.body("roll_link").id], [1, 0, 0, 0], atol=1e-12)
    camera = data.site_xmat[model.site("camera").id].reshape(3, 3)
    np.testing.assert_allclose(camera[:, 0], [1, 0, 0], atol=1e-12)


def test_payload_orientation_is_rz_ry_rx(rng):
    model = build_model()
    roll_link = model.body("roll_link").id
    for angles in rng.uniform(-3.0, 3.0, size=(50, 3)):
        data = _pose(model, angles)
        expected = quat.from_pan_tilt_roll(*angles)
        assert _same_rotation(data.xquat[roll_link], expected) < 1e-12


def test_joint_axes_pan_z_tilt_panned_y_roll_tilted_x(rng):
    model = build_model()
    pan, tilt, roll = rng.uniform(-2.0, 2.0, size=3)
    data = _pose(model, [pan, tilt, roll])
    rz = quat.from_axis_angle([0, 0, 1], pan)
    rzy = quat.mul(rz, quat.from_axis_angle([0, 1, 0], tilt))
    np.testing.assert_allclose(data.xaxis[0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(data.xaxis[1], quat.rotate(rz, [0, 1, 0]), atol=1e-12)
    np.testing.assert_allclose(data.xaxis[2], quat.rotate(rzy, [1, 0, 0]), atol=1e-12)
    # The three axes meet at one point, so the payload only rotates.
    np.testing.assert_allclose(data.xanchor[1], data.xanchor[2], atol=1e-12)
    np.testing.assert_allclose(data.xanchor[0][:2], data.xanchor[1][:2], atol=1e-12)


def test_every_geom_is_contact_free():
    model = build_model()
    assert np.all(model.geom_contype == 0)
    assert np.all(model.geom_conaffinity == 0)


def test_random_poses_and_random_controls_give_no_contact_and_no_warning(rng):
    # As Menagerie tests its models: pseudo-random controls, fail on any warning.
    model = build_model()
    data = mujoco.MjData(model)
    for _ in range(20):
        data.qpos[:] = rng.uniform(-3.0, 3.0, size=3)
        data.ctrl[:] = rng.uniform(-3.0, 3.0, size=model.nu)
        mujoco.mj_step(model, data, nstep=50)
        assert data.ncon == 0
    assert all(w.number == 0 for w in data.warning)


def test_payload_mass_is_added_to_the_roll_link():
    light = build_model(GimbalConfig(payload_kg=0.1))
    heavy = build_model(GimbalConfig(payload_kg=0.4))
    body = light.body("roll_link").id
    assert heavy.body_mass[body] - light.body_mass[body] == pytest.approx(0.3)
    empty = build_model(GimbalConfig(payload_kg=0.0))
    assert empty.body_mass[body] > 0


def test_payload_offset_moves_the_centre_of_mass():
    model = build_model(GimbalConfig(payload_offset_m=(0.05, 0.0, 0.02)))
    data = _pose(model, [0.0, 0.0, 0.0])
    body = model.body("roll_link").id
    com = data.xipos[body] - data.xpos[body]
    assert com[0] > 0.03 and com[2] > 0.01


def test_servo_per_joint_sets_armature_and_motor():
    config = GimbalConfig(servos=("XM540-W270", "XM430-W350", XL430_W250))
    model = build_model(config)
    assert model.dof_armature[0] == pytest.approx(XM540_W270.armature)
    assert model.dof_armature[2] == pytest.approx(XL430_W250.armature)
    assert config.servos[1].name == "XM430-W350"


def test_timestep_comes_from_the_config():
    assert build_model(GimbalConfig(timestep_s=0.0005)).opt.timestep == 0.0005
    assert 'timestep="0.001"' in gimbal_mjcf()


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"servos": ("XM430-W350",) * 2}, ValueError, r"`servos` to hold 3 servos"),
        ({"servos": "XM999"}, ValueError, r"unknown model 'XM999' \(known: XM430-W350"),
        ({"servos": (1, 2, 3)}, TypeError, r"Expected a servo model name, got 1"),
        ({"payload_kg": -0.1}, ValueError, r"`payload_kg` .* in 0..100, got -0.1"),
        ({"payload_kg": "heavy"}, TypeError, r"`payload_kg` .* in 0..100, got 'heavy'"),
        (
            {"payload_offset_m": (0.0, 0.0)},
            ValueError,
            r"`payload_offset_m` to be a list of 3 numbers",
        ),
        ({"torque_margin": 0.0}, ValueError, r"`torque_margin` .* in \(0, 1\], got 0.0"),
        ({"torque_margin": 1.5}, ValueError, r"`torque_margin` .* in \(0, 1\], got 1.5"),
        ({"timestep_s": 0.002}, ValueError, r"`timestep_s` .* in \(0, 0.001\], got 0.002"),
        (
            {"max_tracking_error_rad": math.nan},
            ValueError,
            r"`max_tracking_error_rad` to be a finite number > 0, got nan",
        ),
    ],
)
def test_config_rejects_bad_values(kwargs, error, match):
    with pytest.raises(error, match=match):
        GimbalConfig(**kwargs)
