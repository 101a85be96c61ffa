"""The run-in from rest (trajgen.run_in): its time law by hand, the motion it plays
(at rest at both ends, C3, the same path), the file key, and the note for plans that
start moving."""

import numpy as np
import pytest

from trajgen.keyframes import load_keyframe_file
from trajgen.run_in import DISTANCE_RAMP, SPEED_RAMP, RunIn, run_in, starts_or_ends_moving
from trajgen.stream import plan_joint_trajectory

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]
WRIST = ROOT / "examples" / "wrist_loop.toml"


def test_speed_ramp_is_the_septic_smoothstep():
    x = np.linspace(0.0, 1.0, 11)
    hand = 35 * x**4 - 84 * x**5 + 70 * x**6 - 20 * x**7
    np.testing.assert_allclose(np.polyval(SPEED_RAMP, x), hand)
    assert np.polyval(DISTANCE_RAMP, 1.0) == pytest.approx(0.5)
    for m in range(1, 4):  # its first three derivatives vanish at both ends
        d = np.polyder(SPEED_RAMP, m)
        assert np.polyval(d, 0.0) == 0.0 and np.polyval(d, 1.0) == pytest.approx(0.0, abs=1e-9)


def test_time_law_hand_worked_values():
    law = RunIn(1.0, 5.0, 0.5)  # a 4 s path, 0.5 s ramps: the motion lasts 4.5 s
    assert law.t_start == 1.0 and law.t_end == 5.5
    s, ds, dds, ddds = law(np.array([1.0, 1.25, 1.5, 3.0, 5.0, 5.5]))
    np.testing.assert_allclose(
        s, [1.0, 1.0 + 0.5 * np.polyval(DISTANCE_RAMP, 0.5), 1.25, 2.75, 4.75, 5.0], atol=1e-15
    )
    np.testing.assert_allclose(ds, [0.0, 0.5, 1.0, 1.0, 1.0, 0.0], atol=1e-12)  # p(1/2) = 1/2
    # s'' = p'(x) / D: p'(1/2) = 35 / 16 on the way in, the mirror on the way out.
    assert dds[1] == pytest.approx(35 / 16 / 0.5) and dds[0] == dds[-1] == 0.0
    assert ddds[0] == ddds[-1] == 0.0


def test_time_law_is_c4_with_consistent_derivatives():
    law = RunIn(0.0, 2.0, 0.7)
    t = np.linspace(0.0, law.t_end, 200_001)
    values = law(t)
    for m in range(3):
        np.testing.assert_allclose(np.gradient(values[m], t)[2:-2], values[m + 1][2:-2], atol=2e-5)
    for join in (0.7, law.t_end - 0.7):  # the joins: every derivative continuous
        left, right = law(np.array([join - 1e-9])), law(np.array([join + 1e-9]))
        for a, b in zip(left, right, strict=True):
            assert abs(a[0] - b[0]) < 1e-7
    times = law.inverse(np.array([0.3, 1.0, 1.9]))
    np.testing.assert_allclose(law(times, 0)[0], [0.3, 1.0, 1.9], atol=1e-12)


def test_run_in_is_refused_when_too_long_or_not_positive():
    with pytest.raises(ValueError, match="Expected `run_in_s` at most the path's 2 s"):
        RunIn(0.0, 2.0, 2.5)
    with pytest.raises(ValueError, match="run_in_s"):
        RunIn(0.0, 2.0, 0.0)


def test_wrist_loop_plays_from_rest_along_its_own_path():
    kf = load_keyframe_file(WRIST)
    assert kf.run_in_s == 0.5
    motion = kf.spline()
    path = motion.path  # the closed loop as written
    assert motion.t_end == pytest.approx(path.t_end + 0.5)
    plan = plan_joint_trajectory(motion, 200.0)
    bare = plan_joint_trajectory(path, 200.0)
    assert starts_or_ends_moving(bare.qd) and not starts_or_ends_moving(plan.qd)
    np.testing.assert_allclose(plan.qdd[[0, -1]], 0.0, atol=1e-12)  # at rest, no acceleration
    np.testing.assert_allclose(plan.q[[0, -1]], bare.q[[0, -1]], atol=1e-12)  # same ends
    # The same path: in the middle, the plan is the bare one 0.25 s earlier.
    np.testing.assert_allclose(plan.q[200], bare.q[150], atol=1e-9)
    # Keyframes are passed in order, 0.25 s after their t (the middle ones).
    np.testing.assert_allclose(motion.times[1:-1], path.times[1:-1] + 0.25, atol=1e-9)
    ev = motion.evaluate(np.array([motion.t_start, motion.t_end]), max_order=3)
    np.testing.assert_allclose(ev.omega, 0.0, atol=1e-12)
    np.testing.assert_allclose(ev.jerk, 0.0, atol=1e-9)


def test_run_in_wraps_any_path():
    kf = load_keyframe_file(WRIST)
    motion = run_in(kf.spline().path, 1.0)
    assert motion.t_end == pytest.approx(5.0)


def test_file_key_is_checked(tmp_path):
    text = WRIST.read_text()
    for value, match in (("-1", r"\[stream\] run_in_s"), ("9.0", r"at most the path's 4 s")):
        bad = tmp_path / "bad.toml"
        bad.write_text(text.replace("run_in_s = 0.5", f"run_in_s = {value}"))
        with pytest.raises(ValueError, match=match):
            load_keyframe_file(bad).spline()


def test_a_plan_that_starts_moving_gets_a_note_with_the_remedy(tmp_path):
    from trajgen.sim.check import check_torque

    bare = tmp_path / "loop.toml"
    bare.write_text(WRIST.read_text().replace("run_in_s = 0.5", ""))
    report = check_torque(bare, lead="none")
    assert any("add `[stream] run_in_s = 0.5`" in n for n in report.lead_notes)
    assert not any("run_in_s" in n for n in check_torque(WRIST, lead="none").lead_notes)
