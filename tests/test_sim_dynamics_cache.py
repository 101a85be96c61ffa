"""``inverse_dynamics`` keeps a model's MjData and its copy without Coulomb friction
between calls: the cached calls give what fresh MuJoCo objects give."""

import copy

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from trajgen.sim import dynamics  # noqa: E402
from trajgen.sim.model import GimbalConfig  # noqa: E402
from trajgen.sim.run import simulation_model  # noqa: E402


def fresh(model, q, qd, qdd, coulomb):
    """mj_inverse on a new MjData (and a new friction-free copy), sample by sample."""
    if not coulomb:
        model = copy.copy(model)
        model.dof_frictionloss[:] = 0.0
    data, tau = mujoco.MjData(model), np.empty_like(q)
    for i in range(len(q)):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[i], qd[i], qdd[i]
        mujoco.mj_inverse(model, data)
        tau[i] = data.qfrc_inverse
    return tau


@pytest.mark.parametrize("coulomb", [True, False])
def test_cached_calls_equal_fresh_ones(coulomb):
    model = simulation_model(GimbalConfig())
    rng = np.random.default_rng(5)
    for _ in range(4):  # the later calls reuse the first one's objects
        q, qd, qdd = (rng.uniform(-s, s, (7, model.nv)) for s in (3.0, 6.0, 80.0))
        cached = dynamics.inverse_dynamics(model, q, qd, qdd, coulomb=coulomb)
        np.testing.assert_array_equal(cached, fresh(model, q, qd, qdd, coulomb))
    assert dynamics._scratch(model) is dynamics._scratch(model)


def test_split_equals_the_two_calls_with_the_cache_warm():
    model = simulation_model(GimbalConfig(axes="zy", servos=("XM430-W350", "XL330-M288")))
    rng = np.random.default_rng(6)
    q, qd, qdd = (rng.uniform(-s, s, (9, model.nv)) for s in (3.0, 6.0, 80.0))
    tau, smooth = dynamics.inverse_dynamics_split(model, q, qd, qdd)
    np.testing.assert_array_equal(tau, fresh(model, q, qd, qdd, True))
    np.testing.assert_array_equal(smooth, fresh(model, q, qd, qdd, False))
