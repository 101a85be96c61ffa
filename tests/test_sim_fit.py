"""`trajgen fit` and `trajgen.sim.fit_timing`: the path retimed, passing the check, tight."""

import argparse
import re
import tomllib

import numpy as np
import pytest

from trajgen.cli.fit import register
from trajgen.keyframes import KeyframeFileError, load_keyframe_file
from trajgen.sim import FitError, JointLimits, check_limits, check_torque, fit_timing
from trajgen.sim.check import resolve_source
from trajgen.sim.fit import FASTER, plan_reasons
from trajgen.stream import plan_joint_trajectory
from trajgen.timelaw import RetimedPath, TimeLaw

# Segment 1 is a large pan move, segment 2 a small tilt nudge, segment 3 a medium return.
KEYS = """\
[spline]
method = "blending"

[stream]
rate_hz = 100

[gimbal]
servo = "XM430-W350"
payload_kg = 0.15
# The envelope binds here, not tracking: with default gains (P 800) an X-series
# servo lags 45 ms x speed, which would cap pan near 1.1 rad/s.
max_tracking_error_rad = 0.3

[bus]
port = "/dev/ttyUSB0"
ids = [1, 2, 3]

[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 2.0
pan = 60.0

[[keyframes]]
t = 4.0
pan = 60.0
tilt = 8.0

[[keyframes]]
t = 6.0
pan = 20.0
tilt = 0.0
"""


