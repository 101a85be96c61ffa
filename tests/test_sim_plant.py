"""The plant behind the virtual servo bus: goal positions in, present values out."""

import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen.sim.errors import SimError
from trajgen.sim.plant import GimbalPlant


def _stream(plant, trajectory):
    period = 1.0 / trajectory.rate_hz
    for frame in trajectory:
        plant.set_goal(frame.q)
        plant.advance(period)


def test_starts_limp_at_zero():
    plant = GimbalPlant()
    plant.advance(0.05)
    position, velocity, current = plant.read()
    np.testing.assert_array_equal(current, 0.0)
    # Coulomb friction holds the unbalanced tilt against gravity, but MuJoCo's
    # soft friction constraint lets it creep a little.
    assert np.abs(position).max() < 1e-4
    assert plant.time_s == pytest.approx(0.05)


def test_streamed_goals_are_followed_and_reported():
    trajectory = quintic_trajectory([0.7, 0.3, -0.4], 1.5)
    plant = GimbalPlant()
    for joint in range(3):
        plant.set_torque_enabled(joint, True)
    _stream(plant, trajectory)
    plant.advance(0.2)
    position, velocity, current = plant.read()
    np.testing.assert_allclose(position, trajectory.q[-1], atol=0.01)
    assert np.abs(velocity).max() < 0.05
    report = plant.report(trajectory)
    assert report.ok
    # Goals only: the servo lags 45 ms x speed (0.875 rad/s at the peak).
    assert 0.035 < report.joints["pan"].max_tracking_error_rad < 0.05


def test_current_is_torque_over_the_torque_constant():
    plant = GimbalPlant()
    plant.set_torque_enabled(1, True)
    plant.set_goal([0.0, 0.5, 0.0])
    plant.advance(0.01)
    _, _, current = plant.read()
    torque_constant = plant.config.servos[1].torque_constant_nm_a
    assert current[1] * torque_constant > 0.5  # pushing towards the goal
    assert current[0] == 0.0 and current[2] == 0.0  # torque off


def test_torque_off_lets_a_joint_coast():
    plant = GimbalPlant()
    plant.set_torque_enabled(0, True)
    plant.set_goal([1.0, 0.0, 0.0])
    plant.advance(0.1)
    plant.set_torque_enabled(0, False)
    moving = plant.read()[1][0]
    plant.advance(0.05)
    position, velocity, current = plant.read()
    assert current[0] == 0.0
    assert abs(velocity[0]) < abs(moving)  # friction slows it; no motor holds it


def test_a_fast_stream_fails_the_report():
    trajectory = quintic_trajectory([1.0, 0.0, 0.0], 0.2)
    plant = GimbalPlant()
    for joint in range(3):
        plant.set_torque_enabled(joint, True)
    _stream(plant, trajectory)
    report = plant.report(trajectory)
    assert not report.ok
    assert report.joints["pan"].steps_at_limit > 0


def test_bad_calls_are_refused():
    plant = GimbalPlant()
    with pytest.raises(ValueError, match=r"`positions_rad` to be 3 finite numbers"):
        plant.set_goal([0.0, 0.0])
    with pytest.raises(ValueError, match=r"`joint` to be an integer in 0\.\.2, got 3"):
        plant.set_torque_enabled(3, True)
    with pytest.raises(TypeError, match=r"`joint` to be an integer in 0\.\.2, got 1.0"):
        plant.set_torque_enabled(1.0, True)
    with pytest.raises(ValueError, match=r"`dt_s` >= 0, got -0.1"):
        plant.advance(-0.1)
    with pytest.raises(SimError, match=r"no goal position was received"):
        plant.report(quintic_trajectory([0.1, 0, 0], 0.5))
    with pytest.raises(ValueError, match=r"`timestep_s` .* in \(0, 0.001\], got 0.01"):
        GimbalPlant(timestep_s=0.01)


def test_a_plant_that_does_not_record_says_so():
    plant = GimbalPlant(record=False)
    plant.set_torque_enabled(0, True)
    plant.set_goal([0.1, 0.0, 0.0])
    plant.advance(0.05)
    assert plant.read()[0][0] > 0.01  # it moves all the same
    with pytest.raises(SimError, match=r"record=False: nothing to report"):
        plant.report(quintic_trajectory([0.1, 0, 0], 0.5))
