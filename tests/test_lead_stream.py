"""Led goals on the bus: what the streamer sends and logs, what bring-up checks, follow."""

import csv
import dataclasses
import io
import math
import sys
from contextlib import contextmanager

import numpy as np
import pytest

from trajgen.cli import follow, main
from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.clock import SimulatedClock
from trajgen.drivers.control_table import Register
from trajgen.drivers.errors import BringUpError
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.telemetry import telemetry_columns
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.gimbal import GimbalKinematics
from trajgen.keyframes import BUILTIN_EXAMPLE, load_keyframe_file
from trajgen.lead import LedFrames, lead_cap
from trajgen.sim.lead import lead_params, lead_trajectory, torque_function
from trajgen.sim.model import GimbalConfig, gimbal_config_from_tables
from trajgen.sim.run import simulation_model
from trajgen.stream import JointTrajectory

RATE_HZ = 200.0
MODELS = ("XM430-W350",) * 3
TICK_RAD = 2 * math.pi / 4096
JOINTS = ("pan", "tilt", "roll")


def _move(q_end, duration_s=0.6):
    """A minimum-jerk joint move from 0 to ``q_end`` (rad), exact derivatives."""
    t = np.arange(round(duration_s * RATE_HZ) + 1) / RATE_HZ
    s = (t / duration_s)[:, None]
    d = np.asarray(q_end)
    q = d * (10 * s**3 - 15 * s**4 + 6 * s**5)
    qd = d * (30 * s**2 - 60 * s**3 + 30 * s**4) / duration_s
    qdd = d * (60 * s - 180 * s**2 + 120 * s**3) / duration_s**2
    return JointTrajectory(t, q, qd, qdd, RATE_HZ)


@contextmanager
def _servos(**registers):
    """A virtual bus of three XM430s (first-order plant) and a ServoBus open on it."""
    plant = FirstOrderPlant(time_constant_s=0.01)
    with VirtualBus(plant, models=MODELS, lockstep_dt_s=1 / RATE_HZ, **registers) as virtual:
        bus = ServoBus(virtual.port).open()
        try:
            yield virtual, bus
        finally:
            bus.close()


def test_telemetry_has_the_plan_beside_goal_and_position():
    columns = telemetry_columns(JOINTS)
    for j in JOINTS:
        k = columns.index(f"plan_rad_{j}")
        assert columns.index(f"goal_rad_{j}") > k and columns.index(f"position_rad_{j}") > k


def test_the_streamer_sends_the_led_goals_and_logs_the_plan(tmp_path):
    led, goals, _ = lead_trajectory(_move([0.5, -0.3, 0.2]), GimbalConfig())
    assert np.abs(led.goal - led.q).max() > 0.01  # a real lead, not the plan
    joints = JointMap()
    log = tmp_path / "t.csv"
    with _servos() as (virtual, bus):
        bounds = bring_up(bus, joints, MODELS, led).goal_bounds_ticks
        streamer = Streamer(
            bus, joints, telemetry=log, clock=SimulatedClock(), goal_bounds_ticks=bounds
        )
        stats = streamer.run(led)
        goal_log = list(virtual.goal_log)
    lift = led.lift  # the tilt's static gravity term, brought in before the plan
    sent = np.vstack([lift.goal, led.goal])
    received = joints.to_rad(np.array(goal_log[-len(sent) :]))
    np.testing.assert_allclose(received, sent, atol=TICK_RAD / 2 + 1e-12)
    assert stats.frames_sent == len(led)
    assert stats.lift_frames == len(lift) and stats.lift_s == lift.duration_s > 0.2
    assert stats.to_json_dict()["lift_s"] == lift.duration_s
    assert f"+{len(lift)} lift, {lift.duration_s:.3f} s" in stats.format()
    with open(log, newline="") as f:
        rows = list(csv.DictReader(f))
    for phase, q, goals in (
        ("lift", np.tile(lift.q, (len(lift), 1)), lift.goal),
        ("stream", led.q, led.goal),
    ):
        chosen = [r for r in rows if r["phase"] == phase]
        plan = np.array([[float(r[f"plan_rad_{j}"]) for j in JOINTS] for r in chosen])
        goal = np.array([[float(r[f"goal_rad_{j}"]) for j in JOINTS] for r in chosen])
        np.testing.assert_array_equal(plan, q)  # during the lift the plan holds its first point
        np.testing.assert_array_equal(goal, goals)
    t = np.array([float(r["t_s"]) for r in rows if r["phase"] != "approach"])
    np.testing.assert_allclose(np.diff(t), 1 / RATE_HZ, atol=1e-9)  # one stream, lift first


