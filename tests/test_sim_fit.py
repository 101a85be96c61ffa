"""`trajgen fit` and `trajgen.sim.fit_timing`: the fastest timing that passes, and tight."""

import argparse
import re
import tomllib

import numpy as np
import pytest

from trajgen.cli.fit import register
from trajgen.keyframes import KeyframeFileError, load_keyframe_file
from trajgen.sim import FitError, JointLimits, check_limits, check_torque, fit_timing
from trajgen.sim.check import resolve_source

# Segment 1 is a large pan move, segment 2 a small tilt nudge, segment 3 a medium return.
KEYS = """\
[spline]
# Per-segment tightness needs a local spline: with the global SmoothSpline (the
# default method) speeding one segment moves its neighbours too.
method = "blending"

[stream]
rate_hz = 100

[gimbal]
servo = "XM430-W350"
payload_kg = 0.15
# The envelope and the limits bind here, not tracking: with default gains (P 800)
# an X-series servo lags 45 ms x speed, which would cap pan near 1.1 rad/s.
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


def _retimed(tmp_path, document, times, name):
    from trajgen.toml_writer import dumps

    for entry, t in zip(document["keyframes"], times, strict=True):
        entry["t"] = float(t)
    return _write(tmp_path, dumps(document), name)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("fit")
    path = _write(tmp_path)
    result = fit_timing(path)
    out = _write(tmp_path, result.toml(), "fitted.toml")
    return path, result, out


def test_gentle_motion_gets_faster_and_passes(fitted):
    path, result, out = fitted
    assert result.duration_s < 0.5 * result.old_duration_s
    assert result.report.ok
    # The file as written passes `trajgen sim`'s check and keeps every other table.
    assert check_torque(out).ok
    original, written = tomllib.loads(path.read_text()), tomllib.loads(out.read_text())
    for table in ("stream", "gimbal", "bus"):
        assert written[table] == original[table]
    for a, b in zip(original["keyframes"], written["keyframes"], strict=True):
        assert {k: v for k, v in a.items() if k != "t"} == {k: v for k, v in b.items() if k != "t"}
    np.testing.assert_allclose(load_keyframe_file(out).times, result.times)


def test_ten_percent_faster_fails(fitted, tmp_path):
    _, result, out = fitted
    assert result.tight
    faster = result.times / 1.1
    report = check_torque(_retimed(tmp_path, tomllib.loads(out.read_text()), faster, "f.toml"))
    assert not report.ok


def test_each_segment_is_bound_by_its_own_limit(fitted, tmp_path):
    """Speeding up a segment bound by its own limit alone by 10 % fails.

    A segment whose binding limit is hit in another segment ("... in segment
    k": the spline's knot rates couple the segments) is held by that one.
    """
    _, result, out = fitted
    document = tomllib.loads(out.read_text())
    durations = np.diff(result.times)
    own = [i for i, s in enumerate(result.segments) if "in segment" not in s.binding]
    assert own, result.format()
    for i in own:
        d = durations.copy()
        d[i] /= 1.1
        times = np.concatenate([[0.0], np.cumsum(d)])
        report = check_torque(_retimed(tmp_path, document, times, f"seg{i}.toml"))
        assert not report.ok, f"segment {i + 1} could go 10% faster alone"
    # Per-segment, not a uniform scaling of the equal input durations.
    assert durations.max() / durations.min() > 1.05
    assert "fit:" in result.format() and "tight" in result.format()


def test_limits_table_binds_and_is_kept(tmp_path):
    path = _write(tmp_path, KEYS + "\n[limits]\nspeed_rad_s = {pan = 1.0}\n")
    result = fit_timing(path)
    trajectory, _ = resolve_source(_write(tmp_path, result.toml(), "out.toml"))
    assert np.abs(trajectory.qd[:, 0]).max() <= 1.0
    assert check_limits(trajectory, result.limits) == ()
    assert result.segments[0].binding == "speed limit (pan)"
    assert any("speed" in r for r in result.faster_reasons)
    assert tomllib.loads(result.toml())["limits"] == {"speed_rad_s": {"pan": 1.0}}


def test_check_limits_names_joint_and_time():
    from conftest import quintic_trajectory

    trajectory = quintic_trajectory([1.0, 0.0, 0.0], 1.0)
    assert check_limits(trajectory, JointLimits()) == ()
    reasons = check_limits(trajectory, JointLimits(speed_rad_s=1.0, jerk_rad_s3=(1e6, 1e6, 1e6)))
    assert len(reasons) == 1
    assert reasons[0].startswith("pan: speed 1.88 rad/s > limit 1 rad/s at t = 0.500 s")


def test_pose_too_heavy_to_hold_is_refused(tmp_path):
    path = _write(tmp_path, KEYS.replace("payload_kg = 0.15", "payload_kg = 20.0"))
    with pytest.raises(FitError, match="keyframe 1: the tilt servo cannot hold this pose against"):
        fit_timing(path)


def test_a_keyframe_at_gimbal_lock_is_refused_when_loaded(tmp_path):
    # One rule for every command (issue 20): refused as bad input, before any fit.
    path = _write(tmp_path, KEYS.replace("tilt = 8.0", "tilt = 89.0"))
    with pytest.raises(KeyframeFileError, match="'tilt': 89 deg is within 10.0 deg of gimbal"):
        fit_timing(path)


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ("[limits]\nspeed = 1.0\n", r"\[limits\]: unknown key 'speed'"),
        ("[limits]\njerk_rad_s3 = -1\n", r"\[limits\] jerk_rad_s3: expected a number > 0"),
        ("[limits]\nspeed_rad_s = {yaw = 1}\n", r"\[limits\] speed_rad_s: unknown joint 'yaw'"),
    ],
)
def test_bad_limits_table(tmp_path, extra, match):
    with pytest.raises(ValueError, match=match):
        fit_timing(_write(tmp_path, KEYS + extra))


def test_bad_arguments(tmp_path):
    with pytest.raises(TypeError, match="Expected `source`"):
        fit_timing(3.0)
    with pytest.raises(
        ValueError, match=r"Expected `tolerance` to be a finite number in \(0, 0.05\]"
    ):
        fit_timing(_write(tmp_path), tolerance=0.5)
    with pytest.raises(ValueError, match="Expected `speed_rad_s` to be a finite number > 0"):
        JointLimits(speed_rad_s=0.0)


def _fit_cli(argv):
    parser = argparse.ArgumentParser(prog="trajgen")
    register(parser.add_subparsers())
    args = parser.parse_args(["fit", *map(str, argv)])
    return args.func(args)


def test_cli_writes_file_and_reports_segments(tmp_path, capsys):
    out = tmp_path / "out.toml"
    assert (
        _fit_cli([_write(tmp_path, KEYS.replace("rate_hz = 100", "rate_hz = 50")), "--out", out])
        == 0
    )
    text = capsys.readouterr().out
    assert "segment  keyframes" in text and "binding limit" in text and "tight" in text
    assert out.read_text().startswith("# Fitted by `trajgen fit`")
    assert load_keyframe_file(out).tables["bus"]["ids"] == [1, 2, 3]


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


def test_sim_command_checks_the_limits_table(tmp_path, capsys):
    from trajgen.cli import main

    slow = KEYS.replace("rate_hz = 100", "rate_hz = 50") + "\n[limits]\nspeed_rad_s = {pan = 0.4}\n"
    path = _write(tmp_path, slow)
    assert main(["sim", str(path)]) == 1
    out = capsys.readouterr().out
    assert "torque check: OK" in out and "[limits]: FAILED" in out
    assert re.search(r"  - pan: speed [0-9.]+ rad/s > limit 0.4 rad/s at t = ", out)
    fitted = tmp_path / "fitted.toml"
    assert main(["fit", str(path), "--out", str(fitted)]) == 0
    capsys.readouterr()
    assert main(["sim", str(fitted)]) == 0
    assert "[limits]: OK" in capsys.readouterr().out


def test_plan_only_fit_keeps_the_envelope(fitted):
    from trajgen.sim.check import check_planned_torque

    path, result, _ = fitted
    plan_only = fit_timing(path, simulate=False)
    trajectory, config = resolve_source(_write(path.parent, plan_only.toml(), "plan_only.toml"))
    assert check_planned_torque(trajectory, config) == ()
    assert plan_only.duration_s <= result.duration_s * 1.01
    assert plan_only.faster_reasons  # 10% faster leaves the envelope


def test_too_fast_motion_is_slowed_to_what_the_servos_track(tmp_path):
    """Default tracking budget (0.05 rad): the firmware loop's lag binds; fit slows it, tight."""
    text = KEYS.replace("max_tracking_error_rad = 0.3\n", "")
    for old, new in (("t = 2.0", "t = 0.3"), ("t = 4.0", "t = 0.6"), ("t = 6.0", "t = 0.9")):
        text = text.replace(old, new)
    path = _write(tmp_path, text)
    assert not check_torque(path).ok
    result = fit_timing(path)
    assert result.duration_s > 0.9
    out = _write(tmp_path, result.toml(), "out.toml")
    assert check_torque(out).ok
    faster = check_torque(
        _retimed(tmp_path, tomllib.loads(out.read_text()), result.times / 1.1, "f.toml")
    )
    assert not faster.ok
    assert any("tracking" in s.binding for s in result.segments)


# The same keyframes on the default spline: global, so one segment's duration moves all.
SMOOTH_KEYS = KEYS.replace('method = "blending"', 'method = "smooth"')


@pytest.fixture(scope="module")
def fitted_smooth(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("fit_smooth")
    path = _write(tmp_path, SMOOTH_KEYS)
    result = fit_timing(path)
    return path, result, _write(tmp_path, result.toml(), "fitted.toml")


def test_smooth_spline_fit_is_tight_segment_by_segment(fitted_smooth, tmp_path):
    """On the global spline too, any one segment 10 % faster alone fails the check."""
    _, result, out = fitted_smooth
    assert result.report.ok and result.tight
    document = tomllib.loads(out.read_text())
    durations = np.diff(result.times)
    for i in range(len(durations)):
        d = durations.copy()
        d[i] /= 1.1
        times = np.concatenate([[0.0], np.cumsum(d)])
        report = check_torque(_retimed(tmp_path, document, times, f"seg{i}.toml"))
        assert not report.ok, f"segment {i + 1} could go 10% faster alone\n{result.format()}"


def test_plan_only_fit_reaches_its_splines_floor(fitted_smooth):
    """The joint fit is as short as a global search over the durations finds (within 1 %).

    Nelder-Mead over the durations' ratios on :func:`uniform_time_function`
    (each shape scaled until its slowest sample is at its limit). A fit that
    moves one segment at a time stops about 20 % above it here, where
    shortening any one segment pushes a neighbour over its limit.
    """
    from scipy.optimize import minimize

    from trajgen.sim.fit import uniform_time_function

    path, _, _ = fitted_smooth
    plan_only = fit_timing(path, simulate=False)
    probe, exact = uniform_time_function(path, probe=True), uniform_time_function(path)
    search = minimize(
        lambda x: probe(np.exp(x)), np.zeros(3), method="Nelder-Mead", options={"xatol": 1e-3}
    )
    floor = exact(np.exp(search.x))
    assert plan_only.duration_s <= 1.01 * floor
    # At the fit's own durations the plan is at its limit (within the tolerance).
    assert exact(np.diff(plan_only.times)) == pytest.approx(plan_only.duration_s, rel=0.01)
    # The uniformly scaled time depends on the durations' ratios only.
    assert exact(np.array([2.0, 1.0, 3.0])) == pytest.approx(exact([4.0, 2.0, 6.0]), rel=0.01)


def test_first_negative_root_matches_a_fine_grid(rng):
    from trajgen.sim.fit import _first_negative_root

    a = rng.uniform(-0.2, 1.0, 400)
    b, c = rng.normal(size=400), rng.normal(size=400)
    c[:20] = 0.0  # linear
    root = _first_negative_root(a, b, c)
    s = np.linspace(0.0, 10.0, 20_001)[:, None]
    negative = a + b * s + c * s * s < 0
    grid = np.where(negative.any(axis=0), s[np.argmax(negative, axis=0), 0], np.inf)
    inside = np.isfinite(grid) & (root < 9.9)
    np.testing.assert_allclose(root[inside], grid[inside], atol=1e-3)
    never = root[~np.isfinite(grid) & (a >= 0)]
    assert np.all(never > 9.99)
    assert np.all(root[a < 0] == 0.0)


def test_cli_without_scipy_is_bad_input(tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "scipy" else real(name, *a)
    )
    from trajgen.cli import main

    assert main(["fit", str(_write(tmp_path)), "--out", str(tmp_path / "o.toml")]) == 2
    assert "fit needs the scipy package: pip install scipy" in capsys.readouterr().err
