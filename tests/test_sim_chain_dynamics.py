"""The numpy inverse dynamics of the gimbal chain against MuJoCo's, and the envelope
check built on it."""

import numpy as np
import pytest

pytest.importorskip("mujoco")

from trajgen.sim.check import envelope_check  # noqa: E402
from trajgen.sim.dynamics import ChainDynamics, inverse_dynamics  # noqa: E402
from trajgen.sim.errors import SimulationError  # noqa: E402
from trajgen.sim.model import GimbalConfig  # noqa: E402
from trajgen.sim.run import simulation_model  # noqa: E402

CONFIGS = [
    {},
    {"payload_kg": 0.4, "payload_offset_m": (0.02, 0.01, -0.03)},
    {"axes": "zy", "servos": ("XM430-W350", "XL330-M288")},
    {"axes": "zxy"},
    {"axes": "zyz"},
]


def states(rng, n, nv, speed=6.0, acc=80.0):
    q = rng.uniform(-np.pi, np.pi, (n, nv))
    qd = rng.uniform(-speed, speed, (n, nv))
    qdd = rng.uniform(-acc, acc, (n, nv))
    qd[: n // 4] *= 1e-4  # near rest, where MuJoCo's friction is in its soft zone
    return q, qd, qdd


@pytest.mark.parametrize("kwargs", CONFIGS)
def test_smooth_torque_is_mujocos_without_coulomb(kwargs):
    model = simulation_model(GimbalConfig(**kwargs))
    chain = ChainDynamics(model)
    q, qd, qdd = states(np.random.default_rng(3), 300, model.nv)
    ours = chain.smooth(q, qd, qdd)
    theirs = inverse_dynamics(model, q, qd, qdd, coulomb=False)
    assert np.abs(theirs).max() > 0.1  # not a trivially small motion
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12)


