"""Follow a wandering target through the virtual servo bus, changing the plan while moving.

A scripted target wanders in pan and tilt and changes its mind every 0.3-1 s.
Each time it does, the script sends one keyframe line to ``trajgen follow``
("be where the target is 0.6 s from now", a retarget), exactly as a tracker
would on stdin. The gimbal is the simulated one behind the virtual bus; the
stream, the checks and the torque report are those of the command line.

Writes ``out/follow_target.png``: the commanded joint angles with every
keyframe drawn from the moment it arrived to the time it asked for, the joint
speeds, and the planned and simulated torque against the servo's envelope.

Run: .venv/bin/python examples/follow_target.py [--seconds 8] [--out out/follow_target.png]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from trajgen import quat as Q
from trajgen.cli import build_parser
from trajgen.cli.follow import follow
from trajgen.gimbal import forward

HERE = Path(__file__).parent
LEAD_S = 0.6  # each keyframe asks to be there this long after it arrives


def wandering_target(seconds: float, seed: int = 7):
    """Lines of a target that changes its mind every 0.3-1 s: a function of the
    follower, so that the first line waits for the stream to run."""
    rng = np.random.default_rng(seed)

    def lines(follower):
        while follower.spline.committed < 0.5:  # the stream is running
            time.sleep(0.01)
        pan, tilt, end = 0.0, 0.0, time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(rng.uniform(0.3, 1.0))
            pan = float(np.clip(pan + rng.normal(0.0, 15.0), -60.0, 60.0))
            tilt = float(np.clip(tilt + rng.normal(0.0, 8.0), -30.0, 30.0))
            yield json.dumps({"in": LEAD_S, "pan": round(pan, 2), "tilt": round(tilt, 2)})

    return lines


def plot(follower, report, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    traj = report.trajectory
    fig, axes = plt.subplots(3, 2, figsize=(13, 9), sharex=True)
    for j, name in enumerate(("pan", "tilt")):
        ax_q, ax_w, ax_t = axes[:, j]
        ax_q.plot(traj.t, np.degrees(traj.q[:, j]), color="tab:blue", label="commanded")
        ax_q.plot(
            report.record.t,
            np.degrees(report.record.q[:, j]),
            "--",
            color="tab:orange",
            lw=1,
            label="simulated",
        )
        for n, kf in enumerate(follower.keyframes):
            angle = np.degrees(_joint_angle(kf["quat"], j))
            ax_q.plot([kf["now"], kf["t"]], [angle, angle], color="0.6", lw=0.8)
            ax_q.plot(
                kf["t"], angle, "o", color="tab:red", ms=4, label="keyframe" if n == 0 else None
            )
            ax_q.plot(kf["now"], angle, "|", color="0.3", ms=8, label="arrived" if n == 0 else None)
        ax_q.set_title(f"{name}: commanded path and keyframes (arrival -> asked time)")
        ax_w.plot(traj.t, traj.qd[:, j], color="tab:blue", label="planned")
        ax_w.plot(
            report.record.t,
            report.record.qd[:, j],
            "--",
            color="tab:orange",
            lw=1,
            label="simulated",
        )
        servo = report.config.servos[j]
        usable = report.torque_margin * servo.tau_max(traj.qd[:, j])
        ax_t.fill_between(
            traj.t,
            -usable,
            usable,
            color="0.9",
            label=f"{report.torque_margin:g} x envelope (>= {usable.min():.2f} N m)",
        )
        ax_t.plot(
            report.record.t,
            report.record.torque_nm[:, j],
            color="tab:orange",
            lw=0.5,
            label="simulated",
        )
        ax_t.plot(traj.t, report.planned_torque_nm[:, j], color="tab:blue", label="planned")
        lim = 1.3 * max(np.abs(report.planned_torque_nm[:, j]).max(), 0.1)
        ax_t.set_ylim(-lim, lim)
        ax_t.set_xlabel("stream time (s)")
    axes[0, 0].set_ylabel("angle (deg)")
    axes[1, 0].set_ylabel("joint speed (rad/s)")
    axes[2, 0].set_ylabel("torque (N m)")
    for ax, where in zip(axes[:, 0], ("lower left", "upper left", "upper left"), strict=True):
        ax.legend(fontsize=8, loc=where)
    s = follower.summary()
    fig.suptitle(
        f"trajgen follow --virtual: {s['accepted']} keyframes while moving, line to frame "
        f"p50 {1e3 * s['latency_s']['p50']:.0f} ms; torque check "
        f"{'OK' if report.ok else 'FAILED'}"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _joint_angle(quat, joint: int) -> float:
    """Joint angle (rad) of a keyframe orientation (pan, tilt, roll in (-pi, pi])."""
    from trajgen.gimbal import GimbalKinematics

    return float(GimbalKinematics().inverse(np.array([quat]))[0, joint])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="how long the target wanders")
    parser.add_argument("--out", type=Path, default=Path("out/follow_target.png"))
    options = parser.parse_args()
    args = build_parser().parse_args(["follow", str(HERE / "follow_target.toml"), "--virtual"])
    status, follower, report = follow(args, wandering_target(options.seconds))
    if report is not None:
        print(f"plot: {plot(follower, report, options.out)}")
        gap = Q.distance(forward(follower.trajectory().q[-1]), follower.keyframes[-1]["quat"])
        print(f"the stream ends {np.degrees(gap):.1e} deg from the last keyframe, at rest")
    return status


if __name__ == "__main__":
    raise SystemExit(main())
