"""Plot a torque report: joint angles, velocities, tracking error, torque, and how much
of the envelope is used."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: The use panel's logarithmic axis starts here (%): a joint at rest uses ~0 %.
USE_FLOOR_PCT = 0.1


def reversals(qd: np.ndarray) -> np.ndarray:
    """Indices where a joint speed changes sign, or leaves zero (where Coulomb friction steps).

    Parameters
    ----------
    qd : ndarray, shape (N,)
        Joint speed (rad/s).

    Returns
    -------
    ndarray of int
        Sample indices ``i`` with the step between samples ``i - 1`` and ``i``.
    """
    sign = np.sign(qd)
    return np.flatnonzero(sign[1:] != sign[:-1]) + 1


def envelope_use_pct(tau_nm: np.ndarray, usable_nm: np.ndarray) -> np.ndarray:
    """``|tau| / usable`` in percent; ``inf`` where nothing is usable (at or past no-load speed)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(usable_nm > 0, 100.0 * np.abs(tau_nm) / usable_nm, np.inf)


def period_mean_and_range(t, values, period_s):
    """Mean, min and max of ``values`` (K,) over consecutive windows of ``period_s``.

    Returns
    -------
    tuple of ndarray
        Window centres (s), mean, min, max; shape (W,) each.
    """
    t = np.asarray(t, dtype=float)
    window = np.floor((t - t[0]) / period_s + 1e-9).astype(int)
    starts = np.flatnonzero(np.diff(window, prepend=-1))
    count = np.diff(np.append(starts, len(t)))
    mean = np.add.reduceat(values, starts) / count
    return (
        t[starts] + 0.5 * period_s,
        mean,
        np.minimum.reduceat(values, starts),
        np.maximum.reduceat(values, starts),
    )


#: The tracking-error panel's logarithmic axis starts here (rad): below a tick's rounding.
ERROR_FLOOR_RAD = 1e-5
#: Smallest span of an angle (rad) or velocity (rad/s) axis: a joint that does not
#: move is drawn flat, not autoscaled to its rounding noise.
MIN_SPAN = {"angle": 0.02, "velocity": 0.02}

#: What each kind of reason in ``TorqueReport.reasons`` says failed (first match).
_CHECKS = (
    ("tracking error", "tracking error"),
    ("physics steps at the torque limit", "torque limit"),
    ("envelope", "planned torque"),
    ("no-load speed", "planned speed"),
    ("goal", "goal bounds"),
)


def failed_checks(report) -> str:
    """Which checks failed and on which joints, e.g. ``"tracking error (pan, tilt)"``."""
    failed: dict[str, list[str]] = {}
    for reason in report.reasons:
        joint, _, text = reason.partition(": ")
        check = next((name for key, name in _CHECKS if key in text), "other")
        failed.setdefault(check, [])
        if joint not in failed[check]:
            failed[check].append(joint)
    return "; ".join(f"{check} ({', '.join(joints)})" for check, joints in failed.items())


def _min_span(ax, span: float) -> None:
    """Widen ``ax``'s y range to at least ``span`` about its centre."""
    low, high = ax.get_ylim()
    if high - low < span:
        mid = 0.5 * (low + high)
        ax.set_ylim(mid - 0.5 * span, mid + 0.5 * span)


