"""Follow live keyframes: a wandering target, the plan changed while the gimbal moves.

A scripted target wanders in pan and tilt and changes its mind every 0.3-1 s.
Each time it does, the script hands one keyframe line to a
``trajgen.follower.Follower`` ("be where the target is 0.6 s from now", a
retarget), exactly as a tracker writes them to ``trajgen follow`` on stdin.
``Session.follow`` streams the follower's plan, here to the simulated gimbal
behind the virtual bus, and the torque report says what the servos made of it.
The stream runs on simulated time paced by the wall clock (in real time where
the host keeps up, slower where it does not, never late), and the target here
changes its mind on the stream's time: what the run does is the same on any
host, however busy.

Writes ``out/follow_target.png``: the commanded joint angles with every
keyframe drawn from the moment it arrived to the time it asked for, the joint
speeds, and the planned and simulated torque against the servo's envelope.

Run: .venv/bin/python examples/05_follow_target.py [--seconds 8] [--out out/follow_target.png]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from trajgen import load_keyframe_file, plan_joint_trajectory
from trajgen import quat as Q
from trajgen.drivers.config import bus_config_from_tables
from trajgen.drivers.session import Session
from trajgen.follower import Follower, load_compiled_kernel, online_spline
from trajgen.gimbal import forward
from trajgen.sim import GimbalPlant, gimbal_config_from_tables

HERE = Path(__file__).parent
LEAD_S = 0.6  # each keyframe asks to be there this long after it arrives


def wandering_target(seconds: float, seed: int = 7):
    """Lines of a target that changes its mind every 0.3-1 s of stream time, for
    ``seconds`` from 0.5 s into the stream: a function of the follower, whose stream
    time (the last frame streamed) says when each line is due."""
    rng = np.random.default_rng(seed)

    def lines(follower):
        pan, tilt, due = 0.0, 0.0, 0.5
        while True:
            due += rng.uniform(0.3, 1.0)
            if due > 0.5 + seconds:
                return
            while follower.spline.committed < due:  # the stream's time, not the wall's
                time.sleep(0.005)
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
            # A retarget that came before this keyframe's time dropped it.
            later = follower.keyframes[n + 1 :]
            dropped = any(k["mode"] == "retarget" and k["at"] < kf["t"] for k in later)
            kind = "dropped by a later line" if dropped else "keyframe"
            face = "white" if dropped else "tab:red"
            ax_q.plot([kf["now"], kf["t"]], [angle, angle], color="0.6", lw=0.8)
            ax_q.plot(kf["t"], angle, "o", ms=4, color="tab:red", mfc=face, label=kind)
            ax_q.plot(kf["now"], angle, "|", color="0.3", ms=8, label="arrived")
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
        handles, names = ax.get_legend_handles_labels()
        unique = dict(zip(names, handles, strict=True))  # one entry per kind
        ax.legend(unique.values(), unique.keys(), fontsize=8, loc=where)
    s = follower.summary()
    fig.suptitle(
        f"Session.follow, virtual bus: {s['accepted']} keyframes while moving, line to frame "
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
    parser.add_argument("--no-plot", action="store_true", help="skip the plot (and matplotlib)")
    options = parser.parse_args()

    keyframes = load_keyframe_file(HERE / "follow_target.toml")
    rate_hz = keyframes.stream_rate()
    follower = Follower(online_spline(keyframes), rate_hz, on_skip=print)
    load_compiled_kernel()  # where numba is installed: the spline's evaluations run compiled

    bus = bus_config_from_tables(keyframes.tables, keyframes.path)
    first = plan_joint_trajectory(keyframes.spline(), rate_hz).q[0]
    gimbal = gimbal_config_from_tables(keyframes.tables, keyframes.path)
    plant = GimbalPlant(gimbal, initial_rad=first)
    session = Session(bus, plant=plant, plant_registers=plant.initial_registers())
    outcome = session.follow(follower, wandering_target(options.seconds))
    print(follower.format())
    print(outcome.clock.format())  # how the simulation kept pace with the wall clock
    print(f"servos: {outcome.servo_states}  (stopped by: {outcome.stopped_by or 'the end'})")
    if not outcome.ok:
        return 1
    report = plant.report(outcome.trajectory)
    print(report.format())
    if not options.no_plot:
        print(f"plot: {plot(follower, report, options.out)}")
    if not follower.keyframes:
        print("no keyframe line was accepted (see the messages above)")
        return 1
    gap = Q.distance(forward(outcome.trajectory.q[-1]), follower.keyframes[-1]["quat"])
    print(f"the stream ends {np.degrees(gap):.1e} deg from the last keyframe, at rest")
    return 0 if report.ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