def test_bring_up_checks_the_goals_not_only_the_plan():
    # Tilt limited to 1800..2300 (up to 22.1 deg); the plan ends inside, 1 mrad short
    # of the limit; a goal led past it is refused before anything changes.
    high = (2300 - 2048) * TICK_RAD
    plan = _move([0.0, high - 0.001, 0.0])
    goal = plan.q.copy()
    goal[-40, 1] = high + 0.01
    limits = {Register.MIN_POSITION_LIMIT: 1800, Register.MAX_POSITION_LIMIT: 2300}
    with _servos(registers={2: limits}) as (_, bus):
        bring_up(bus, JointMap(), MODELS, plan)  # the plan alone fits
    with _servos(registers={2: limits}) as (virtual, bus):
        with pytest.raises(BringUpError, match=r"tilt leaves its position limits at t = 0\.4\d+ s"):
            bring_up(bus, JointMap(), MODELS, dataclasses.replace(plan, goal=goal))
        assert not any(s.torque_on for s in virtual.servos.values())


def test_bring_up_checks_the_lifts_goals_too():
    # The plan and its goals fit the tilt's limits; a lift goal past them is refused.
    high = (2300 - 2048) * TICK_RAD
    plan = _move([0.0, high - 0.05, 0.0])
    led, _, _ = lead_trajectory(plan, GimbalConfig())
    goal = led.lift.goal.copy()
    goal[5, 1] = high + 0.01
    limits = {Register.MIN_POSITION_LIMIT: 1800, Register.MAX_POSITION_LIMIT: 2300}
    with _servos(registers={2: limits}) as (_, bus):
        bring_up(bus, JointMap(), MODELS, led)
    lifted = dataclasses.replace(led, lift=dataclasses.replace(led.lift, goal=goal))
    with _servos(registers={2: limits}) as (virtual, bus):
        with pytest.raises(BringUpError, match=r"tilt leaves its position limits at t = -0\.\d+ s"):
            bring_up(bus, JointMap(), MODELS, lifted)
        assert not any(s.torque_on for s in virtual.servos.values())


def test_follow_sends_goals_led_from_the_live_plan(monkeypatch, tmp_path):
    seen = {}

    class SpyFollower(follow.Follower):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            seen["follower"] = self

    monkeypatch.setattr(follow, "Follower", SpyFollower)
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))  # no lines: the file's plan
    keys = tmp_path / "keys.toml"
    # configure: the follow range needs Extended Position Mode
    keys.write_text(BUILTIN_EXAMPLE.read_text() + "\n[bus]\nwatchdog_s = 0.5\nconfigure = true\n")
    log = tmp_path / "follow.csv"
    argv = ["follow", str(keys), "--virtual", "--max-delay", "60", "--telemetry", str(log)]
    assert main(argv) == 0
    traj = seen["follower"].trajectory()
    with open(log, newline="") as f:
        every = list(csv.DictReader(f))
    rows = [r for r in every if r["phase"] == "stream"]
    plan = np.array([[float(r[f"plan_rad_{j}"]) for j in JOINTS] for r in rows])
    goal = np.array([[float(r[f"goal_rad_{j}"]) for j in JOINTS] for r in rows])
    np.testing.assert_array_equal(plan, traj.q)
    # The goals are the live plan's own led goals (same q, qd, qdd, same function).
    kf = load_keyframe_file(keys)
    config = gimbal_config_from_tables(kf.tables, kf.path)
    model = simulation_model(config)
    params = lead_params(config, model)
    cap = lead_cap(np.array([[s.no_load_speed_rad_s for s in config.servos]]), params)
    live = LedFrames(
        iter(traj),
        RATE_HZ,
        "model",
        params,
        np.array(GimbalKinematics().limits_rad),
        cap,
        torque_function(model),
    )
    expected = [f.goal for f in live]
    np.testing.assert_allclose(goal, expected, atol=1e-12)
    assert np.abs(goal - plan).max() > 0.01  # led: ahead of the plan while it moves
    # ... after the lift, drawn from the live plan's first frame
    lifted = [r for r in every if r["phase"] == "lift"]
    assert len(lifted) == len(live.lift) > 0
    lift_goal = np.array([[float(r[f"goal_rad_{j}"]) for j in JOINTS] for r in lifted])
    np.testing.assert_allclose(lift_goal, live.lift.goal, atol=1e-12)
