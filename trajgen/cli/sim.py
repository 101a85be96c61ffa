"""The ``trajgen sim`` command: run a keyframe file through the simulated gimbal.

Without a file it runs trajgen's built-in look-around example.

This module imports quickly: MuJoCo and matplotlib load inside :func:`run_sim`.
"""

from __future__ import annotations

import ctypes
import sys

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    Progress,
    add_file_argument,
    add_json_argument,
    add_lead_argument,
    add_rate_argument,
    bad_input,
    check_module,
    check_output_path,
    check_plot_path,
    check_timing,
    exit_status_text,
    from_ctrl_c,
    load_checked,
    output_path,
    tell,
    write_json,
)
from trajgen.errors import TrajgenError

DESCRIPTION = """\
Plan the joint stream of a keyframe file, play it to a simulated gimbal of
Dynamixel servos (MuJoCo, 1 ms physics; goal positions in whole ticks
held for one stream period, followed by each servo's own firmware position
loop) and check torque: the planned torque (inverse dynamics) must stay within
torque_margin x the rated-voltage torque-speed envelope tau_stall (1 - |w| / w0), no
simulated step may reach the servo's torque limit, and the tracking error must stay
below the limit (with default gains a servo lags its goal by about speed x
45 ms, so each goal is sent ahead of the plan: --lead, [stream] lead, default
model; the error is against the plan, docs/lead.md). The file's [gimbal]
table picks the axes and joint names (axes = "zy", joints = [...]; default
pan-tilt-roll, docs/gimbals.md), the servos (servo = "XM430-W350" for every
joint), your own MJCF or URDF model (model = "my_gimbal.xml", its hinge joints
named by joints; docs/simulation.md), payload_kg, payload_offset_m,
torque_margin, max_tracking_error_rad and p_divisor; [gimbal.<joint>] sets that
joint's servo, armature, frictionloss, damping and position_p_gain (trajgen
identify fits them).

Units: keyframe angles in degrees (file), the report in SI units (rad, rad/s,
N m, s) with the unit in every --json key."""


def register(subparsers) -> None:
    """Add the ``sim`` subcommand to an argparse ``subparsers`` object."""
    import argparse

    p = subparsers.add_parser(
        "sim",
        help="check a keyframe file's torque on a simulated gimbal",
        description=DESCRIPTION,
        epilog=exit_status_text(
            "the torque check failed (planned torque beyond torque_margin x the envelope, a "
            "simulated step at the torque limit, tracking beyond its limit), a [limits] "
            "check failed, or the simulation failed"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_file_argument(p)
    add_rate_argument(p)
    add_lead_argument(p)
    add_json_argument(p, "the report (on Ctrl-C: what was done so far)")
    p.add_argument(
        "--plot",
        metavar="OUT.png",
        help="plot joint angles, velocities, torque and envelope use to OUT.png (.pdf, .svg)",
    )
    p.add_argument(
        "--video",
        metavar="OUT.mp4",
        help="render the simulated motion to OUT.mp4 (offscreen; needs imageio-ffmpeg)",
    )
    p.set_defaults(func=run_sim)


def check_sim_arguments(args) -> None:
    """Refuse unusable output options before anything is planned or simulated.

    Raises
    ------
    BadInput
        Naming the option.
    """
    inputs = [args.file]
    check_output_path("--json", args.json, (".json",), inputs)
    check_plot_path(args.plot, inputs)
    check_output_path("--video", args.video, (".mp4",), inputs)
    if args.video:
        check_module("--video", "imageio_ffmpeg", "imageio-ffmpeg")


def run_sim(args) -> int:
    """Run ``trajgen sim``; returns the exit status (0 ok, 1 check failed, 2 bad input,
    130 interrupted)."""
    progress = Progress("trajgen sim: simulating")
    done = {"stage": "checking the file", "file": str(args.file)}
    try:
        check_sim_arguments(args)
        return _run(args, progress, done)
    except TrajgenError as e:
        return bad_input(e)
    except (KeyboardInterrupt, ctypes.ArgumentError) as e:
        if not from_ctrl_c(e):
            raise
        print("", file=sys.stderr)
        tell("interrupted")
        if args.json:
            done["simulated_fraction"] = round(progress.fraction, 4)
            try:
                _write_json(args.json, {"ok": None, "interrupted": True, **done})
            except TrajgenError as e:
                bad_input(e)
        return EXIT_INTERRUPTED


def _write_json(path: str, data: dict) -> None:
    write_json("--json", path, data)
    print(f"json: {path}")


def _held_joints(config) -> tuple[str, ...]:
    """The joints of a user's model the gimbal does not name (``sim.user_model``)."""
    if config.model is None:
        return ()
    from trajgen.sim.user_model import held_joints

    return held_joints(config)


def _run(args, progress: Progress, done: dict) -> int:
    from trajgen.sim.check import check_torque
    from trajgen.sim.errors import SimError

    checked = load_checked(args.file, any_axes=True)
    kf = checked.keyframes
    rate = kf.stream_rate(args.rate)
    check_timing(kf, rate)
    # The simulation's own samples: one per physics step.
    check_timing(kf, 1.0 / checked.gimbal.timestep_s)
    done.update(stage="simulating", rate_hz=rate, duration_s=float(kf.times[-1] - kf.times[0]))
    try:
        report = check_torque(
            kf,
            rate_hz=rate,
            config=checked.gimbal,
            progress=progress,
            lead=getattr(args, "lead", None),
        )
    except SimError as e:
        tell(f"simulation failed: {e}")
        return EXIT_FAILED
    from trajgen.sim.limits import check_limits

    limit_reasons = check_limits(report.trajectory, checked.limits)
    summary = {**report.to_json_dict(), "limits_ok": not limit_reasons}
    summary["limit_reasons"] = list(limit_reasons)
    held = _held_joints(checked.gimbal)
    if held:
        summary["held_joints"] = list(held)
    done.update(stage="writing outputs", report=summary)
    print(report.format())
    for joint in held:
        print(
            f"held: joint '{joint}' (not in [gimbal] joints) is welded at its reference pose, "
            "where the model draws it"
        )
    if "limits" in kf.tables:
        print(f"[limits]: {'FAILED' if limit_reasons else 'OK'}")
        print("\n".join(f"  - {r}" for r in limit_reasons), end="\n" if limit_reasons else "")
    if args.json:
        _write_json(args.json, summary)
    if args.plot:
        from trajgen.sim.plot import plot_report

        with output_path("--plot", args.plot) as tmp:
            plot_report(report, tmp)
        print(f"plot: {args.plot}")
    if args.video:
        from trajgen.sim.video import render_video

        with output_path("--video", args.video) as tmp:
            render_video(report.record, tmp, report.config)
        print(f"video: {args.video}")
    return EXIT_OK if report.ok and not limit_reasons else EXIT_FAILED
