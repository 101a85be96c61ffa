"""trajgen.sim.retime_optimum: the torque-rate-bounded time-optimal profile (the bench's peer)."""

import numpy as np
import pytest

from trajgen.sim import JointLimits
from trajgen.sim.retime_optimum import _Grid, rate_bounded_optimum

KEYS = """\
[stream]
rate_hz = 100

[gimbal]
servo = "XM430-W350"
payload_kg = 0.15

[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 1.0
pan = 40.0
tilt = 10.0

[[keyframes]]
t = 2.0
pan = 20.0
"""


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """The path's tables and a plan-only fit's law on it, sampled on 201 gridpoints."""
    from trajgen.sim import fit_timing
    from trajgen.sim.fit import _Fitter

    path = tmp_path_factory.mktemp("optimum") / "keys.toml"
    path.write_text(KEYS)
    fitter = _Fitter.build(path, None, JointLimits(), None, None, None)
    law = fit_timing(path, simulate=False).law
    s, speed = law(np.linspace(law.t_start, law.t_end, 201), 1)
    s = np.clip(s - law.s_start, 0.0, fitter.dyn.s_span)
    s[0], s[-1] = 0.0, fitter.dyn.s_span
    return fitter.dyn, s, speed, law.duration_s


def test_rows_and_time_gradient_match_finite_differences(planned, rng):
    dyn, s, speed, _ = planned
    grid = _Grid(dyn, s, 300.0)
    y = speed * rng.uniform(0.9, 1.1, len(speed))
    h, jac = grid.rows(y)
    t, g = grid.time(y)
    step = 1e-7
    for i in [0, 1, len(y) - 2, len(y) - 1, *rng.choice(len(y), 6, replace=False)]:
        dy = np.zeros_like(y)
        dy[i] = step * max(1.0, y[i])
        fd = (grid.rows(y + dy)[0] - grid.rows(y - dy)[0]) / (2 * dy[i])
        np.testing.assert_allclose(jac[:, i].toarray().ravel(), fd, atol=1e-5, rtol=1e-5)
        fd_t = (grid.time(y + dy)[0] - grid.time(y - dy)[0]) / (2 * dy[i])
        assert g[i] == pytest.approx(fd_t, rel=1e-5, abs=1e-9)


def test_optimum_keeps_its_rows_and_beats_the_smooth_law(planned):
    dyn, s, speed, ours = planned
    best = rate_bounded_optimum(dyn, s, speed, 300.0)
    assert best.violation <= 1e-6
    assert best.duration_s < ours  # a free profile on 201 points, no smoothness
    assert best.duration_s > 0.8 * ours  # ... but the same limits
    grid = _Grid(dyn, best.s, 300.0)
    assert grid.time(best.speed)[0] == pytest.approx(best.duration_s)
    assert grid.rows(best.speed)[0].max() <= 1e-6


def test_a_lower_torque_rate_bound_costs_time(planned):
    dyn, s, speed, _ = planned
    loose = rate_bounded_optimum(dyn, s, speed, 3000.0).duration_s
    tight = rate_bounded_optimum(dyn, s, speed, 100.0).duration_s
    assert tight > 1.03 * loose