def _write(tmp_path, text=KEYS, name="keys.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("fit")
    path = _write(tmp_path)
    result = fit_timing(path)
    out = _write(tmp_path, result.toml(), "fitted.toml")
    return path, result, out


def _scaled(result, factor):
    """The fitted motion ``factor`` times as fast."""
    law = result.law
    faster = TimeLaw(
        law.knots, law.coefficients, law.t_start, law.duration_s / factor, law.s_start, law.s_span
    )
    return RetimedPath(result.path.path, faster)


def test_fitted_file_passes_and_keeps_everything_else(fitted):
    path, result, out = fitted
    assert result.duration_s < 0.5 * result.old_duration_s
    assert result.report.ok
    # The file as written passes `trajgen sim`'s check and keeps every other table.
    assert check_torque(out).ok
    original, written = tomllib.loads(path.read_text()), tomllib.loads(out.read_text())
    for table in ("stream", "gimbal", "bus"):
        assert written[table] == original[table]
    assert written["spline"] == {"method": "smooth"}  # the C3 path
    for a, b in zip(original["keyframes"], written["keyframes"], strict=True):
        assert {k: v for k, v in a.items() if k != "t"} == {k: v for k, v in b.items() if k != "t"}
    kf = load_keyframe_file(out)
    np.testing.assert_allclose(kf.times, result.times, atol=1e-12)
    # What `sim`, `stream`, `follow` and `plan` play is the fitted motion.
    fitted_plan = plan_joint_trajectory(result.path, 100.0)
    np.testing.assert_allclose(resolve_source(out)[0].q, fitted_plan.q, atol=1e-12)


def test_five_percent_faster_fails(fitted):
    _, result, _ = fitted
    assert result.tight and result.faster == FASTER == 1.05
    assert not check_torque(_scaled(result, FASTER), rate_hz=100.0, config=result.report.config).ok
    assert "tight: 5% faster fails" in result.format()


def test_every_keyframe_is_passed_in_order(fitted):
    _, result, out = fitted
    kf = load_keyframe_file(out)
    assert (np.diff(kf.times) > 0).all()
    q = kf.spline().evaluate(kf.times, max_order=0).q
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", q, kf.quats)), 1.0, atol=1e-12)


def test_rest_at_both_ends_and_torque_rate_within_bound(fitted):
    _, result, _ = fitted
    fine = plan_joint_trajectory(result.path, 1000.0)
    for k in (0, -1):
        assert np.abs(fine.qd[k]).max() < 1e-9 and np.abs(fine.qdd[k]).max() < 1e-6
    config = result.report.config
    assert plan_reasons(result.path, config, JointLimits(), 300.0, 100.0) == ()
    assert plan_reasons(result.path, config, JointLimits(), 30.0, 100.0)  # a bound that binds


def test_jerk_is_continuous(fitted):
    """The jerk's change between samples falls about tenfold from 1 kHz to 10 kHz."""
    _, result, _ = fitted
    steps = []
    for rate in (1000.0, 10000.0):
        jerk = result.path.sample(rate, max_order=3).jerk
        steps.append(np.abs(np.diff(jerk, axis=0)).max())
    assert steps[1] < steps[0] / 5


def test_segments_report_old_and_new_and_binding(fitted):
    _, result, _ = fitted
    text = result.format()
    assert "segment  keyframes" in text and "binding limit" in text
    assert [s.old_s for s in result.segments] == [2.0, 2.0, 2.0]
    np.testing.assert_allclose([s.new_s for s in result.segments], np.diff(result.times))
    names = ("torque envelope", "torque rate", "sim torque limit", "tracking error")
    assert all(s.binding.startswith(names) for s in result.segments), text


def test_law_gradient_matches_finite_differences(tmp_path, rng):
    from trajgen.sim.fit import _Fitter
    from trajgen.sim.retime import LawProblem, initial_law

    fitter = _Fitter.build(_write(tmp_path), None, JointLimits(jerk_rad_s3=500.0), None, None, None)
    knots, c, z = initial_law(fitter.dyn, fitter.bounds)
    problem = LawProblem(fitter.dyn, fitter.bounds, knots)
    c = c + np.concatenate([[0.0], rng.uniform(-0.1, 0.1, len(c) - 2), [0.0]]) / len(c)
    h, parts = problem.rows(c, z)
    rows = rng.choice(h.size, 200, replace=False)
    jc, jz = problem.jacobian(parts, rows)
    step = 1e-7
    for i in rng.choice(np.arange(1, len(c) - 1), 6, replace=False):
        dc = np.zeros_like(c)
        dc[i] = step
        fd = (problem.rows(c + dc, z)[0].ravel() - problem.rows(c - dc, z)[0].ravel()) / (2 * step)
        np.testing.assert_allclose(jc[:, i].toarray().ravel(), fd[rows], atol=1e-4, rtol=1e-4)
    fd = (problem.rows(c, z + step)[0].ravel() - problem.rows(c, z - step)[0].ravel()) / (2 * step)
    np.testing.assert_allclose(jz, fd[rows], atol=1e-5, rtol=1e-5)


def test_limits_table_and_torque_rate_bind(tmp_path):
    """Plan only: [limits] speed and a low torque-rate bound are kept and reported."""
    path = _write(tmp_path, KEYS + "\n[limits]\nspeed_rad_s = {pan = 1.0}\ntorque_rate_nm_s = 20\n")
    result = fit_timing(path, simulate=False)
    trajectory, config = resolve_source(_write(tmp_path, result.toml(), "out.toml"))
    assert np.abs(trajectory.qd[:, 0]).max() <= 1.0
    assert check_limits(trajectory, result.limits) == ()
    assert plan_reasons(result.path, config, result.limits, 20.0, 100.0) == ()
    assert any(s.binding.startswith(("speed limit (pan)", "torque rate")) for s in result.segments)
    assert tomllib.loads(result.toml())["limits"] == {
        "speed_rad_s": {"pan": 1.0},
        "torque_rate_nm_s": 20,
    }
    assert result.tight


def test_pose_too_heavy_to_hold_is_refused(tmp_path):
    path = _write(tmp_path, KEYS.replace("payload_kg = 0.15", "payload_kg = 20.0"))
    with pytest.raises(FitError, match="keyframe 1: the tilt servo cannot hold this pose against"):
        fit_timing(path)


def test_a_keyframe_at_gimbal_lock_is_refused_when_loaded(tmp_path):
    # One rule for every command (issue 20): refused as bad input, before any fit.
    path = _write(tmp_path, KEYS.replace("tilt = 8.0", "tilt = 89.0"))
    with pytest.raises(KeyframeFileError, match="'tilt': 89 deg is within 10.0 deg of gimbal"):
        fit_timing(path)


def test_moving_ends_are_refused(tmp_path):
    path = _write(tmp_path, KEYS.replace('method = "blending"', 'boundary = "natural"'))
    with pytest.raises(FitError, match="from rest to rest: \\[spline\\] boundary is 'natural'"):
        fit_timing(path)


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ("[limits]\nspeed = 1.0\n", r"\[limits\]: unknown key 'speed'"),
        ("[limits]\njerk_rad_s3 = -1\n", r"\[limits\] jerk_rad_s3: expected a number > 0"),
        ("[limits]\nspeed_rad_s = {yaw = 1}\n", r"\[limits\] speed_rad_s: unknown joint 'yaw'"),
        (
            "[limits]\ntorque_rate_nm_s = 0\n",
            r"\[limits\] torque_rate_nm_s: expected a finite number > 0, got 0",
        ),
    ],
)
def test_bad_limits_table(tmp_path, extra, match):
    with pytest.raises(ValueError, match=match):
        fit_timing(_write(tmp_path, KEYS + extra))


