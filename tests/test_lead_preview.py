"""The bounded preview of trajgen.lead_preview: the loop's pulse response, the
box-constrained least squares, and goals that anticipate their clips."""

import numpy as np
import pytest
from test_lead import INERTIA, KP, RATE, TAU, params, sine, torque

from trajgen.lead import led_goals
from trajgen.lead_preview import (
    REGULARISATION,
    _solve_window,
    box_least_squares,
    expm,
    preview_goals,
    pulse_response,
)

T = 1.0 / RATE
C = KP * TAU  # K^2/R + b


def test_expm_of_a_rotation_generator_is_the_rotation():
    theta = 2.7
    r = expm(np.array([[0.0, -theta], [theta, 0.0]]))
    np.testing.assert_allclose(r, [[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])


def test_expm_matches_scipy_on_random_matrices():
    scipy_linalg = pytest.importorskip("scipy.linalg")
    rng = np.random.default_rng(3)
    for scale in (0.01, 1.0, 30.0):
        a = scale * rng.normal(size=(3, 3))
        np.testing.assert_allclose(expm(a), scipy_linalg.expm(a), rtol=1e-10, atol=1e-12)


def test_pulse_response_sums_to_the_hand_worked_step_response():
    # J e'' + c e' + kp e = kp u: underdamped here, with step response
    # 1 - exp(-z w t) (cos(wd t) + z w / wd sin(wd t)).
    h = pulse_response(KP, C, INERTIA, T)
    w = np.sqrt(KP / INERTIA)
    z = C / (2 * np.sqrt(KP * INERTIA))
    assert 0 < z < 1
    wd = w * np.sqrt(1 - z**2)
    t = T * np.arange(1, len(h) + 1)
    step = 1 - np.exp(-z * w * t) * (np.cos(wd * t) + z * w / wd * np.sin(wd * t))
    np.testing.assert_allclose(np.cumsum(h), step, atol=1e-12)
    assert abs(np.sum(h) - 1.0) < 2e-3  # cut once it has settled


def test_box_least_squares_hand_cases():
    # One variable: the unconstrained b / a, clipped.
    a = np.array([[2.0]])
    assert box_least_squares(a, np.array([3.0]), np.array([-1.0]), np.array([1.0]))[0] == 1.0
    assert box_least_squares(a, np.array([1.0]), np.array([-1.0]), np.array([1.0]))[0] == 0.5
    # Two variables, the first bound active: x1 then solves its own row.
    a = np.array([[1.0, 0.0], [1.0, 1.0]])
    b = np.array([5.0, 1.0])
    x = box_least_squares(a, b, np.array([-2.0, -10.0]), np.array([2.0, 10.0]))
    np.testing.assert_allclose(x, [2.0, -1.0])


def test_box_least_squares_matches_scipy():
    optimize = pytest.importorskip("scipy.optimize")
    rng = np.random.default_rng(11)
    for _ in range(20):
        m, k = rng.integers(5, 40), rng.integers(2, 20)
        k = min(k, m)
        a, b = rng.normal(size=(m, k)), rng.normal(size=m)
        lo = -rng.uniform(0.0, 0.5, k)
        hi = rng.uniform(0.0, 0.5, k)
        x = box_least_squares(a, b, lo, hi)
        ref = optimize.lsq_linear(a, b, bounds=(lo, hi), tol=1e-14).x
        assert np.all(x >= lo) and np.all(x <= hi)
        cost = np.sum((a @ x - b) ** 2)
        assert cost <= np.sum((a @ ref - b) ** 2) + 1e-10
        np.testing.assert_allclose(x, ref, atol=1e-6)


def test_one_clipped_frame_and_one_free_frame_solve_by_hand():
    # Frame 1 is held at -d (its bound), frame 0 is free. The cost
    # sum_k (h_k x0 - d h_(k-1))^2 + R (x0^2 + (x0 + d)^2 + d^2) is least at
    # x0 = d (c1 - R) / (c0 + 2 R), c0 = sum h_k^2, c1 = sum h_k h_(k-1).
    h = pulse_response(KP, C, INERTIA, T)
    d = 0.003
    c0, c1, r = np.sum(h**2), np.sum(h[1:] * h[:-1]), REGULARISATION
    x = _solve_window(h, np.array([-np.inf, -d]), np.array([np.inf, -d]))
    np.testing.assert_allclose(x, [d * (c1 - r) / (c0 + 2 * r), -d], rtol=1e-9, atol=1e-15)


def test_preview_leaves_unclipped_goals_alone_and_keeps_clipped_ones_inside():
    n = 400
    t = T * np.arange(n)
    goal = np.stack([0.1 * t, 0.2 * np.sin(np.pi * t / t[-1])], axis=1)  # one peak
    lo, hi = np.full((n, 2), -np.inf), np.full((n, 2), np.inf)
    hi[:, 1] = 0.195  # joint 1 is clipped at its top
    out, changed = preview_goals(goal, lo, hi, T, [KP] * 2, [C] * 2, [INERTIA] * 2)
    np.testing.assert_array_equal(out[:, 0], goal[:, 0])
    assert changed[0] == 0 and changed[1] > (goal[:, 1] > hi[:, 1]).sum()
    assert np.all(out[:, 1] <= hi[:, 1])
    # The preview is the least cost over every goal inside the bounds, so below the
    # plain clip's (error against the loop's model plus the step penalty); its error too.
    h = pulse_response(KP, C, INERTIA, T)

    def cost(g):
        dg = g - goal[:, 1]
        return np.sum(np.convolve(dg, h) ** 2) + REGULARISATION * np.sum(np.diff(dg) ** 2)

    clipped = np.minimum(goal[:, 1], hi[:, 1])
    assert cost(out[:, 1]) < 0.99 * cost(clipped)
    error = lambda g: np.abs(np.convolve(g - goal[:, 1], h)).max()  # noqa: E731
    assert error(out[:, 1]) < error(clipped)


def test_model_lead_with_inertia_previews_its_clips_at_a_reversal():
    # A long lag and a light joint: the lead overshoots each reversal by about
    # |qdd| (tau^2 / 2 - J / kp) = 2 (0.005 - 0.001) rad.
    tr = sine(amplitude=0.5, hz=1.0)
    light = 0.02
    slow = dict(lag_s=[0.1] * 3, back_emf_nm_s_rad=[2.0] * 3)

    def inertial(q, qd, qdd):
        return light * qdd

    plain = led_goals(tr, "model", params(**slow), torque=inertial)
    with_inertia = params(**slow, inertia_kg_m2=[light] * 3)
    previewed = led_goals(tr, "model", with_inertia, torque=inertial)
    b = previewed.bounds
    assert plain.clipped.min() > 0  # the lead overshoots the plan's range at each reversal
    assert np.all(previewed.goal >= b[:, 0]) and np.all(previewed.goal <= b[:, 1])
    assert np.all(previewed.clipped >= plain.clipped)
    moved = np.any(previewed.goal != plain.goal, axis=1)
    assert moved.any() and not moved.all()  # only near the reversals
    # And inside installed limits tighter than the plan's range.
    limits = np.array([[-0.45, 0.45]] * 3)
    inside = led_goals(tr, "model", with_inertia, torque=inertial, limits_rad=limits)
    assert np.all(np.abs(inside.goal) <= 0.45) and inside.clipped.min() > plain.clipped.min()


def test_none_and_advance_do_not_preview():
    tr = sine(amplitude=0.5, hz=1.0)
    with_inertia = params(inertia_kg_m2=[INERTIA] * 3)
    for lead in ("none", "advance"):
        np.testing.assert_array_equal(
            led_goals(tr, lead, with_inertia, torque=torque).goal,
            led_goals(tr, lead, params(), torque=torque).goal,
        )
    np.testing.assert_array_equal(led_goals(tr, "none", with_inertia).goal, tr.q)


def test_inertia_is_checked():
    with pytest.raises(ValueError, match="Expected `inertia_kg_m2` to have 3 finite entries"):
        params(inertia_kg_m2=[1.0, 0.0, 1.0])