def plot_report(report, path) -> Path:
    """Save a 5 x n figure (rows: angle, velocity, tracking error, torque, envelope use;
    a column per joint).

    - angle: the plan, the goals sent (led ahead of the plan, ``trajgen.lead``)
      and the simulated angle; angle and velocity axes span at least
      ``MIN_SPAN``, so a joint that does not move is not autoscaled to noise.
    - tracking error: ``|simulated - plan|`` on a logarithmic axis with the
      check's limit; the title gives the peak and the lead used.

    - torque: the planned torque (``mj_inverse``) with its Coulomb-friction
      steps marked (the joint starts or reverses, so friction flips sign: a
      step of twice the friction whatever the plan), the plan without Coulomb
      friction dashed, and the simulated actuator torque as its mean over each
      stream period with the range within the period shaded (the zero-order
      hold's setpoint steps make the 1 ms torque ripple inside each period).
      The envelope ``tau_stall (1 - |w| / w0)``, clipped at 0, is drawn when it
      is within reach of the axis; otherwise the panel says how far off it is.
    - use: the planned and the simulated (period mean) torque as a share of
      margin x envelope, on a logarithmic axis with the 100 % limit labelled;
      the check fails above it. Speeds at or past no-load (no torque left) are
      shaded.

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
    import matplotlib.pyplot as plt

    fig = report_figure(report)
    path = Path(path)
    try:
        fig.savefig(path, dpi=100)
    finally:
        plt.close(fig)
    return path


def report_figure(report):
    """The figure :func:`plot_report` saves (a ``matplotlib.figure.Figure``; close it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    traj, rec = report.trajectory, report.record
    period = 1.0 / report.rate_hz
    margin = report.torque_margin
    names = report.config.names
    fig, axes = plt.subplots(5, len(names), figsize=(14 * len(names) / 3, 13.5), sharex=True)
    limit = report.max_tracking_error_rad
    goal = getattr(traj, "goal", None)
    for j, name in enumerate(names):
        servo = report.config.servos[j]
        ax_q, ax_w, ax_e, ax_t, ax_u = axes[:, j]
        ax_q.plot(traj.t, traj.q[:, j], label="planned")
        if goal is not None:
            ax_q.plot(
                traj.t, goal[:, j], ":", color="tab:green", label=f"goal sent ({report.lead})"
            )
        ax_q.plot(rec.t, rec.q[:, j], "--", label="simulated")
        ax_q.set_title(f"{name} ({servo.name})")
        _min_span(ax_q, MIN_SPAN["angle"])
        ax_w.plot(traj.t, traj.qd[:, j], label="planned")
        ax_w.plot(rec.t, rec.qd[:, j], "--", label="simulated")
        ax_w.axhline(0.0, color="0.6", lw=0.5)
        _min_span(ax_w, MIN_SPAN["velocity"])

        error = np.abs(rec.tracking_error_rad[:, j])
        top = 10 ** np.ceil(np.log10(max(2.0 * error.max(), 2.0 * limit)))
        ax_e.plot(rec.t, np.clip(error, ERROR_FLOOR_RAD, top), color="tab:purple", lw=0.8)
        ax_e.axhline(limit, color="r", lw=1)
        ax_e.text(
            traj.t[0], limit, f" {limit:g} rad: the limit", color="r", va="bottom", fontsize=8
        )
        ax_e.set_yscale("log")
        ax_e.set_ylim(ERROR_FLOOR_RAD, top)
        k = int(np.argmax(error))
        ax_e.set_title(
            f"tracking error: peak {1e3 * error[k]:.2f} mrad at t = {rec.t[k]:.2f} s "
            f"(lead {report.lead})",
            fontsize=9,
        )

        tau = report.planned_torque_nm[:, j]
        tc, sim_mean, sim_lo, sim_hi = period_mean_and_range(rec.t, rec.torque_nm[:, j], period)
        ax_t.fill_between(
            tc,
            sim_lo,
            sim_hi,
            color="tab:orange",
            alpha=0.25,
            lw=0,
            label="simulated, range within each period",
        )
        ax_t.plot(
            tc, sim_mean, color="tab:orange", lw=0.6, alpha=0.8, label="simulated, mean per period"
        )
        if report.planned_torque_smooth_nm is not None:
            ax_t.plot(
                traj.t,
                report.planned_torque_smooth_nm[:, j],
                "--",
                color="tab:blue",
                lw=0.8,
                label="planned without Coulomb friction",
            )
        ax_t.plot(traj.t, tau, color="tab:blue", lw=1.4, zorder=3, label="planned")
        steps = reversals(traj.qd[:, j])
        if len(steps):
            ax_t.plot(
                traj.t[steps],
                tau[steps],
                "v",
                color="tab:red",
                zorder=4,
                ms=5,
                ls="none",
                label="friction step: the joint starts or reverses, so Coulomb friction "
                "flips sign (a step of 2 x friction, not of the plan)",
            )
        peak = max(np.abs(tau).max(), np.abs(sim_hi).max(), np.abs(sim_lo).max(), 0.02)
        lim = 1.25 * peak
        envelope = np.maximum(servo.tau_max(traj.qd[:, j]), 0.0)
        if envelope.min() <= 3 * lim:
            for scale, style, label in (
                (1.0, "k:", "envelope"),
                (margin, "r-", f"{margin:g} x envelope"),
            ):
                ax_t.plot(traj.t, scale * envelope, style, lw=1, label=label)
                ax_t.plot(traj.t, -scale * envelope, style, lw=1)
            lim = max(lim, 1.05 * envelope.max())
        else:
            ax_t.text(
                0.99,
                0.97,
                f"envelope {envelope.min():.2g}..{envelope.max():.2g} N m: off this scale",
                transform=ax_t.transAxes,
                ha="right",
                va="top",
                fontsize=8,
                color="0.3",
            )
        ax_t.set_ylim(-lim, lim)

        usable = margin * servo.tau_max(traj.qd[:, j])
        use = envelope_use_pct(tau, usable)
        sim_usable = margin * servo.tau_max(np.interp(tc, rec.t, rec.qd[:, j]))
        sim_use = envelope_use_pct(sim_mean, sim_usable)
        finite = np.concatenate([use[np.isfinite(use)], sim_use[np.isfinite(sim_use)], [100.0]])
        top = 10 ** np.ceil(np.log10(max(2.0 * finite.max(), 200.0)))
        ax_u.plot(
            tc,
            np.clip(sim_use, USE_FLOOR_PCT, top),
            color="tab:orange",
            lw=0.6,
            alpha=0.8,
            label="use: simulated (period mean)",
        )
        ax_u.plot(
            traj.t,
            np.clip(use, USE_FLOOR_PCT, top),
            color="tab:blue",
            lw=1.4,
            zorder=3,
            label="use: planned",
        )
        ax_u.axhline(100.0, color="r", lw=1)
        ax_u.text(traj.t[0], 100.0, " 100 %: the limit", color="r", va="bottom", fontsize=8)
        no_torque = ~(usable > 0)
        if no_torque.any():
            ax_u.fill_between(
                traj.t,
                USE_FLOOR_PCT,
                top,
                where=no_torque,
                color="tab:red",
                alpha=0.15,
                lw=0,
                label="at or past no-load speed: no torque left",
            )
        worst = int(np.argmax(np.where(np.isfinite(use), use, -1.0)))
        title = f"planned peak {use[worst]:.3g} % at t = {traj.t[worst]:.2f} s"
        if no_torque.any():
            title += f"; past no-load speed from t = {traj.t[np.argmax(no_torque)]:.2f} s"
        ax_u.set_title(title, fontsize=9)
        ax_u.set_yscale("log")
        ax_u.set_ylim(USE_FLOOR_PCT, top)
        ax_u.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g} %"))
        ax_u.set_xlabel("t (s)")
    axes[0, 0].set_ylabel("angle (rad)")
    axes[1, 0].set_ylabel("velocity (rad/s)")
    axes[2, 0].set_ylabel("|simulated - plan| (rad)")
    axes[3, 0].set_ylabel("torque (N m)")
    axes[4, 0].set_ylabel(f"|torque| / ({margin:g} x envelope)")
    axes[0, 0].legend(fontsize=8)
    # One legend for the torque and use rows, below the figure, clear of the data.
    handles = {}
    for ax in axes[3:, :].flat:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=3, fontsize=8)
    verdict = "OK" if report.ok else f"FAILED: {failed_checks(report)}"
    fig.suptitle(
        f"torque check: {verdict}\n({report.duration_s:.2f} s at {report.rate_hz:g} Hz, "
        f"margin {margin:g} of the {report.envelope_volts} envelope, lead {report.lead})"
    )
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return fig
