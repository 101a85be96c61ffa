"""trajgen.sim.fit_durations: the keyframe-times fit the retiming replaced (kept as reference)."""

import numpy as np

from trajgen.sim.fit_durations import fit_durations, uniform_time_function

KEYS = """\
[spline]
method = "blending"

[gimbal]
max_tracking_error_rad = 0.3

[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 2.0
pan = 60.0

[[keyframes]]
t = 4.0
pan = 20.0
tilt = 8.0
"""


def test_plan_only_durations_fit_is_at_its_limit_and_tight(tmp_path):
    path = tmp_path / "keys.toml"
    path.write_text(KEYS)
    result = fit_durations(path, simulate=False)
    assert result.duration_s < 0.5 * result.old_duration_s
    assert result.tight and result.faster == 1.1
    exact = uniform_time_function(path)
    assert abs(exact(np.diff(result.times)) - result.duration_s) < 0.01 * result.duration_s


def test_first_negative_root_matches_a_fine_grid(rng):
    from trajgen.sim.fit_durations import _first_negative_root

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
