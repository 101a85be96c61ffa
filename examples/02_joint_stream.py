"""A joint stream: a keyframe file planned into pan, tilt and roll frames at a fixed rate.

The whole stream offline as arrays (``plan_joint_trajectory``: inverse
kinematics with pan and roll unwrapped, joint rates from the spline's exact
angular velocity and acceleration, the joint limits and the gimbal-lock guard
checked), and the same frames one at a time, as a streamer takes them
(``stream_frames``). Angles are radians in the library; the file is in degrees.

Run: .venv/bin/python examples/02_joint_stream.py [--file examples/pan_sweep.toml] [--rate 100]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from trajgen import JOINT_NAMES, load_keyframe_file, plan_joint_trajectory, stream_frames

HERE = Path(__file__).parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", type=Path, default=HERE / "pan_sweep.toml")
    parser.add_argument("--rate", type=float, help="stream rate (Hz); default the file's")
    options = parser.parse_args()

    keyframes = load_keyframe_file(options.file)
    rate_hz = keyframes.stream_rate(options.rate)
    spline = keyframes.spline()
    trajectory = plan_joint_trajectory(spline, rate_hz)
    print(f"{options.file.name}: {len(trajectory)} frames at {rate_hz:g} Hz")
    for j, name in enumerate(JOINT_NAMES):
        q, qd = np.degrees(trajectory.q[:, j]), trajectory.qd[:, j]
        print(
            f"  {name:4}: {q.min():7.2f} .. {q.max():6.2f} deg, "
            f"peak {np.abs(qd).max():.3f} rad/s, {np.abs(trajectory.qdd[:, j]).max():.3f} rad/s^2"
        )

    # The same frames, one per call: what a fixed-rate loop consumes.
    frames = list(stream_frames(spline, rate_hz))
    gap = max(np.abs(f.q - q).max() for f, q in zip(frames, trajectory.q, strict=True))
    print(f"frame by frame: {len(frames)} frames, largest difference {gap:.1e} rad")
    return 0 if len(frames) == len(trajectory) and gap < 1e-9 else 1


if __name__ == "__main__":
    raise SystemExit(main())
