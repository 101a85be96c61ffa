import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen.sim.plot import envelope_use_pct, period_mean_and_range, reversals


def test_reversals_are_where_the_speed_changes_sign_or_leaves_zero():
    qd = np.array([0.0, 0.1, 0.2, -0.1, -0.2, 0.0, 0.0, 0.3])
    np.testing.assert_array_equal(reversals(qd), [1, 3, 5, 7])


def test_use_is_a_percentage_and_infinite_where_no_torque_is_left():
    use = envelope_use_pct(np.array([0.5, -1.0, 0.1]), np.array([2.0, 1.0, -0.3]))
    np.testing.assert_array_equal(use, [25.0, 100.0, np.inf])


def test_period_mean_and_range_by_hand():
    t = np.arange(10) * 0.001  # 1 ms steps, 5 ms periods
    values = np.array([0, 1, 2, 3, 4, 10, 10, 10, 10, 20], dtype=float)
    centre, mean, lo, hi = period_mean_and_range(t, values, 0.005)
    np.testing.assert_allclose(centre, [0.0025, 0.0075])
    np.testing.assert_allclose(mean, [2.0, 12.0])
    np.testing.assert_array_equal(lo, [0, 10])
    np.testing.assert_array_equal(hi, [4, 20])


def test_a_failing_run_plots_past_no_load_speed(tmp_path):
    pytest.importorskip("matplotlib")
    from trajgen.sim import check_torque
    from trajgen.sim.plot import plot_report

    report = check_torque(quintic_trajectory([1.0, 0.4, -0.3], 0.2))
    out = plot_report(report, tmp_path / "fail.png")
    assert out.stat().st_size > 10_000


def test_the_plot_shows_the_tracking_error_and_says_what_failed():
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    from trajgen.keyframes import BUILTIN_EXAMPLE
    from trajgen.sim import check_torque
    from trajgen.sim.plot import ERROR_FLOOR_RAD, MIN_SPAN, failed_checks, report_figure

    # A 0.9 rad pan move in 0.8 s sent as planned: pan lags past the 2.9 deg budget.
    report = check_torque(quintic_trajectory([0.9, 0.0, 0.0], 0.8), lead="none")
    assert not report.ok and failed_checks(report) == "tracking error (pan)"
    fig = report_figure(report)
    try:
        assert fig._suptitle.get_text().startswith("torque check: FAILED: tracking error (pan)")
        axes = np.array(fig.axes[:15]).reshape(5, 3)
        pan_error = axes[2, 0]
        assert pan_error.get_yscale() == "log" and pan_error.get_ylim()[0] == ERROR_FLOOR_RAD
        limits = [line.get_ydata()[0] for line in pan_error.get_lines()[1:]]
        assert report.max_tracking_error_rad in limits  # the limit is drawn
        assert "tracking error: peak" in pan_error.get_title()
        # roll does not move: its axes are not blown up to rounding noise
        low, high = axes[0, 2].get_ylim()
        assert high - low >= MIN_SPAN["angle"]
        low, high = axes[1, 2].get_ylim()
        assert high - low >= MIN_SPAN["velocity"]
    finally:
        plt.close(fig)
    led = check_torque(BUILTIN_EXAMPLE)
    assert led.ok and failed_checks(led) == ""
