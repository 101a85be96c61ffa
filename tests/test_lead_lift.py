"""The lift (trajgen.lift) against hand-worked values, its bounds, and where it is sent."""

import numpy as np
import pytest

from trajgen.lead import LeadParams, led_goals, led_trajectory
from trajgen.lift import LIFT_RAMP, LIFT_SETTLE, lift_frames, sagged, sent_goals
from trajgen.lift import settle_time_s as settle
from trajgen.stream import JointTrajectory

RATE = 200.0
T = 1.0 / RATE
KP, K2R, DAMP, FRIC, GRAV, INERTIA = 20.0, 0.8, 0.2, 0.03, 0.4, 0.05
TAU = (K2R + DAMP) / KP  # 0.05 s


def params(**kw):
    base = dict(
        kp_nm_rad=[KP] * 2,
        back_emf_nm_s_rad=[K2R] * 2,
        lag_s=[TAU] * 2,
        frictionloss_nm=[FRIC] * 2,
        enabled=True,
        inertia_kg_m2=[INERTIA] * 2,
    )
    base.update(kw)
    return LeadParams(**base)


def torque(q, qd, qdd):
    """Inertia, viscous damping and constant gravity on joint 1 only (joint 0 is a pan)."""
    tau = INERTIA * qdd + DAMP * qd
    tau[:, 1] += GRAV
    return tau


def at_rest(q0=(0.1, -0.2), duration=1.0):
    t = np.arange(int(duration * RATE) + 1) / RATE
    q = np.tile(q0, (len(t), 1))
    zero = np.zeros_like(q)
    return JointTrajectory(t, q, zero, zero.copy(), RATE)


def test_the_sag_is_where_the_loop_holds_gravity():
    # constant gravity: q = goal - g / kp exactly
    np.testing.assert_allclose(sagged([0.3], [KP], lambda q: np.array([GRAV])), 0.3 - GRAV / KP)
    # a pendulum's gravity, m g l cos(q): the loop's torque balances it at the result
    goal = np.array([0.2, -0.4])
    kp = np.array([1.2, 1.2])

    def pendulum(q):
        return 0.044 * np.cos(q)

    q = sagged(goal, kp, pendulum)
    np.testing.assert_allclose(kp * (goal - q), pendulum(q), atol=1e-12)
    with pytest.raises(ValueError, match="gravity is stiffer than the position loop"):
        sagged([0.0], [1.0], lambda q: 5.0 * np.sin(3.0 * q) - 5.0)


def test_the_settle_time_is_the_loops_slowest_pole():
    p = params()
    c = KP * TAU
    # underdamped here (c^2 = 1 < 4 kp J = 4): the decay 2 J / c
    np.testing.assert_allclose(settle(p), 2 * INERTIA / c)
    heavy_damping = params(lag_s=[0.5, 0.5])  # c = 10, overdamped
    poles = np.roots([INERTIA, KP * 0.5, KP])
    np.testing.assert_allclose(settle(heavy_damping), 1 / np.abs(poles.real).min())
    np.testing.assert_allclose(settle(params(inertia_kg_m2=None)), TAU)  # J -> 0


def test_lift_goals_are_the_model_lead_of_a_smooth_lift_from_the_sag():
    tr = at_rest()
    q0, lifted = tr.q[0], led_goals(tr, "model", params(), torque=torque)
    lift = lifted.lift
    static = np.array([0.0, GRAV / KP])
    np.testing.assert_allclose(lift.sagged, q0 - static)
    # 3 settle times, in whole frames, the last one period before the plan's first
    m = lift_frames(LIFT_SETTLE * 2 * INERTIA / (KP * TAU), RATE)
    assert len(lift) == m and lift.duration_s == pytest.approx(m * T)
    np.testing.assert_allclose(lift.t, tr.t[0] - T * np.arange(m, 0, -1))
    # from the goal held (the plan's first point) to the plan's first led goal
    np.testing.assert_array_equal(lift.goal[0], q0)
    np.testing.assert_allclose(lift.goal[-1], q0 + static, atol=1e-15)
    np.testing.assert_allclose(lifted.goal[0], q0 + static, atol=1e-15)
    # in between, by hand: y = sag + (q0 - sag) r(x), goal = y + (J y'' + (b + K^2/R) y' + g) / kp
    span = (m - 1) * T
    x = np.arange(m) * T / span
    r = np.polyval(LIFT_RAMP, x)
    rd = np.polyval(np.polyder(LIFT_RAMP), x) / span
    rdd = np.polyval(np.polyder(LIFT_RAMP, 2), x) / span**2
    rise = static[1]
    y = lift.sagged[1] + rise * r
    goal = y + (INERTIA * rise * rdd + (DAMP + K2R) * rise * rd + GRAV) / KP
    np.testing.assert_allclose(lift.goal[1:-1, 1], goal[1:-1], atol=1e-15)
    np.testing.assert_allclose(lift.path[:, 1], y)
    np.testing.assert_allclose(lift.goal[:, 0], q0[0])  # no gravity on the pan: no lift
    # smooth (C2): the nonic's first four derivatives vanish at both ends
    for k in (1, 2, 3, 4):
        np.testing.assert_allclose(np.polyval(np.polyder(LIFT_RAMP, k), [0.0, 1.0]), 0.0)
    steps = np.diff(lift.goal[:, 1])
    assert np.abs(steps).max() < 0.1 * abs(rise)  # no goal step
    assert abs(steps[0]) < 1e-3 * abs(rise) and abs(steps[-1]) < 1e-3 * abs(rise)


