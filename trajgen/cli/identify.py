"""The ``trajgen identify`` command: fit the simulated gimbal to logged telemetry.

This module imports quickly: MuJoCo and ``mujoco.sysid`` load inside :func:`run_identify`.
"""

from __future__ import annotations

import argparse
import re
import zipfile
from pathlib import Path

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    BadInput,
    bad_input,
    check_output_path,
    exit_status_text,
    load_checked,
    output_path,
    positive_int,
    tell,
)
from trajgen.cli.outputs import check_model_beside
from trajgen.errors import TrajgenError

DESCRIPTION = """\
Fit each joint's armature (kg m^2), Coulomb friction (N m), viscous damping (N
m s/rad) and Position P Gain (register units) of the simulated gimbal to
telemetry logged by `trajgen excite` (or `trajgen stream --telemetry`), with
mujoco.sysid (install the extra: pip install 'trajgen[sysid]'). FILE gives the
gimbal (its [gimbal] table: servos, payload) and the starting values. Prints
fit, 95 % interval and residual per joint and names every parameter the logs
do not excite enough; writes OUT.toml: FILE with its [gimbal.pan],
[gimbal.tilt], [gimbal.roll] tables replaced by the fit (intervals in
comments), ready for `trajgen sim OUT.toml` (written whole or not at all;
never over FILE or a log).

Each row's present values are taken --delay-ms after its goal (default 0: what
the servo had as the goal arrived, as the virtual bus logs it; on hardware the
read follows the write by about 1 ms); --fit-delay fits that delay too (after
a first fit with it held, as it trades against the lag of the P gain).

The logged current is fitted too, as torque over the torque constant (stall
torque / stall current); --fit-current-scale fits a factor between the two (a
real servo's reading needs one; it widens the intervals, as only the motor's
back-EMF then fixes the overall scale), --no-current fits positions and
velocities only."""

_ANY_HEADER = re.compile(r"^\s*\[")


def register(subparsers) -> None:
    """Add the ``identify`` subcommand to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "identify",
        help="fit the simulated gimbal's friction, inertia and gains to telemetry logs",
        description=DESCRIPTION,
        epilog=exit_status_text("the fit failed (it did not converge, or a log cannot be fitted)"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("file", metavar="FILE", help="keyframe file of the gimbal (TOML)")
    p.add_argument(
        "logs",
        metavar="LOG",
        nargs="+",
        help="telemetry logs (.csv, .npz or .mcap) of trajgen excite",
    )
    p.add_argument(
        "--out", metavar="OUT.toml", required=True, help="write the fitted file to OUT.toml"
    )
    p.add_argument("--no-current", action="store_true", help="do not fit the logged current")
    p.add_argument(
        "--p-scale",
        action="store_true",
        help="write the fitted loop gain as each servo's P scale (p_divisor; the e-Manual "
        "says 128, BAM measured 256 on an XL330) beside the P Gain register the file "
        "states, instead of as a P Gain; the led goals depend on it (docs/lead.md)",
    )
    p.add_argument(
        "--delay-ms",
        type=float,
        default=0.0,
        metavar="MS",
        help="time from a goal to its row's present values (ms) (default %(default)g)",
    )
    p.add_argument("--fit-delay", action="store_true", help="fit that delay too")
    p.add_argument(
        "--fit-current-scale",
        action="store_true",
        help="fit a scale between the logged current and torque / torque constant",
    )
    p.add_argument(
        "--max-iter",
        type=positive_int,
        default=30,
        metavar="N",
        help="Gauss-Newton iterations (default %(default)d)",
    )
    p.set_defaults(func=run_identify)


def fitted_file_text(source_text: str, tables: str, joints) -> str:
    """``source_text`` without its ``[gimbal.<joint>]`` tables, then ``tables``.

    Parameters
    ----------
    source_text : str
        A keyframe file's text.
    tables : str
        The fitted ``[gimbal.<joint>]`` tables (``Fit.toml``).
    joints : sequence of str
        The gimbal's joint names (``[gimbal] joints``).
    """
    names = "|".join(re.escape(j) for j in joints)
    header = re.compile(rf"^\s*\[\s*gimbal\s*\.\s*[\"']?({names})[\"']?\s*\]")
    kept, skipping = [], False
    for line in source_text.splitlines():
        if header.match(line):
            skipping = True
        elif _ANY_HEADER.match(line):
            skipping = False
        if not skipping:
            kept.append(line)
    return "\n".join(kept).rstrip() + "\n\n" + tables


def run_identify(args) -> int:
    """Run ``trajgen identify``; returns the exit status."""
    from trajgen.keyframes import load_keyframe_file, read_text
    from trajgen.sim.errors import SimError
    from trajgen.sim.identify import identify
    from trajgen.sim.model import gimbal_config_from_tables

    try:
        check_output_path("--out", args.out, (".toml",), [args.file, *args.logs])
        if not 0 <= args.delay_ms < 1000:
            raise BadInput(f"--delay-ms: expected 0 <= ms < 1000, got {args.delay_ms}")
        if args.fit_current_scale and args.no_current:
            raise BadInput("--fit-current-scale needs the current: drop --no-current")
        # every table, as every command checks them
        checked = load_checked(args.file, spline=False, any_axes=True)
        check_model_beside("--out", args.out, args.file, checked.keyframes.tables)
        config = checked.gimbal
        logs = [_load_log(path, config.names) for path in args.logs]
        source_text = read_text(args.file)
        fit = identify(
            config,
            logs,
            use_current=not args.no_current,
            delay_s=args.delay_ms / 1000.0,
            fit_delay=args.fit_delay,
            fit_current_scale=args.fit_current_scale,
            max_iter=args.max_iter,
            p_scale=args.p_scale,
        )
    except (ValueError, TypeError, OSError) as e:  # IdentifyError, KeyframeFileError
        return bad_input(e)
    except SimError as e:
        tell(f"identify failed: {e}")
        return EXIT_FAILED
    print(fit.format())
    sources = ", ".join(Path(p).name for p in args.logs)
    text = fitted_file_text(source_text, fit.toml(sources, p_scale=args.p_scale), config.names)
    try:
        with output_path("--out", args.out) as tmp:
            Path(tmp).write_text(text, encoding="utf-8")
            if Path(tmp).is_file():  # not a device (/dev/null), which cannot be read back
                # The result must load as the file it claims to be, before it replaces anything.
                fitted = load_keyframe_file(tmp)
                gimbal_config_from_tables(fitted.tables, fitted.path, any_axes=True)
    except (ValueError, OSError) as e:
        return bad_input(e)
    print(f"fitted: {args.out}")
    return EXIT_OK


def _load_log(path: str, joints):
    """A telemetry log of the gimbal's ``joints``, refused in one line naming it when it is
    missing, a folder or not a log."""
    from trajgen.sim.identify import IdentifyError, load_telemetry

    p = Path(path)
    if not p.exists():
        raise BadInput(f"{path}: no such telemetry log")
    if p.is_dir():
        raise BadInput(f"{path}: is a directory, not a telemetry log")
    if p.stat().st_size == 0:
        raise BadInput(f"{path}: empty telemetry log (a log of trajgen excite has a header row)")
    try:
        return load_telemetry(p, joints)
    except UnicodeDecodeError:
        raise BadInput(f"{path}: not a telemetry log (not UTF-8 text)") from None
    except (TrajgenError, IdentifyError):
        raise  # names the file already
    except (KeyError, IndexError, ValueError, zipfile.BadZipFile) as e:
        raise BadInput(f"{path}: not a telemetry log of trajgen excite ({e})") from None