TREE = """
<mujoco>
  <option gravity="0.3 -0.2 -9.81"/>
  <worldbody>
    <body name="a" pos="0.1 0 0.2" quat="0.9 0.1 0.3 0.2">
      <joint type="hinge" axis="0.3 0.4 0.87" pos="0.02 -0.01 0.03" damping="0.02"
             armature="0.01" frictionloss="0.05" stiffness="0.4" springref="0.2"/>
      <geom type="box" size="0.05 0.02 0.01" pos="0.03 0.01 0" mass="0.3"/>
      <body name="welded" pos="0.05 0.04 -0.02" quat="0.7 0 0.7 0">
        <geom type="capsule" size="0.01 0.03" mass="0.1"/>
        <body name="b" pos="0 0.06 0" quat="0.5 0.5 -0.5 0.5">
          <joint type="hinge" axis="1 0 0" pos="0.01 0 0" ref="0.3"/>
          <geom type="box" size="0.02 0.04 0.01" pos="0.02 0.02 0.01" mass="0.2"/>
        </body>
      </body>
      <body name="c" pos="-0.04 0 0.05">
        <joint type="hinge" axis="0 1 0"/>
        <geom type="sphere" size="0.02" pos="0 0 0.03" mass="0.15"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_smooth_torque_on_a_tree_with_offsets_welds_and_springs():
    import mujoco

    model = mujoco.MjModel.from_xml_string(TREE)
    q, qd, qdd = states(np.random.default_rng(7), 300, model.nv)
    ours = ChainDynamics(model).smooth(q, qd, qdd)
    theirs = inverse_dynamics(model, q, qd, qdd, coulomb=False)
    assert np.abs(theirs).max() > 0.1
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kwargs", CONFIGS[:3])
def test_coulomb_friction_is_bounded_by_frictionloss(kwargs):
    model = simulation_model(GimbalConfig(**kwargs))
    chain = ChainDynamics(model)
    q, qd, qdd = states(np.random.default_rng(4), 300, model.nv)
    friction = inverse_dynamics(model, q, qd, qdd) - inverse_dynamics(
        model, q, qd, qdd, coulomb=False
    )
    assert (np.abs(friction) <= chain.friction * (1 + 1e-12)).all()
    # and it reaches the bound when moving, so the bound is not loose there
    moving = np.abs(qd) > 1.0
    np.testing.assert_allclose(
        np.abs(friction[moving]), np.broadcast_to(chain.friction, qd.shape)[moving], rtol=1e-9
    )


def test_envelope_check_is_mujocos_verdict_on_every_sample():
    config = GimbalConfig()
    model = simulation_model(config)
    within = envelope_check(config, model=model)
    rng = np.random.default_rng(5)
    q, qd, qdd = states(rng, 400, 3, speed=5.0, acc=40.0)  # many beyond the envelope
    tau = inverse_dynamics(model, q, qd, qdd)
    usable = np.stack(
        [config.torque_margin * s.tau_max(qd[:, j]) for j, s in enumerate(config.servos)], axis=1
    )
    direct = (np.abs(tau) <= usable).all(axis=1)
    assert 0.2 < direct.mean() < 0.9  # both verdicts occur
    np.testing.assert_array_equal(within(q, qd, qdd), direct)
    # on the edge: torques within the friction bound of the envelope, decided by MuJoCo
    edge = np.abs(usable - np.abs(tau)) < chain_friction(model)
    assert edge.any(axis=1).sum() >= 5


def test_envelope_check_in_steps_is_the_same_verdict():
    config = GimbalConfig()
    within = envelope_check(config)
    q, qd, qdd = states(np.random.default_rng(6), 200, 3, speed=5.0, acc=40.0)
    steps, yields = within.steps(q, qd, qdd), 0
    while True:
        try:
            next(steps)
            yields += 1
        except StopIteration as end:
            verdict = end.value
            break
    np.testing.assert_array_equal(verdict, within(q, qd, qdd))
    assert 0 < verdict.sum() < len(verdict)
    # three bodies out along the chain and back, then MuJoCo on the undecided frames
    # EXACT_CHUNK at a time (some of these are beyond the bounds' reach)
    assert yields > 6


def test_envelope_check_of_a_model_chain_dynamics_does_not_take_is_mujocos():
    import mujoco

    from trajgen.sim.model import gimbal_mjcf

    config = GimbalConfig()
    spec = mujoco.MjSpec.from_string(gimbal_mjcf(config))
    for joint in spec.joints:
        joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        joint.range = [-3.0, 3.0]
    model = spec.compile()
    with pytest.raises(SimulationError, match="joint limits"):
        ChainDynamics(model)
    within = envelope_check(config, model=model)
    q, qd, qdd = states(np.random.default_rng(8), 200, 3, speed=5.0, acc=40.0)
    q = np.clip(q, -2.5, 2.5)
    tau = inverse_dynamics(model, q, qd, qdd)
    usable = np.stack(
        [config.torque_margin * s.tau_max(qd[:, j]) for j, s in enumerate(config.servos)], axis=1
    )
    direct = (np.abs(tau) <= usable).all(axis=1)
    assert 0 < direct.sum() < len(direct)
    np.testing.assert_array_equal(within(q, qd, qdd), direct)


def test_chain_dynamics_checks_its_arguments_as_mj_inverse_does():
    chain = ChainDynamics(simulation_model(GimbalConfig()))
    ok = np.zeros((4, 3))
    with pytest.raises(ValueError, match=r"`qd` to have shape \(N, 3\)"):
        chain.smooth(ok, np.zeros((4, 2)), ok)
    with pytest.raises(ValueError, match="`qdd` to be finite"):
        chain.smooth(ok, ok, np.full((4, 3), np.nan))
    with pytest.raises(ValueError, match="of one shape"):
        chain.smooth(ok, ok, np.zeros((5, 3)))


def chain_friction(model):
    return ChainDynamics(model).friction


def test_chain_dynamics_refuses_what_it_does_not_model():
    import mujoco

    slide = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint type="slide"/><geom size="0.1"/></body>'
        "</worldbody></mujoco>"
    )
    with pytest.raises(SimulationError, match="hinge"):
        ChainDynamics(slide)
    limited = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint type="hinge" range="-1 1" limited="true"/>'
        '<geom size="0.1"/></body></worldbody></mujoco>'
    )
    with pytest.raises(SimulationError, match="joint limits"):
        ChainDynamics(limited)