def test_the_lift_stays_inside_the_bounds_and_is_sent_first():
    tr = at_rest()
    q0 = tr.q[0]
    limits = np.array([[-1.0, 1.0], [-1.0, q0[1] + 0.5 * GRAV / KP]])  # half the static term
    goals = led_goals(tr, "model", params(), torque=torque, limits_rad=limits)
    assert goals.lift.goal[:, 1].max() == pytest.approx(limits[1, 1])
    assert np.all(goals.lift.goal >= goals.bounds[:, 0]) and np.all(
        goals.lift.goal <= goals.bounds[:, 1]
    )
    led = led_trajectory(tr, goals)
    t, sent = sent_goals(led)
    np.testing.assert_array_equal(sent, np.vstack([goals.lift.goal, goals.goal]))
    np.testing.assert_allclose(np.diff(t), T)  # one stream, the lift's frames first
    assert len(list(led)) == len(tr)  # iterating gives the plan's frames only


def test_no_lift_without_a_static_term():
    tr = at_rest()

    def level(q, qd, qdd):
        return INERTIA * qdd + DAMP * qd

    assert led_goals(tr, "model", params(), torque=level).lift is None
    assert led_goals(tr, "advance", params()).lift is None
    assert led_goals(tr, "none", params()).lift is None
    off = led_goals(tr, "model", params().without([1]), torque=torque)
    assert off.lift is None  # the only joint with gravity gets no lead


def test_a_live_stream_draws_its_lift_with_its_first_frame():
    from trajgen.lead import LedFrames, lead_cap

    tr = at_rest()
    bounds = np.array([[-1.0, 1.0]] * 2)
    live = LedFrames(iter(tr), RATE, "model", params(), bounds, lead_cap(tr.qd, params()), torque)
    frames = iter(live)
    assert live.lift is None
    first = next(frames)
    whole = led_goals(tr, "model", params(), torque=torque)
    np.testing.assert_allclose(live.lift.goal, whole.lift.goal)
    np.testing.assert_allclose(first.goal, whole.goal[0], atol=1e-15)


HEAD = """[gimbal]
axes = "zy"
joints = ["pan", "tilt"]
servo = "XL330-M288"

[bus]
ids = [11, 12]

[[keyframes]]
t = 0.0
pan = 0.0
tilt = 0.0

[[keyframes]]
t = 1.0
pan = 20.0
tilt = 10.0
"""


def test_a_two_axis_head_is_lifted_in_sim_and_on_the_virtual_bus(tmp_path, capsys):
    """The XL330 tilt carries a camera ahead of its axis: the lift brings its 34 mrad
    static term in before the plan; sim and stream say how long, the telemetry marks it,
    and the error from the plan's start is within 2 mrad."""
    import csv
    import json

    from trajgen.cli import main

    keys = tmp_path / "head.toml"
    keys.write_text(HEAD)
    sim_json, stream_json, log = tmp_path / "sim.json", tmp_path / "stream.json", tmp_path / "t.csv"
    assert main(["sim", str(keys), "--json", str(sim_json)]) == 0
    assert "lift: 0.595 s before the plan" in capsys.readouterr().out
    report = json.loads(sim_json.read_text())
    assert report["lift_s"] == pytest.approx(0.595)
    argv = ["stream", str(keys), "--virtual", "--json", str(stream_json), "--telemetry", str(log)]
    assert main(argv) == 0
    out = json.loads(stream_json.read_text())
    assert out["stream"]["lift_s"] == pytest.approx(0.595) and out["stream"]["lift_frames"] == 119
    assert out["torque"]["lift_s"] == pytest.approx(0.595)
    for result in (report, out["torque"]):
        tilt = result["joints"]["tilt"]
        assert tilt["max_tracking_error_rad"] < 0.002 < tilt["max_lift_error_rad"]
    with open(log, newline="") as f:
        rows = list(csv.DictReader(f))
    lifted = [r for r in rows if r["phase"] == "lift"]
    assert len(lifted) == 119
    assert {float(r["plan_rad_tilt"]) for r in lifted} == {0.0}  # the plan holds still
    goals = [float(r["goal_rad_tilt"]) for r in lifted]
    assert goals[0] == 0.0 and goals[-1] < -0.03  # up to the static term
