"""Plot a torque report: joint angles, velocities and torque against the envelope."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trajgen.sim.model import JOINT_NAMES


def plot_report(report, path) -> Path:
    """Save a 4 x 3 figure (rows: angle, velocity, torque, envelope use; columns: joints).

    The torque row shows the planned torque (``mj_inverse``), the simulated
    actuator torque, and, where they fall inside the axis range, the envelope
    ``+-tau_stall (1 - |w| / w0)`` at the planned speed, full and times the
    margin. The last row shows the planned torque as a share of margin x
    envelope (%): the check fails above 100 %.

    Parameters
    ----------
    report : sim.check.TorqueReport
    path : str or Path
        Output image (the extension picks the format, e.g. ``.png``).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        If matplotlib cannot write that format.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    traj, rec = report.trajectory, report.record
    fig, axes = plt.subplots(4, 3, figsize=(13, 10), sharex=True)
    for j, name in enumerate(JOINT_NAMES):
        servo = report.config.servos[j]
        ax_q, ax_w, ax_t, ax_u = axes[:, j]
        ax_q.plot(traj.t, traj.q[:, j], label="planned")
        ax_q.plot(rec.t, rec.q[:, j], "--", label="simulated")
        ax_q.set_title(f"{name} ({servo.name})")
        ax_w.plot(traj.t, traj.qd[:, j], label="planned")
        ax_w.plot(rec.t, rec.qd[:, j], "--", label="simulated")
        envelope = servo.tau_max(traj.qd[:, j])
        for scale, style, label in ((1.0, "k:", "envelope"), (report.torque_margin, "r-", None)):
            label = label or f"{scale:g} x envelope"
            ax_t.plot(traj.t, scale * envelope, style, lw=1, label=label)
            ax_t.plot(traj.t, -scale * envelope, style, lw=1)
        tau = report.planned_torque_nm[:, j]
        ax_t.plot(rec.t, rec.torque_nm[:, j], color="tab:orange", lw=0.5, label="simulated")
        ax_t.plot(traj.t, tau, color="tab:blue", label="planned")
        lim = 1.2 * max(np.abs(tau).max(), np.abs(rec.torque_nm[:, j]).max(), 0.05)
        ax_t.set_ylim(-lim, lim)
        usable = report.torque_margin * envelope
        share = np.where(usable > 0, np.abs(tau) / np.where(usable > 0, usable, 1.0), np.inf)
        ax_u.plot(traj.t, 100.0 * np.minimum(share, 10.0), color="tab:blue")
        ax_u.axhline(100.0, color="r", lw=1)
        ax_u.set_xlabel("t (s)")
    axes[0, 0].set_ylabel("angle (rad)")
    axes[1, 0].set_ylabel("velocity (rad/s)")
    axes[2, 0].set_ylabel("torque (N m)")
    axes[3, 0].set_ylabel("planned / usable (%)")
    axes[0, 0].legend(fontsize=8)
    axes[2, 0].legend(fontsize=8)
    fig.suptitle(f"torque check: {'OK' if report.ok else 'FAILED'}")
    fig.tight_layout()
    path = Path(path)
    try:
        fig.savefig(path, dpi=100)
    finally:
        plt.close(fig)
    return path
