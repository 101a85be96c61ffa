"""The ``trajgen sweep`` command: the torque check over payloads, servos and speeds.

This module imports quickly: MuJoCo, matplotlib and Dask load inside :func:`run_sweep`.
"""

from __future__ import annotations

import argparse
from dataclasses import asdict

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    Progress,
    add_file_argument,
    add_json_argument,
    add_rate_argument,
    bad_input,
    check_output_path,
    check_plot_path,
    exit_status_text,
    load_checked,
    output_path,
    positive_int,
    prefix,
    tell,
    write_json,
)
from trajgen.cli.help_texts import SWEEP_DESCRIPTION
from trajgen.cli.sweep_options import (
    MAX_VARIANTS,
    masses,
    offset,
    scales,
    servo_choice,
    sweep_variants,
)
from trajgen.errors import TrajgenError


def register(subparsers) -> None:
    """Add the ``sweep`` subcommand to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "sweep",
        help="torque check over payloads, servos and speeds",
        description=SWEEP_DESCRIPTION,
        epilog=exit_status_text("a simulation failed (the table says which variants pass)"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_file_argument(p)
    p.add_argument(
        "--payload-kg", type=masses, metavar="M,M,...", help="payload masses (kg; 0: none)"
    )
    p.add_argument(
        "--offset-m",
        type=offset,
        action="append",
        metavar="X,Y,Z",
        help="payload centre of mass in the roll link frame (m); repeat for several",
    )
    p.add_argument(
        "--servo",
        type=servo_choice,
        action="append",
        metavar="JOINT=MODEL[,MODEL...]",
        help="servo models to try on a joint (by the file's joint names); repeat per joint",
    )
    p.add_argument(
        "--time-scale",
        type=scales,
        default=[0.5, 0.75, 1.0, 1.5],
        metavar="S,S,...",
        help="keyframe time multipliers (default 0.5,0.75,1,1.5)",
    )
    add_rate_argument(p)
    p.add_argument(
        "--threads",
        type=positive_int,
        default=2,
        metavar="N",
        help="rollout threads (default %(default)d)",
    )
    p.add_argument(
        "--max-variants",
        type=positive_int,
        default=MAX_VARIANTS,
        metavar="N",
        help=f"refuse sweeps of more than N variants (default {MAX_VARIANTS:,})",
    )
    p.add_argument(
        "--dask",
        metavar="ADDRESS",
        help='run on the Dask scheduler at ADDRESS ("local": start a local cluster); '
        "needs the dist extra",
    )
    p.add_argument("--plot", metavar="OUT.png", help="plot pass/fail and margin per variant")
    add_json_argument(p, "the results")
    p.set_defaults(func=run_sweep)


def _progress():
    """A ``(done, total)`` callback that drives the shared progress line."""
    line = Progress(f"{prefix()}: variants")
    return lambda done, total: line(done / total)


def run_sweep(args) -> int:
    """Run ``trajgen sweep``; returns the exit status."""
    from trajgen.sim import sweep
    from trajgen.sim.errors import SimError

    try:
        check_plot_path(args.plot, [args.file])
        check_output_path("--json", args.json, (".json",), [args.file])
        checked = load_checked(args.file, any_axes=True)  # every table of the file
        source, base = checked.keyframes, checked.gimbal
        variants = sweep_variants(args, source, base)
    except (ValueError, TypeError, OSError, ModuleNotFoundError) as e:
        return bad_input(e)  # every option and table, checked before any simulation
    seconds = float(source.times[-1] - source.times[0]) * sum(v.time_scale for v in variants)
    tell(f"{len(variants):,} variants, {seconds:,.1f} s of motion to simulate in all")
    try:
        if args.dask:
            results = _on_dask(args.dask, sweep, source, variants, base, args.rate)
        else:
            results = sweep.run_sweep(
                source,
                variants,
                config=base,
                rate_hz=args.rate,
                threads=args.threads,
                progress=_progress(),
            )
    except SimError as e:
        tell(f"simulation failed: {e}")
        return EXIT_FAILED
    except OSError as e:  # a Dask scheduler that cannot be reached
        if not args.dask:
            raise
        return bad_input(f"--dask {args.dask}: {e}")
    print(format_results(results, base.names))
    try:
        if args.plot:
            from trajgen.sim.sweep_plot import plot_sweep

            with output_path("--plot", args.plot) as tmp:
                plot_sweep(results, tmp, base.names)
            print(f"plot: {args.plot}")
        if args.json:
            write_json("--json", args.json, [asdict(r) for r in results])
            print(f"json: {args.json}")
    except (OSError, TrajgenError) as e:
        return bad_input(e)
    return EXIT_OK


def _on_dask(address, sweep, source, variants, base, rate):
    from contextlib import nullcontext

    from distributed import Client, LocalCluster

    local = address == "local"
    with LocalCluster(n_workers=2, threads_per_worker=1) if local else nullcontext() as cluster:
        with Client(cluster if local else address) as c:
            return sweep.sweep_on_dask(
                source, variants, c, config=base, rate_hz=rate, progress=_progress()
            )


def format_results(results, joints=("pan", "tilt", "roll")) -> str:
    """A table, one row per variant: payload, offset, servos (one per joint of ``joints``),
    time scale, verdict, margin."""
    servos = f"servos ({'/'.join(joints)})"
    lines = [
        f"{'payload':>8} {'offset (m)':<17} {servos:<34} {'scale':>6} "
        f"{'time s':>7} {'check':<6} {'worst margin':>13}  failed",
    ]
    for r in results:
        v = r.variant
        offset = ",".join(f"{o:g}" for o in v.payload_offset_m)
        lines.append(
            f"{v.payload_kg:8.3g} {offset:<17} {'/'.join(v.servos):<34} {v.time_scale:6.3g} "
            f"{r.duration_s:7.2f} {'ok' if r.ok else 'FAIL':<6} "
            f"{r.worst_margin_nm:8.3f} N m ({r.worst_joint}){'':1} {', '.join(r.failed)}"
        )
    passed = sum(r.ok for r in results)
    lines.append(f"{passed} of {len(results)} variants pass")
    return "\n".join(lines)
