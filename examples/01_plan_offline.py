"""Plan offline: a blending spline through keyframes, sampled with its rates.

Kim & Nam's circular blending quaternion spline through four orientations
(given as pan, tilt, roll in degrees), evaluated like scipy's ``Slerp``: one
time gives one orientation, an array a stack; ``evaluate`` gives the
space-frame angular velocity, acceleration and jerk too. The spline passes
every keyframe exactly and starts and ends at rest.

Run: .venv/bin/python examples/01_plan_offline.py [--rate 50]
"""

from __future__ import annotations

import argparse

import numpy as np

from trajgen import BlendingSpline, quat


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=50.0, help="samples per second (Hz)")
    options = parser.parse_args()

    pan_tilt_roll_deg = np.array([[0, 0, 0], [40, 10, 0], [-20, 25, 5], [0, 0, 0]], float)
    times_s = np.array([0.0, 1.5, 3.0, 4.5])
    keyframes = quat.from_pan_tilt_roll(*np.radians(pan_tilt_roll_deg).T)  # (4, 4), w first
    spline = BlendingSpline(keyframes, times_s, k=2, boundary="rest")

    t = np.arange(spline.t_start, spline.t_end + 1e-12, 1.0 / options.rate)
    samples = spline.evaluate(t, max_order=3)
    speed = np.linalg.norm(samples.omega, axis=1)
    accel = np.linalg.norm(samples.alpha, axis=1)
    print(f"{len(t)} samples over {spline.t_end - spline.t_start:g} s at {options.rate:g} Hz")
    print(f"peak angular speed {speed.max():.3f} rad/s, acceleration {accel.max():.3f} rad/s^2")

    at_knots = spline(times_s)  # one orientation per time, shape (4, 4)
    miss = quat.distance(at_knots, keyframes).max()
    print(f"largest miss at the keyframes: {miss:.1e} rad")
    rest = np.linalg.norm(spline.evaluate(times_s[[0, -1]], max_order=1).omega, axis=1)
    print(f"angular speed at start and end: {rest[0]:.1e}, {rest[1]:.1e} rad/s")
    return 0 if miss < 1e-9 and rest.max() < 1e-9 else 1


if __name__ == "__main__":
    raise SystemExit(main())
