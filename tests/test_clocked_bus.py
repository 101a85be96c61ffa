"""``drivers.virtual.clocked.ClockedBus``: the servos' time is the host's simulated clock."""

import math

import numpy as np
import pytest

from trajgen.drivers.clock import SimulatedClock
from trajgen.drivers.control_table import MODELS, Register
from trajgen.drivers.virtual.clocked import ClockedBus
from trajgen.drivers.virtual.plant import FirstOrderPlant

XM430 = MODELS["XM430-W350"]
TAU_S = 0.05
TICK_RAD = 2 * math.pi / 4096


@pytest.fixture
def rig():
    clock = SimulatedClock(10.0)
    plant = FirstOrderPlant(time_constant_s=TAU_S)
    virtual = ClockedBus(plant, clock=clock).start()
    bus = virtual.connect().open()
    for servo_id in (1, 2, 3):
        bus.add_servo(servo_id, XM430)
    yield clock, plant, virtual, bus
    bus.close()
    virtual.stop()


def test_the_plant_moves_with_the_clock_not_with_the_traffic(rig):
    clock, plant, virtual, bus = rig
    bus.write(1, Register.TORQUE_ENABLE, 1)
    for _ in range(5):  # goals and polls end no period of their own
        bus.write(1, Register.GOAL_POSITION, 3000)
        bus.read(1, Register.PRESENT_POSITION)
    assert virtual.sim_time_s == 0.0 and plant.time_s == 0.0
    clock.time_s += 0.1
    position = bus.read(1, Register.PRESENT_POSITION)
    assert virtual.sim_time_s == pytest.approx(0.1) and plant.time_s == pytest.approx(0.1)
    expected = 2048 + (3000 - 2048) * (1 - math.exp(-0.1 / TAU_S))
    assert abs(position - expected) <= 1
    assert virtual.servos[1].get("Realtime Tick") == 100  # ms of simulated time


def test_the_bus_watchdog_trips_in_the_step_its_period_ends_and_the_servo_stops_there(rig):
    clock, plant, virtual, bus = rig
    bus.write(1, Register.TORQUE_ENABLE, 1)
    bus.write(1, Register.BUS_WATCHDOG, 5)  # 100 ms
    bus.write(1, Register.GOAL_POSITION, 3000)
    clock.time_s += 0.099
    bus.read(2, Register.PRESENT_POSITION)  # to another servo: nothing to servo 1
    assert virtual.servos[1].get(Register.BUS_WATCHDOG) == 5
    clock.time_s += 0.4  # 499 ms without a packet to servo 1: it tripped at 101 ms
    bus.read(2, Register.PRESENT_POSITION)
    assert virtual.servos[1].get(Register.BUS_WATCHDOG) == -1
    stopped = (3000 - 2048) * (1 - math.exp(-0.101 / TAU_S)) * TICK_RAD
    np.testing.assert_allclose(plant.read()[0][0], stopped, atol=1e-9)
    assert plant.time_s == pytest.approx(0.499)


def test_packets_keep_the_watchdog_quiet_however_long_the_stream(rig):
    clock, _, virtual, bus = rig
    bus.write(1, Register.TORQUE_ENABLE, 1)
    bus.write(1, Register.BUS_WATCHDOG, 1)  # 20 ms
    for _ in range(200):  # 10 ms between packets, 2 s in all
        clock.time_s += 0.01
        bus.write(1, Register.GOAL_POSITION, 2100)
    assert virtual.servos[1].get(Register.BUS_WATCHDOG) == 1
    assert virtual.sim_time_s == pytest.approx(2.0)