def test_bad_arguments(tmp_path):
    with pytest.raises(TypeError, match="Expected `source`"):
        fit_timing(3.0)
    with pytest.raises(ValueError, match="Expected `torque_rate_nm_s` to be a finite number > 0"):
        fit_timing(_write(tmp_path), torque_rate_nm_s=-1.0)


def _fit_cli(argv):
    parser = argparse.ArgumentParser(prog="trajgen")
    register(parser.add_subparsers())
    args = parser.parse_args(["fit", *map(str, argv)])
    return args.func(args)


def test_cli_fits_and_sim_passes_the_result(tmp_path, capsys):
    from trajgen.cli import main

    slow = KEYS.replace("rate_hz = 100", "rate_hz = 50") + "\n[limits]\nspeed_rad_s = {pan = 0.4}\n"
    path = _write(tmp_path, slow)
    assert main(["sim", str(path)]) == 1
    out = capsys.readouterr().out
    assert "torque check: OK" in out and "[limits]: FAILED" in out
    assert re.search(r"  - pan: speed [0-9.]+ rad/s > limit 0.4 rad/s at t = ", out)
    fitted = tmp_path / "fitted.toml"
    assert _fit_cli([path, "--out", fitted]) == 0
    text = capsys.readouterr().out
    assert "segment  keyframes" in text and "binding limit" in text and "tight" in text
    assert fitted.read_text().startswith("# Fitted by `trajgen fit`")
    assert load_keyframe_file(fitted).tables["bus"]["ids"] == [1, 2, 3]
    assert main(["sim", str(fitted)]) == 0
    assert "[limits]: OK" in capsys.readouterr().out


def test_cli_refusal_and_bad_input(tmp_path, capsys):
    heavy = _write(tmp_path, KEYS.replace("payload_kg = 0.15", "payload_kg = 20.0"))
    assert _fit_cli([heavy, "--out", tmp_path / "o.toml"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("trajgen: fit refused: keyframe 1") and err.count("\n") == 1
    bad = _write(tmp_path, KEYS + "[limits]\nspeed = 1\n", "bad.toml")
    from trajgen.cli import main

    assert main(["fit", str(bad), "--out", str(tmp_path / "o.toml")]) == 2
    assert "[limits]: unknown key 'speed'" in capsys.readouterr().err
    assert not (tmp_path / "o.toml").exists()


def test_too_fast_motion_is_slowed_to_what_the_servos_track(tmp_path):
    """Default tracking budget (0.05 rad) and unled goals (``lead = "none"``, which the fit
    judges by, as the stream sends): the firmware loop's lag binds; fit slows it, tight."""
    text = KEYS.replace("max_tracking_error_rad = 0.3\n", "").replace(
        "rate_hz = 100\n", 'rate_hz = 100\nlead = "none"\n'
    )
    path = _write(tmp_path, text)
    result = fit_timing(path)
    out = _write(tmp_path, result.toml(), "out.toml")
    assert check_torque(out, lead="none").ok
    faster = _scaled(result, FASTER)
    assert not check_torque(faster, rate_hz=100.0, config=result.report.config, lead="none").ok
    assert result.tight
    assert any("tracking" in s.binding for s in result.segments), result.format()


def test_cli_without_scipy_is_bad_input(tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "scipy" else real(name, *a)
    )
    from trajgen.cli import main

    assert main(["fit", str(_write(tmp_path)), "--out", str(tmp_path / "o.toml")]) == 2
    assert "fit needs the scipy package: pip install scipy" in capsys.readouterr().err
