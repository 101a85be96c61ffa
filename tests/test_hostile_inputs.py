"""Every bad input we tried on the command line, with the exit status and message it gets.

Each row is ``(name, argv, file, status, message, before)``:

- ``argv``: the command line after ``trajgen``; ``{file}`` is the keyframe
  file written from ``file`` (TOML text), ``{tmp}`` a fresh empty folder;
- ``status``: 2 bad input (one line on stderr naming the option or the
  file/keyframe/field, no traceback), 1 a failed check, 0 accepted;
- ``message``: a regular expression the output must match;
- ``before``: what the same input did before the issue that fixed it (issue 8,
  or issue 20 for the rows under its headings), on the earlier command line:
  ``"ok"`` (already a clear refusal), ``"crash"`` (a traceback), ``"silent"``
  (accepted, or refused only after planning, simulating or streaming, or a wrong
  result), ``"hang"`` (no answer in 90 s, or growing without bound),
  ``"wrong"`` (a valid input refused), ``"unclear"`` (exit 2 but more than one
  line, or a message that did not name the option), ``"new"`` (an option or
  table that did not exist then).

Every row runs in-process through :func:`trajgen.cli.main`; nothing here
touches a serial port (``stream`` refuses before opening one).
"""

from __future__ import annotations

import json
import os
import re

import pytest

from trajgen.cli import main

#: Every subcommand: its errors start "trajgen <command>:".
COMMANDS = ("plan", "sim", "fit", "sweep", "stream", "follow", "scan", "virtual-bus", "excite")
COMMANDS += ("identify",)

# Three keyframes, 2 s apart: a gentle pan and tilt.
KEYS = """
[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 2.0
pan = 30.0
tilt = 10.0

[[keyframes]]
t = 4.0
pan = 0.0
"""
GOOD = KEYS


def keys(*rows: str) -> str:
    """``[[keyframes]]`` tables from rows of ``key = value`` lines separated by ';'."""
    return "".join("\n[[keyframes]]\n" + row.replace(";", "\n") + "\n" for row in rows)


#: Two keyframes 1 s apart: 10 deg of pan.
PAN_10 = keys("t = 0;pan = 0", "t = 1;pan = 10")


def closed(local: str = "auto") -> str:
    return f'[spline]\nboundary = "closed"\nlocal = "{local}"\n' + keys(
        "t = 0;pan = 0", "t = 1;pan = 30", "t = 2;pan = 0;tilt = 20", "t = 3;pan = 0"
    )


CASES = [
    # --- the command line itself -----------------------------------------------
    (
        "no command",
        [],
        None,
        2,
        r"trajgen: error: the following arguments are required: COMMAND",
        "unclear",
    ),
    ("unknown command", ["fly"], None, 2, r"invalid choice: 'fly'", "unclear"),
    (
        "plan --rate 0",
        ["plan", "--rate", "0"],
        None,
        2,
        r"argument --rate: expected a number > 0, got '0'",
        "unclear",
    ),
    (
        "plan --rate -5",
        ["plan", "--rate=-5"],
        None,
        2,
        r"argument --rate: expected a number > 0",
        "unclear",
    ),
    (
        "plan --rate nan",
        ["plan", "--rate", "nan"],
        None,
        2,
        r"argument --rate: expected a number > 0",
        "unclear",
    ),
    (
        "plan --rate inf",
        ["plan", "--rate", "inf"],
        None,
        2,
        r"argument --rate: expected a number > 0",
        "unclear",
    ),
    (
        "plan --rate abc",
        ["plan", "--rate", "abc"],
        None,
        2,
        r"argument --rate: expected a number, got 'abc'",
        "unclear",
    ),
    (
        "plan --rate 1e9",
        ["plan", "--rate", "1e9"],
        None,
        2,
        r"8 s at 1e\+09 Hz is 8e\+09 samples, over the limit of 5,000,000",
        "crash",
    ),
    (
        "plan --rate 1e-9",
        ["plan", "--rate", "1e-9"],
        None,
        2,
        r"keyframes 1 and 2: 1.5 s apart, less than one sample period",
        "silent",
    ),
    (
        "plan --max-samples 0",
        ["plan", "--max-samples", "0"],
        None,
        2,
        r"argument --max-samples: expected a whole number >= 2",
        "new",
    ),
    (
        "plan --max-samples 1.5",
        ["plan", "--max-samples", "1.5"],
        None,
        2,
        r"argument --max-samples: expected a whole number >= 2",
        "new",
    ),
    (
        "plan --max-samples too few",
        ["plan", "--max-samples", "100"],
        None,
        2,
        r"is 1601 samples, over the limit of 100 .*; --max-samples N raises the limit",
        "new",
    ),
    (
        "plan --out no folder",
        ["plan", "--out", "{tmp}/no/such/p.csv"],
        None,
        2,
        r"--out '.*/no/such/p.csv': no such folder",
        "crash",
    ),
    (
        "plan --out a folder",
        ["plan", "--out", "{tmp}"],
        None,
        2,
        r"--out '.*': is a directory; give a file name",
        "crash",
    ),
    ("plan --out ''", ["plan", "--out", ""], None, 2, r"--out '': an empty name", "silent"),
    # --- the keyframe file as a file -------------------------------------------
    ("file missing", ["plan", "{tmp}/missing.toml"], None, 2, r"missing.toml: no such file", "ok"),
    (
        "file is a folder",
        ["plan", "{tmp}"],
        None,
        2,
        r": is a directory, not a keyframe file",
        "ok",
    ),
    (
        "file empty",
        ["plan", "{file}"],
        "",
        2,
        r"no \[\[keyframes\]\] \(at least 2 are needed\)",
        "ok",
    ),
    ("file not TOML", ["plan", "{file}"], "t = = 1\n", 2, r"invalid TOML", "ok"),
    (
        "file binary",
        ["plan", "{file}"],
        b"\xff\xfe\x00\x01",
        2,
        r"keys.toml: binary data \(a NUL byte\), not a TOML text file",
        "ok",
    ),
    (
        "unknown table",
        ["plan", "{file}"],
        "[camera]\nfov = 60\n" + KEYS,
        2,
        r"keys.toml: unknown table 'camera' \(known: spline, keyframes, stream, gimbal, bus",
        "ok",
    ),
    # --- [spline] ----------------------------------------------------------------
    (
        "k = 0",
        ["plan", "{file}"],
        "[spline]\nk = 0\n" + KEYS,
        2,
        r"\[spline\] k: expected an integer in 1\.\.6, got 0",
        "ok",
    ),
    (
        "k = 7",
        ["plan", "{file}"],
        "[spline]\nk = 7\n" + KEYS,
        2,
        r"\[spline\] k: expected an integer in 1\.\.6, got 7",
        "silent",
    ),
    (
        "k = 30",
        ["plan", "{file}"],
        "[spline]\nk = 30\n" + KEYS,
        2,
        r"\[spline\] k: expected an integer in 1\.\.6, got 30",
        "silent",
    ),
    (
        "k = 1000",
        ["plan", "{file}"],
        "[spline]\nk = 1000\n" + KEYS,
        2,
        r"\[spline\] k: expected an integer in 1\.\.6, got 1000",
        "crash",
    ),
    (
        "k = 2.5",
        ["plan", "{file}"],
        "[spline]\nk = 2.5\n" + KEYS,
        2,
        r"\[spline\] k: expected an integer in 1\.\.6, got 2.5",
        "ok",
    ),
    (
        "k = true",
        ["plan", "{file}"],
        "[spline]\nk = true\n" + KEYS,
        2,
        r"\[spline\] k: expected an integer in 1\.\.6, got True",
        "ok",
    ),
    (
        "boundary unknown",
        ["plan", "{file}"],
        '[spline]\nboundary = "free"\n' + KEYS,
        2,
        r"\[spline\] boundary: expected one of rest, natural, closed, got 'free'",
        "ok",
    ),
    (
        "local not a string",
        ["plan", "{file}"],
        "[spline]\nlocal = 3\n" + KEYS,
        2,
        r"\[spline\] local: expected one of auto, circle, parabola, got 3",
        "ok",
    ),
    (
        "reparam unknown",
        ["plan", "{file}"],
        '[spline]\nreparam = "cubic"\n' + KEYS,
        2,
        r"\[spline\] reparam: expected one of paper, rational",
        "ok",
    ),
    (
        "spline unknown key",
        ["plan", "{file}"],
        "[spline]\norder = 2\n" + KEYS,
        2,
        r"\[spline\]: unknown key 'order' \(known: method, k, boundary",
        "ok",
    ),
    (
        "spline not a table",
        ["plan", "{file}"],
        "spline = 2\n" + KEYS,
        2,
        r"\[spline\] must be a table, got 2",
        "ok",
    ),
    (
        "closed loop not closed",
        ["plan", "{file}"],
        '[spline]\nboundary = "closed"\n'
        + keys("t = 0;pan = 0", "t = 1;pan = 30", "t = 2;pan = 9"),
        2,
        r"needs the last keyframe to repeat the first; they are 9 deg apart",
        "ok",
    ),
    (
        "closed with 2 keyframes",
        ["plan", "{file}"],
        '[spline]\nboundary = "closed"\n' + keys("t = 0;pan = 0", "t = 1;pan = 0"),
        2,
        r"A closed spline needs at least 3 keyframes, got 2",
        "ok",
    ),
    (
        "circle through a reversal",
        ["plan", "{file}"],
        '[spline]\nlocal = "circle"\n' + keys("t = 0;pan = 0", "t = 1;pan = 30", "t = 2;pan = 0"),
        2,
        r"no circle passes through them; use local='auto' or 'parabola'",
        "ok",
    ),
    (
        "closed loop plans to t_end",
        ["plan", "{file}"],
        closed(),
        0,
        r"planned .*: 601 samples at 200 Hz over 3\.000 s",
        "silent",
    ),
    # --- [stream] ------------------------------------------------------------------
    (
        "rate_hz = 0",
        ["plan", "{file}"],
        "[stream]\nrate_hz = 0\n" + KEYS,
        2,
        r"\[stream\] rate_hz: expected a finite number > 0, got 0",
        "ok",
    ),
    (
        "rate_hz string",
        ["plan", "{file}"],
        '[stream]\nrate_hz = "fast"\n' + KEYS,
        2,
        r"\[stream\] rate_hz: expected a finite number > 0, got 'fast'",
        "ok",
    ),
    (
        "rate_hz inf",
        ["plan", "{file}"],
        "[stream]\nrate_hz = inf\n" + KEYS,
        2,
        r"\[stream\] rate_hz: expected a finite number > 0, got inf",
        "ok",
    ),
    (
        "rate_hz 1e9",
        ["plan", "{file}"],
        "[stream]\nrate_hz = 1e9\n" + KEYS,
        2,
        r"is 4e\+09 samples, over the limit",
        "crash",
    ),
    (
        "stream unknown key",
        ["plan", "{file}"],
        "[stream]\nrate = 100\n" + KEYS,
        2,
        r"\[stream\]: unknown key 'rate' \(known: rate_hz, lead, run_in_s\)",
        "ok",
    ),
    (
        "stream not a table",
        ["plan", "{file}"],
        "stream = 100\n" + KEYS,
        2,
        r"\[stream\] must be a table, got 100",
        "ok",
    ),
    ("one default rate", ["plan", "{file}"], KEYS, 0, r"801 samples at 200 Hz", "silent"),
    # --- [[keyframes]] -------------------------------------------------------------
    (
        "no keyframes",
        ["plan", "{file}"],
        "[spline]\nk = 2\n",
        2,
        r"no \[\[keyframes\]\] \(at least 2 are needed\)",
        "ok",
    ),
    (
        "one keyframe",
        ["plan", "{file}"],
        keys("t = 0;pan = 0"),
        2,
        r"\[\[keyframes\]\]: at least 2 are needed, got 1",
        "ok",
    ),
    (
        "keyframes not tables",
        ["plan", "{file}"],
        "keyframes = 5\n",
        2,
        r"keyframes: expected a list of tables, each starting with a line \[\[keyframes\]\] "
        r"\(two brackets\), got 5",
        "ok",
    ),
    (
        "keyframe not a table",
        ["plan", "{file}"],
        "keyframes = [1, 2]\n",
        2,
        r"keyframe 1: expected a table, got 1",
        "ok",
    ),
    (
        "t missing",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "pan = 10"),
        2,
        r"keyframe 2: field 't' is missing \(seconds\)",
        "ok",
    ),
    (
        "t string",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", 't = "1s";pan = 10'),
        2,
        r"keyframe 2: field 't': expected a finite number, got '1s'",
        "ok",
    ),
    (
        "t nan",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = nan;pan = 10"),
        2,
        r"keyframe 2: field 't': expected a finite number, got nan",
        "ok",
    ),
    (
        "t inf",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = inf;pan = 10"),
        2,
        r"keyframe 2: field 't': expected a finite number, got inf",
        "ok",
    ),
    (
        "t boolean",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = true;pan = 10"),
        2,
        r"keyframe 2: field 't': expected a finite number, got True",
        "ok",
    ),
    (
        "t = 1e308",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1e308;pan = 10"),
        2,
        r"1e\+308 s at 200 Hz is more than 1e300 samples, over the limit",
        "crash",
    ),
    (
        "t = -1e308 .. 1e308",
        ["plan", "{file}"],
        keys("t = -1e308;pan = 0", "t = 1e308;pan = 10"),
        2,
        r"keyframes 1 to 2: field 't': the times span more than 1e308 s",
        "crash",
    ),
    (
        "1e6 s apart at 1 kHz",
        ["plan", "{file}", "--rate", "1000"],
        keys("t = 0;pan = 0", "t = 1e6;pan = 10"),
        2,
        r"1e\+06 s at 1000 Hz is 1e\+09 samples, over the limit of 5,000,000",
        "crash",
    ),
    (
        "times equal",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 0;pan = 10"),
        2,
        r"keyframe 2: field 't': 0 s is not after keyframe 1's 0 s",
        "ok",
    ),
    (
        "times decreasing",
        ["plan", "{file}"],
        keys("t = 1;pan = 0", "t = 0.5;pan = 10"),
        2,
        r"keyframe 2: field 't': 0.5 s is not after keyframe 1's 1 s",
        "ok",
    ),
    (
        "keyframes 1 ns apart",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1e-9;pan = 90"),
        2,
        r"keyframes 1 and 2: 1e-09 s apart, less than one sample period \(0.005 s at 200 Hz\)",
        "silent",
    ),
    (
        "keyframes 1 ms apart",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1;pan = 10", "t = 1.001;pan = 90", "t = 2;pan = 0"),
        2,
        r"keyframes 2 and 3: 0.001 s apart, less than one sample period",
        "silent",
    ),
    (
        "90 deg in 20 ms: a clear warning",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 0.02;pan = 90"),
        0,
        r"warning: peak \|omega\| .* rad/s is beyond the no-load speed of every supported servo",
        "silent",
    ),
    (
        "unknown field",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1;yaw = 10"),
        2,
        r"keyframe 2: unknown field 'yaw' \(known: t, pan, tilt, roll, quat\)",
        "ok",
    ),
    (
        "pan string",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", 't = 1;pan = "ten"'),
        2,
        r"keyframe 2: field 'pan': expected a finite number, got 'ten'",
        "ok",
    ),
    (
        "pan nan",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1;pan = nan"),
        2,
        r"keyframe 2: field 'pan': expected a finite number, got nan",
        "ok",
    ),
    (
        "no orientation",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1"),
        2,
        r"keyframe 2: no orientation: give 'quat' or pan/tilt/roll",
        "ok",
    ),
    (
        "quat and pan",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1;pan = 3;quat = [1, 0, 0, 0]"),
        2,
        r"keyframe 2: give either 'quat' or pan/tilt/roll, not both",
        "ok",
    ),
    (
        "quat of 3",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1;quat = [1, 0, 0]"),
        2,
        r"keyframe 2: field 'quat': expected \[w, x, y, z\], got \[1, 0, 0\]",
        "ok",
    ),
    (
        "quat zero",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1;quat = [0, 0, 0, 0]"),
        2,
        r"keyframe 2: field 'quat': zero quaternion",
        "ok",
    ),
    (
        "quat strings",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", 't = 1;quat = ["1", 0, 0, 0]'),
        2,
        r"keyframe 2: field 'quat': expected a finite number, got '1'",
        "ok",
    ),
    (
        "quat not a list",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 1;quat = 1"),
        2,
        r"keyframe 2: field 'quat': expected \[w, x, y, z\], got 1",
        "ok",
    ),
    # --- [gimbal], checked by every command ----------------------------------------
    (
        "plan: gimbal servo unknown",
        ["plan", "{file}"],
        '[gimbal]\nservo = "XM999"\n' + KEYS,
        2,
        r"\[gimbal\] servo: unknown model 'XM999'",
        "silent",
    ),
    (
        "plan: gimbal payload negative",
        ["plan", "{file}"],
        "[gimbal]\npayload_kg = -1\n" + KEYS,
        2,
        r"\[gimbal\] payload_kg: expected a finite number in 0..100, got -1",
        "silent",
    ),
    (
        "plan: gimbal margin 2",
        ["plan", "{file}"],
        "[gimbal]\ntorque_margin = 2\n" + KEYS,
        2,
        r"\[gimbal\] torque_margin: expected a finite number in \(0, 1\], got 2",
        "silent",
    ),
    (
        "plan: gimbal unknown key",
        ["plan", "{file}"],
        "[gimbal]\nmass = 1\n" + KEYS,
        2,
        r"\[gimbal\]: unknown key 'mass'",
        "silent",
    ),
    (
        "plan: gimbal not a table",
        ["plan", "{file}"],
        "gimbal = 1\n" + KEYS,
        2,
        r"\[gimbal\]: expected a table, got 1",
        "silent",
    ),
    (
        "plan: gimbal offset of 2",
        ["plan", "{file}"],
        "[gimbal]\npayload_offset_m = [0, 0]\n" + KEYS,
        2,
        r"\[gimbal\] payload_offset_m: expected a list of 3 numbers, got \[0, 0\]",
        "silent",
    ),
    (
        "sim: gimbal servo per joint unknown",
        ["sim", "{file}"],
        '[gimbal]\nservo = {yaw = "XM430-W350"}\n' + KEYS,
        2,
        r"\[gimbal\] servo: unknown joint 'yaw' \(known: pan, tilt, roll\)",
        "ok",
    ),
    (
        "stream: lower-case servo name",
        ["stream", "{file}", "--port", "{tmp}/no-port"],
        '[gimbal]\nservo = "xm430-w350"\n' + KEYS,
        2,
        r"no-port",
        "wrong",
    ),
    # --- [bus], checked by every command --------------------------------------------
    (
        "plan: bus baud 123",
        ["plan", "{file}"],
        "[bus]\nbaud = 123\n" + KEYS,
        2,
        r"\[bus\] baud: expected one of 9600, 57600, 115200, 1000000, .*, 4500000, got 123",
        "silent",
    ),
    (
        "plan: bus baud string",
        ["plan", "{file}"],
        '[bus]\nbaud = "fast"\n' + KEYS,
        2,
        r"\[bus\] baud: expected an integer, got 'fast'",
        "silent",
    ),
    (
        "plan: bus ids repeated",
        ["plan", "{file}"],
        "[bus]\nids = [1, 1, 2]\n" + KEYS,
        2,
        r"\[bus\] ids: expected 3 distinct ids, got \[1, 1, 2\]",
        "silent",
    ),
    (
        "plan: bus id 300",
        ["plan", "{file}"],
        "[bus]\nids = [1, 2, 300]\n" + KEYS,
        2,
        r"\[bus\] ids: expected an integer in 0\.\.252, got 300 in \[1, 2, 300\]",
        "silent",
    ),
    (
        "plan: bus directions 0",
        ["plan", "{file}"],
        "[bus]\ndirections = [1, 0, 1]\n" + KEYS,
        2,
        r"\[bus\] directions: expected \+1 or -1 each, got \[1, 0, 1\]",
        "silent",
    ),
    (
        "plan: bus zero tick 5000",
        ["plan", "{file}"],
        "[bus]\nzeros = [2048, 2048, 5000]\n" + KEYS,
        2,
        r"\[bus\] zeros: expected an integer in 0\.\.4095, got 5000",
        "silent",
    ),
    (
        "plan: bus model unknown",
        ["plan", "{file}"],
        '[bus]\nmodels = "MX-28"\n' + KEYS,
        2,
        r"\[bus\] models: unknown model 'MX-28'",
        "silent",
    ),
    (
        "plan: bus watchdog 5 s",
        ["plan", "{file}"],
        "[bus]\nwatchdog_s = 5\n" + KEYS,
        2,
        r"\[bus\] watchdog_s: expected a finite number in 0\.02\.\.2\.54, got 5",
        "silent",
    ),
    (
        "plan: bus port a number",
        ["plan", "{file}"],
        "[bus]\nport = 3\n" + KEYS,
        2,
        r"\[bus\] port: expected a device path string, got 3",
        "silent",
    ),
    (
        "plan: bus unknown key",
        ["plan", "{file}"],
        "[bus]\nspeed = 3\n" + KEYS,
        2,
        r"\[bus\]: unknown key 'speed' \(known: port, baud",
        "silent",
    ),
    (
        "stream: bus baud 123",
        ["stream", "{file}", "--virtual"],
        "[bus]\nbaud = 123\n" + KEYS,
        2,
        r"\[bus\] baud: expected one of 9600",
        "silent",
    ),
    (
        "plan: limits unknown key",
        ["plan", "{file}"],
        "[limits]\nspeed = 1\n" + KEYS,
        2,
        r"\[limits\]: unknown key 'speed'",
        "new",
    ),
    (
        "plan: limits speed negative",
        ["plan", "{file}"],
        "[limits]\nspeed_rad_s = -1\n" + KEYS,
        2,
        r"\[limits\] speed_rad_s: expected a number > 0",
        "new",
    ),
    # --- sim ------------------------------------------------------------------------
    (
        "sim --rate 0",
        ["sim", "--rate", "0"],
        None,
        2,
        r"argument --rate: expected a number > 0",
        "unclear",
    ),
    (
        "sim --json no folder",
        ["sim", "--json", "{tmp}/no/r.json"],
        None,
        2,
        r"--json '.*/no/r.json': no such folder",
        "silent",
    ),
    (
        "sim --json a folder",
        ["sim", "--json", "{tmp}"],
        None,
        2,
        r"--json '.*': is a directory",
        "silent",
    ),
    (
        "sim --plot no folder",
        ["sim", "--plot", "{tmp}/no/p.png"],
        None,
        2,
        r"--plot '.*/no/p.png': no such folder",
        "silent",
    ),
    (
        "sim --plot .txt",
        ["sim", "--plot", "{tmp}/p.txt"],
        None,
        2,
        r"--plot '.*p.txt': expected a \.png or \.pdf or \.svg or \.jpg or \.jpeg file",
        "silent",
    ),
    (
        "sim --video .avi",
        ["sim", "--video", "{tmp}/v.avi"],
        None,
        2,
        r"--video '.*v.avi': expected a \.mp4 file",
        "silent",
    ),
    ("sim --rate 1e9", ["sim", "--rate", "1e9"], None, 2, r"over the limit of 5,000,000", "crash"),
    (
        "sim: 1e6 s of motion",
        ["sim", "{file}"],
        keys("t = 0;pan = 0", "t = 1e6;pan = 10"),
        2,
        r"1e\+06 s at 200 Hz is 2e\+08 samples, over the limit",
        "hang",
    ),
    (
        "sim: keyframes 1 ns apart",
        ["sim", "{file}"],
        keys("t = 0;pan = 0", "t = 1e-9;pan = 90"),
        2,
        r"keyframes 1 and 2: 1e-09 s apart",
        "silent",
    ),
    (
        "sim: too fast is a clear failed check",
        ["sim", "{file}"],
        keys("t = 0;pan = 0", "t = 0.3;pan = 90"),
        1,
        r"torque check: FAILED[\s\S]*pan: planned speed .* exceeds the XM430-W350's no-load speed",
        "ok",
    ),
    # --- commands added since: fit, sweep -----------------------------------------------
    (
        "fit --out no folder",
        ["fit", "--out", "{tmp}/no/f.toml"],
        None,
        2,
        r"--out '.*/no/f.toml': no such folder",
        "new",
    ),
    (
        "fit: bus baud 123",
        ["fit", "{file}", "--out", "{tmp}/f.toml"],
        "[bus]\nbaud = 123\n" + KEYS,
        2,
        r"\[bus\] baud: expected one of",
        "new",
    ),
    (
        "sweep --plot .txt",
        ["sweep", "--plot", "{tmp}/s.txt"],
        None,
        2,
        r"--plot '.*s.txt': expected a \.png",
        "new",
    ),
    (
        "sweep --json a folder",
        ["sweep", "--json", "{tmp}"],
        None,
        2,
        r"--json '.*': is a directory",
        "new",
    ),
    # --- stream and scan: refused before any port is opened ---------------------------
    (
        "stream --baud 123",
        ["stream", "--baud", "123", "--virtual"],
        None,
        2,
        r"argument --baud: 123 is not an X-series baud rate",
        "silent",
    ),
    (
        "stream --baud abc",
        ["stream", "--baud", "abc"],
        None,
        2,
        r"argument --baud: expected an integer, got 'abc'",
        "unclear",
    ),
    (
        "stream --ids repeated",
        ["stream", "--ids", "1,1,2"],
        None,
        2,
        r"argument --ids: expected distinct ids in 0\.\.252, got '1,1,2'",
        "unclear",
    ),
    (
        "stream --ids two",
        ["stream", "--ids", "1,2"],
        None,
        2,
        r"--ids 1,2: expected 3 ids, one per joint \(pan, tilt, roll\)",
        "unclear",
    ),
    (
        "stream --ids 300",
        ["stream", "--ids", "1,2,300"],
        None,
        2,
        r"argument --ids: expected distinct ids in 0\.\.252",
        "unclear",
    ),
    (
        "stream --ids letters",
        ["stream", "--ids", "a,b,c"],
        None,
        2,
        r"argument --ids: expected ids like 1,2,3, got 'a,b,c'",
        "unclear",
    ),
    (
        "stream no port",
        ["stream"],
        None,
        2,
        r"no serial port: give --port, set \[bus\] port, or use --virtual",
        "ok",
    ),
    (
        "stream --port and --virtual",
        ["stream", "--port", "/dev/null", "--virtual"],
        None,
        2,
        r"trajgen stream: error: argument --virtual: not allowed with argument --port",
        "ok",
    ),
    (
        "stream --plot without --virtual",
        ["stream", "--port", "/dev/null", "--plot", "{tmp}/p.png"],
        None,
        2,
        r"--plot needs --virtual",
        "ok",
    ),
    (
        "stream --telemetry .txt",
        ["stream", "--virtual", "--telemetry", "{tmp}/t.txt"],
        None,
        2,
        r"--telemetry '.*t.txt': expected a \.csv or \.npz or \.mcap file",
        "ok",
    ),
    (
        "stream --telemetry no folder",
        ["stream", "--virtual", "--telemetry", "{tmp}/no/t.csv"],
        None,
        2,
        r"--telemetry '.*/no/t.csv': no such folder",
        "ok",
    ),
    (
        "stream --json no folder",
        ["stream", "--virtual", "--json", "{tmp}/no/r.json"],
        None,
        2,
        r"--json '.*/no/r.json': no such folder",
        "silent",
    ),
    (
        "stream --rate 1e9",
        ["stream", "--virtual", "--rate", "1e9"],
        None,
        2,
        r"over the limit of 5,000,000",
        "crash",
    ),
    (
        "stream: keyframes 1 ms apart",
        ["stream", "{file}", "--virtual"],
        keys("t = 0;pan = 0", "t = 0.001;pan = 1"),
        2,
        r"keyframes 1 and 2: 0.001 s apart",
        "silent",
    ),
    (
        "stream: port that does not exist",
        ["stream", "--port", "{tmp}/ttyUSB9"],
        None,
        2,
        r"ttyUSB9",
        "ok",
    ),
    (
        "scan --baud 123",
        ["scan", "--port", "/dev/null", "--baud", "123"],
        None,
        2,
        r"argument --baud: 123 is not an X-series baud rate",
        "silent",
    ),
    (
        "scan no --port",
        ["scan"],
        None,
        2,
        r"the following arguments are required: --port",
        "unclear",
    ),
    # --- issue 20: the same rules on every command ----------------------------
    (
        "plan --rat 100 (a prefix of --rate)",
        ["plan", "--rat", "100"],
        None,
        2,
        r"^trajgen plan: error: unrecognized arguments: --rat",
        "silent",
    ),
    (
        "sim --jso (a prefix of --json)",
        ["sim", "--jso", "{tmp}/r.json"],
        None,
        2,
        r"^trajgen sim: error: unrecognized arguments: --jso",
        "silent",
    ),
    (
        "excite --virt (a prefix of --virtual)",
        ["excite", "--virt", "--telemetry", "{tmp}/t.csv"],
        None,
        2,
        r"^trajgen excite: error: unrecognized arguments: --virt",
        "silent",
    ),
    (
        "excite --port and --virtual",
        ["excite", "--port", "/dev/null", "--virtual", "--telemetry", "{tmp}/t.csv"],
        None,
        2,
        r"^trajgen excite: error: argument --virtual: not allowed with argument --port",
        "ok",
    ),
    (
        "excite --telemetry .txt",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.txt"],
        None,
        2,
        r"^trajgen excite: error: --telemetry '.*t.txt': expected a .csv or .npz or .mcap file",
        "ok",
    ),
    (
        "scan without --port",
        ["scan", "--baud", "57600"],
        None,
        2,
        r"^trajgen scan: error: the following arguments are required: --port",
        "unclear",
    ),
    (
        "sweep --threads 0",
        ["sweep", "--threads", "0"],
        None,
        2,
        r"^trajgen sweep: error: argument --threads: expected a whole number >= 1, got '0'",
        "ok",
    ),
    (
        "sweep --offset-m nan,0,0",
        ["sweep", "--offset-m", "nan,0,0"],
        None,
        2,
        r"argument --offset-m: expected 3 finite numbers x,y,z in m, got 'nan,0,0'",
        "silent",
    ),
    (
        "identify --max-iter 0",
        ["identify", "{file}", "{file}", "--out", "{tmp}/f.toml", "--max-iter", "0"],
        KEYS,
        2,
        r"argument --max-iter: expected a whole number >= 1, got '0'",
        "ok",
    ),
    (
        "fit --out not .toml",
        ["fit", "{file}", "--out", "{tmp}/fitted.csv"],
        KEYS,
        2,
        r"^trajgen fit: error: --out '.*fitted.csv': expected a .toml file",
        "new",
    ),
    # --- issue 20: outputs --------------------------------------------------------
    (
        "plan --out the input file",
        ["plan", "{file}", "--out", "{file}"],
        KEYS,
        2,
        r"--out '.*keys.toml': is the input file '.*keys.toml'; writing it would destroy it",
        "silent",
    ),
    (
        "plan --out a symbolic link to the input",
        ["plan", "{file}", "--out", "{link}"],
        KEYS,
        2,
        r"--out '.*link.csv': is the input file '.*keys.toml'",
        "silent",
    ),
    (
        "plan --out a hard link to the input",
        ["plan", "{file}", "--out", "{hardlink}"],
        KEYS,
        2,
        r"--out '.*hard.csv': is the input file '.*keys.toml'",
        "silent",
    ),
    (
        "fit --out the input file",
        ["fit", "{file}", "--out", "{file}"],
        KEYS,
        2,
        r"^trajgen fit: error: --out '.*keys.toml': is the input file",
        "silent",
    ),
    (
        "identify --out the keyframe file",
        ["identify", "{file}", "{empty}", "--out", "{file}"],
        KEYS,
        2,
        r"^trajgen identify: error: --out '.*keys.toml': is the input file",
        "silent",
    ),
    (
        "sim --json a symbolic link to the input",
        ["sim", "{file}", "--json", "{link}"],
        KEYS,
        2,
        r"--json '.*link.csv': is the input file",
        "silent",
    ),
    (
        "plan --out /dev/full",
        ["plan", "--out", "/dev/full"],
        None,
        2,
        r"^trajgen plan: error: --out '/dev/full': cannot write: No space left on device",
        "crash",
    ),
    ("plan --out /dev/null", ["plan", "--out", "/dev/null"], None, 0, r"wrote /dev/null", "ok"),
    (
        "plan --out /proc/...",
        ["plan", "--out", "/proc/self/plan.csv"],
        None,
        2,
        r"--out '/proc/self/plan.csv': is in /proc, a kernel interface",
        "crash",
    ),
    (
        "plan --out /sys/...",
        ["plan", "--out", "/sys/kernel/plan.csv"],
        None,
        2,
        r"--out '/sys/kernel/plan.csv': is in /sys, a kernel interface",
        "crash",
    ),
    (
        "sweep --json /proc/...",
        ["sweep", "--json", "/proc/self/r.json"],
        None,
        2,
        r"^trajgen sweep: error: --json '/proc/self/r.json': is in /proc",
        "silent",
    ),
    # --- issue 20: what is read ---------------------------------------------------
    (
        "file /dev/zero",
        ["plan", "/dev/zero"],
        None,
        2,
        r"/dev/zero: more than 128 MiB, the most a keyframe file may hold",
        "hang",
    ),
    (
        "file /dev/urandom",
        ["plan", "/dev/urandom"],
        None,
        2,
        r"/dev/urandom: (more than 128 MiB|binary data \(a NUL byte\))",
        "hang",
    ),
    (
        "file with a UTF-8 byte-order mark",
        ["plan", "{file}"],
        "\ufeff" + KEYS,
        0,
        r"801 samples at 200 Hz",
        "wrong",
    ),
    (
        "file not UTF-8",
        ["plan", "{file}"],
        b"# caf\xe9\n" + KEYS.encode(),
        2,
        r"keys.toml: not UTF-8 text \(byte 0xe9 at offset 5\); save it as UTF-8",
        "ok",
    ),
    (
        "keyframes a table, not a list",
        ["plan", "{file}"],
        "[keyframes]\nt = 0\npan = 0\n",
        2,
        r"keys.toml: keyframes: expected a list of tables, each starting with a line "
        r"\[\[keyframes\]\] \(two brackets\), got one \[keyframes\] table",
        "unclear",
    ),
    (
        "unknown table [Spline] (a capital)",
        ["plan", "{file}"],
        "[Spline]\nk = 2\n" + KEYS,
        2,
        r"keys.toml: unknown table 'Spline' \(known: spline, keyframes",
        "ok",
    ),
    (
        "identify: log missing",
        ["identify", "{file}", "{tmp}/none.csv", "--out", "{tmp}/f.toml"],
        KEYS,
        2,
        r"^trajgen identify: error: .*none.csv: no such telemetry log",
        "unclear",
    ),
    (
        "identify: log empty",
        ["identify", "{file}", "{empty}", "--out", "{tmp}/f.toml"],
        KEYS,
        2,
        r"empty.csv: empty telemetry log",
        "unclear",
    ),
    (
        "identify: log a folder",
        ["identify", "{file}", "{tmp}", "--out", "{tmp}/f.toml"],
        KEYS,
        2,
        r": is a directory, not a telemetry log",
        "unclear",
    ),
    (
        "identify: log a keyframe file",
        ["identify", "{file}", "{file}", "--out", "{tmp}/f.toml"],
        KEYS,
        2,
        r"keys.toml: not a telemetry log \(no column 'frame'\)",
        "ok",
    ),
    # --- issue 20: work that cannot finish ---------------------------------------
    (
        "sweep of 100 x 100 values",
        [
            "sweep",
            "--payload-kg",
            ",".join(f"{0.01 * (i + 1):g}" for i in range(100)),
            "--time-scale",
            ",".join(f"{0.5 + 0.01 * i:g}" for i in range(100)),
        ],
        None,
        2,
        r"10,000 variants \(100 payloads x 1 offsets x 1 servo sets x 100 time scales\), over "
        r"the limit of 1,000; --max-variants N raises it",
        "silent",
    ),
    (
        "joint-minimax through 6,000 keyframes",
        ["plan", "{file}"],
        '[spline]\nknots = "joint-minimax"\n'
        + keys(*(f"t = {i};pan = {10 * (i % 2)}" for i in range(6000))),
        2,
        r"knots: 'joint-minimax' through 6,000 keyframes would take about 5 min, over the limit "
        r"of 5,000 keyframes; use knots = 'end-minimax'",
        "silent",
    ),
    # --- issue 20: keyframe angles the path cannot honour --------------------------
    (
        "two turns of pan",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 2;pan = 720"),
        2,
        r"keyframe 2: field 'pan': 720 deg is outside the pan joint's range -360..360 deg",
        "silent",
    ),
    (
        "one turn of pan between two keyframes",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 2;pan = 360"),
        2,
        r"keyframe 2: field 'pan': 360 deg: 360 deg from keyframe 1's 0: the path turns the "
        r"shorter way",
        "silent",
    ),
    (
        "more than half a turn of roll between two keyframes",
        ["sim", "{file}"],
        keys("t = 0;roll = -100", "t = 2;roll = 100"),
        2,
        r"keyframe 2: field 'roll': 100 deg: 200 deg from keyframe 1's -100",
        "silent",
    ),
    (
        "pan = 1e300",
        ["plan", "{file}"],
        keys("t = 0;pan = 1e300", "t = 2;pan = 1e300"),
        2,
        r"keyframe 1: field 'pan': 1e\+300 deg is outside the pan joint's range",
        "silent",
    ),
    (
        "a first pan the stream reaches on another turn",
        ["plan", "{file}"],
        keys("t = 0;pan = 300", "t = 2;pan = 310"),
        2,
        r"keyframe 1: field 'pan': 300 deg: the path reaches this orientation with pan at -60 deg",
        "silent",
    ),
    (
        "pan 0, 150, 300: each step under half a turn",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 2;pan = 150", "t = 4;pan = 300"),
        0,
        r"801 samples",
        "ok",
    ),
    (
        "plan: tilt = 90",
        ["plan", "{file}"],
        keys("t = 0;pan = 0", "t = 2;tilt = 90"),
        2,
        r"keyframe 2: field 'tilt': 90 deg is within 10.0 deg of gimbal lock \(\|tilt\| <= 80.0",
        "silent",
    ),
    (
        "sim: tilt = 90",
        ["sim", "{file}"],
        keys("t = 0;pan = 0", "t = 2;tilt = 90"),
        2,
        r"^trajgen sim: error: .*keyframe 2: field .tilt.: 90 deg is within 10.0 deg of gimbal",
        "ok",
    ),
    (
        "fit: tilt = 90",
        ["fit", "{file}", "--out", "{tmp}/f.toml"],
        keys("t = 0;pan = 0", "t = 2;tilt = 90"),
        2,
        r"^trajgen fit: error: .*keyframe 2: field .tilt.: 90 deg is within 10.0 deg of gimbal",
        "unclear",
    ),
    (
        "stream: tilt = 90",
        ["stream", "{file}", "--virtual"],
        keys("t = 0;pan = 0", "t = 2;tilt = 90"),
        2,
        r"keyframe 2: field .tilt.: 90 deg is within 10.0 deg of gimbal",
        "ok",
    ),
    # --- issue 20: every command's flags, as a careless user types them ----------
    (
        "follow --rat (a prefix of --rate)",
        ["follow", "--rat", "100", "--virtual"],
        None,
        2,
        r"^trajgen follow: error: unrecognized arguments: --rat",
        "silent",
    ),
    (
        "plan with two files",
        ["plan", "{file}", "{file}"],
        KEYS,
        2,
        r"^trajgen plan: error: unrecognized arguments: .*keys.toml",
        "unclear",
    ),
    (
        "stream --max-delay 0",
        ["stream", "--virtual", "--max-delay", "0"],
        None,
        2,
        r"argument --max-delay: expected a number > 0, got '0'",
        "ok",
    ),
    (
        "stream --max-approach nan",
        ["stream", "--virtual", "--max-approach", "nan"],
        None,
        2,
        r"argument --max-approach: expected a number > 0, got 'nan'",
        "ok",
    ),
    (
        "stream --set-limits reversed",
        ["stream", "--virtual", "--set-limits", "tilt=10:-10"],
        None,
        2,
        r"argument --set-limits: expected finite MIN < MAX, got 'tilt=10:-10'",
        "ok",
    ),
    (
        "excite --amplitude 170",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.csv", "--amplitude", "170"],
        None,
        2,
        r"^trajgen excite: error: the excitation: tilt reaches .* of gimbal lock .*; "
        r"lower --amplitude",
        "unclear",
    ),
    (
        "excite --torque-off (a stream option) is honoured",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.csv", "--seconds", "3", "--torque-off"],
        None,
        0,
        r"servos: were released \(torque off\)",
        "new",
    ),
    (
        "excite --seconds 1",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.csv", "--seconds", "1"],
        None,
        2,
        r"--seconds: Expected `seconds` >= 3",
        "ok",
    ),
    (
        "sweep --time-scale 0",
        ["sweep", "--time-scale", "0"],
        None,
        2,
        r"argument --time-scale: expected a number > 0, got '0'",
        "unclear",
    ),
    (
        "sweep --servo pan=XM999",
        ["sweep", "--servo", "pan=XM999"],
        None,
        2,
        r"^trajgen sweep: error: --servo: unknown model 'XM999' \(known: XM430-W350",
        "unclear",
    ),
    (
        "identify --delay-ms -1",
        ["identify", "{file}", "{empty}", "--out", "{tmp}/f.toml", "--delay-ms", "-1"],
        KEYS,
        2,
        r"--delay-ms: expected 0 <= ms < 1000, got -1",
        "ok",
    ),
    (
        "virtual-bus --models of 2",
        ["virtual-bus", "--models", "XM430-W350,XM430-W350"],
        None,
        2,
        r"--models: expected 1 model or 3 \(one per id\), got 2",
        "ok",
    ),
    (
        "[gimbal] payload_kg a string",
        ["sim", "{file}"],
        '[gimbal]\npayload_kg = "heavy"\n' + KEYS,
        2,
        r"\[gimbal\] payload_kg: expected a finite number",
        "ok",
    ),
    (
        "[bus] watchdog_s negative",
        ["stream", "{file}", "--virtual"],
        "[bus]\nwatchdog_s = -1\n" + KEYS,
        2,
        r"\[bus\] watchdog_s: expected",
        "ok",
    ),
    (
        "stream --telemetry '' (said to be a directory before)",
        ["stream", "--virtual", "--telemetry", ""],
        None,
        2,
        r"^trajgen stream: error: --telemetry '': an empty name; give a file name",
        "unclear",
    ),
    (
        "stream --telemetry run.NPZ (refused by the writer after bring-up before)",
        ["stream", "--virtual", "--telemetry", "{tmp}/run.NPZ"],
        None,
        2,
        r"^trajgen stream: error: --telemetry '.*run\.NPZ': write the suffix in lower case "
        r"\(\.npz\)",
        "silent",
    ),
    (
        "stream --set-limits a joint twice (the last one won before)",
        ["stream", "--virtual", "--set-limits", "pan=0:10", "--set-limits", "pan=-5:5"],
        None,
        2,
        r"^trajgen stream: error: --set-limits pan: given twice; give each joint once",
        "silent",
    ),
    (
        "excite --seconds 1e9 (7 TiB asked for before)",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.csv", "--seconds", "1e9"],
        None,
        2,
        r"^trajgen excite: error: --seconds 1e\+09: longer than 600 s, the longest excitation",
        "crash",
    ),
    (
        "excite --seconds 1e5 (minutes with no word, memory growing, before)",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.csv", "--seconds", "1e5"],
        None,
        2,
        r"--seconds 100000: longer than 600 s",
        "hang",
    ),
    (
        "[limits] a joint table with a string",
        ["plan", "{file}"],
        '[limits]\nspeed_rad_s = {pan = "fast"}\n' + KEYS,
        2,
        r"\[limits\] speed_rad_s",
        "ok",
    ),
    # --- issue 20, the last walk through every command and flag ------------------
    # "-" where no command reads standard input or writes standard output
    (
        "plan --out - (a file named '-' was written before)",
        ["plan", "--out", "-"],
        None,
        2,
        r"--out '-': standard output is not written here; give a file name",
        "silent",
    ),
    (
        "plan - (standard input as the keyframe file)",
        ["plan", "-"],
        None,
        2,
        r"-: no such file \(standard input is not read: give a file name\)",
        "ok",
    ),
    ("sim --json -", ["sim", "--json", "-"], None, 2, r"--json '-': standard output", "ok"),
    # a loop of symbolic links, as input and as output
    (
        "plan: the keyframe file a loop of links",
        ["plan", "{loop}"],
        None,
        2,
        r"loop.toml: cannot read: Too many levels of symbolic links",
        "ok",
    ),
    (
        "plan --out a loop of links (the link was replaced by the CSV before)",
        ["plan", "--out", "{loop}"],
        None,
        2,
        r"--out '.*loop.toml': is a loop of symbolic links",
        "silent",
    ),
    (
        "sim --json a loop of links",
        ["sim", "--json", "{loop}"],
        None,
        2,
        r"is a loop of symbolic links",
        "silent",
    ),
    # the input file as every other output
    (
        "sim --plot the input file",
        ["sim", "{file}", "--plot", "{file}"],
        GOOD,
        2,
        r"--plot '.*keys.toml': is the input file",
        "ok",
    ),
    (
        "stream --telemetry the input file",
        ["stream", "{file}", "--virtual", "--telemetry", "{file}"],
        GOOD,
        2,
        r"--telemetry '.*keys.toml': is the input file",
        "ok",
    ),
    (
        "stream --json the input file",
        ["stream", "{file}", "--virtual", "--json", "{file}"],
        GOOD,
        2,
        r"--json '.*keys.toml': is the input file",
        "ok",
    ),
    (
        "sweep --json the input file",
        ["sweep", "{file}", "--json", "{file}"],
        GOOD,
        2,
        r"--json '.*keys.toml': is the input file",
        "ok",
    ),
    (
        "excite --telemetry the input file",
        ["excite", "{file}", "--virtual", "--telemetry", "{file}"],
        GOOD,
        2,
        r"--telemetry '.*keys.toml': is the input file",
        "ok",
    ),
    (
        "identify --out the log",
        ["identify", "{file}", "{empty}", "--out", "{empty}"],
        GOOD,
        2,
        r"--out '.*empty.csv': is the input file",
        "ok",
    ),
    # folders where a file goes
    (
        "stream --json a folder",
        ["stream", "--virtual", "--json", "{tmp}"],
        None,
        2,
        r"--json '.*empty': is a directory",
        "ok",
    ),
    (
        "follow --json a folder",
        ["follow", "--virtual", "--json", "{tmp}"],
        None,
        2,
        r"--json '.*empty': is a directory",
        "ok",
    ),
    (
        "stream --telemetry a folder",
        ["stream", "--virtual", "--telemetry", "{tmp}"],
        None,
        2,
        r"--telemetry '.*empty': is a directory",
        "ok",
    ),
    (
        "fit --out a folder",
        ["fit", "--out", "{tmp}"],
        None,
        2,
        r"--out '.*empty': is a directory",
        "ok",
    ),
    (
        "scan --port a folder",
        ["scan", "--port", "{tmp}"],
        None,
        2,
        r"cannot open at 1000000 baud",
        "ok",
    ),
    # NaN, inf, 1e300 in numeric flags
    (
        "sweep --payload-kg nan",
        ["sweep", "--payload-kg", "nan"],
        None,
        2,
        r"argument --payload-kg: expected a number > 0, got 'nan'",
        "ok",
    ),
    (
        "sweep --time-scale inf",
        ["sweep", "--time-scale", "inf"],
        None,
        2,
        r"argument --time-scale: expected a number > 0, got 'inf'",
        "ok",
    ),
    (
        "sweep --time-scale 1e300 (said after the cost line before)",
        ["sweep", "--time-scale", "1e300"],
        None,
        2,
        r"--time-scale 1e\+300: 8e\+300 s at 200 Hz is .* samples, over the limit",
        "unclear",
    ),
    (
        "sweep --time-scale 1e-300 (numpy warnings before)",
        ["sweep", "--time-scale", "1e-300"],
        None,
        2,
        r"--time-scale 1e-300: puts keyframes 1.5e-300 s apart, less than one sample period",
        "unclear",
    ),
    (
        "sweep --offset-m 1e300,0,0",
        ["sweep", "--offset-m", "1e300,0,0"],
        None,
        2,
        r"--offset-m 1e\+300,0,0: Expected `payload_offset_m\[0\]` to be a finite number in -1..1",
        "crash",
    ),
    (
        "sweep --payload-kg 1e300 (a failed torque check, exit 1, before)",
        ["sweep", "--payload-kg", "1e300"],
        None,
        2,
        r"--payload-kg 1e\+300: Expected `payload_kg` to be a finite number in 0..100",
        "wrong",
    ),
    (
        "stream --max-delay inf",
        ["stream", "--virtual", "--max-delay", "inf"],
        None,
        2,
        r"argument --max-delay: expected a number > 0, got 'inf'",
        "ok",
    ),
    (
        "stream --set-limits 1e300 (numpy's warning and wrapped ticks before)",
        ["stream", "--virtual", "--set-limits", "pan=-1e300:1e300"],
        None,
        2,
        r"argument --set-limits: expected MIN and MAX within -360..360",
        "unclear",
    ),
    (
        "stream --set-limits pan=nan:1",
        ["stream", "--virtual", "--set-limits", "pan=nan:1"],
        None,
        2,
        r"argument --set-limits: expected finite MIN < MAX",
        "ok",
    ),
    (
        "stream --set-limits of a joint the gimbal lacks",
        ["stream", "--virtual", "--set-limits", "yaw=0:10"],
        None,
        2,
        r"limits for 'yaw': not a joint of this gimbal \(one of pan, tilt, roll\)",
        "ok",
    ),
    (
        "excite --amplitude 1e300 (numpy's overflow warnings before)",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.csv", "--amplitude", "1e300"],
        None,
        2,
        r"--amplitude 1e\+300: more than 180 deg, half a turn",
        "unclear",
    ),
    (
        "excite --amplitude nan",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.csv", "--amplitude", "nan"],
        None,
        2,
        r"argument --amplitude: expected a number > 0, got 'nan'",
        "ok",
    ),
    (
        "excite --seconds nan",
        ["excite", "--virtual", "--telemetry", "{tmp}/t.csv", "--seconds", "nan"],
        None,
        2,
        r"argument --seconds: expected a number > 0, got 'nan'",
        "ok",
    ),
    (
        "identify --delay-ms nan",
        ["identify", "{file}", "{empty}", "--out", "{tmp}/f.toml", "--delay-ms", "nan"],
        GOOD,
        2,
        r"--delay-ms: expected 0 <= ms < 1000, got nan",
        "ok",
    ),
    (
        "plan --max-samples inf",
        ["plan", "--max-samples", "inf"],
        None,
        2,
        r"argument --max-samples: expected a whole number >= 2, got 'inf'",
        "ok",
    ),
    (
        "stream --rate 1e-300",
        ["stream", "--virtual", "--rate", "1e-300"],
        None,
        2,
        r"less than one sample period \(1e\+300 s at 1e-300 Hz\)",
        "ok",
    ),
    # ids out of 0..252, too many
    (
        "stream --ids 253,1,2",
        ["stream", "--virtual", "--ids", "253,1,2"],
        None,
        2,
        r"argument --ids: expected distinct ids in 0..252, got '253,1,2'",
        "ok",
    ),
    (
        "stream --ids four",
        ["stream", "--virtual", "--ids", "1,2,3,4"],
        None,
        2,
        r"--ids 1,2,3,4: expected 3 ids, one per joint \(pan, tilt, roll\)",
        "ok",
    ),
    (
        "virtual-bus --ids 253",
        ["virtual-bus", "--ids", "253"],
        None,
        2,
        r"argument --ids: expected distinct ids in 0..252",
        "ok",
    ),
    (
        "virtual-bus --ids fewer than the joints",
        ["virtual-bus", "--ids", "1,2"],
        None,
        2,
        r"--ids 1,2: expected at least 3 ids, one per joint of the gimbal",
        "ok",
    ),
    # NaN, inf and 1e300 in the file's keys; unknown axes letters
    (
        "rate_hz nan",
        ["plan", "{file}"],
        "[stream]\nrate_hz = nan\n" + PAN_10,
        2,
        r"\[stream\] rate_hz: expected a finite number > 0, got nan",
        "ok",
    ),
    (
        "run_in_s 1e300",
        ["plan", "{file}"],
        "[stream]\nrun_in_s = 1e300\n" + PAN_10,
        2,
        r"\[stream\] run_in_s: Expected `run_in_s` at most the path's 1 s",
        "ok",
    ),
    (
        "[gimbal] payload_kg nan",
        ["sim", "{file}"],
        "[gimbal]\npayload_kg = nan\n" + PAN_10,
        2,
        r"\[gimbal\] payload_kg: expected a finite number in 0..100, got nan",
        "ok",
    ),
    (
        "[gimbal] payload_kg 1e300 (a failed torque check before)",
        ["sim", "{file}"],
        "[gimbal]\npayload_kg = 1e300\n" + PAN_10,
        2,
        r"\[gimbal\] payload_kg: expected a finite number in 0..100, got 1e\+300",
        "wrong",
    ),
    (
        "[gimbal] payload_offset_m 1e300 (MuJoCo's traceback before)",
        ["sim", "{file}"],
        "[gimbal]\npayload_offset_m = [1e300, 0, 0]\n" + PAN_10,
        2,
        r"\[gimbal\] payload_offset_m: expected a finite number in -1..1, got 1e\+300",
        "crash",
    ),
    (
        "[gimbal.pan] position_p_gain 1e300",
        ["sim", "{file}"],
        "[gimbal.pan]\nposition_p_gain = 1e300\n" + PAN_10,
        2,
        r"\[gimbal.pan\] position_p_gain: expected an integer in 0..16383",
        "ok",
    ),
    (
        "[gimbal] axes with a letter that is no axis",
        ["plan", "{file}"],
        '[gimbal]\naxes = "zqx"\n' + PAN_10,
        2,
        r"\[gimbal\] axes: Expected `axes` to be 2 or 3 letters",
        "ok",
    ),
    (
        "[gimbal] axes turning twice about z",
        ["plan", "{file}"],
        '[gimbal]\naxes = "zz"\n' + PAN_10,
        2,
        r"to turn about different axes in neighbouring joints",
        "ok",
    ),
    (
        "[bus] zeros nan",
        ["plan", "{file}"],
        "[bus]\nzeros = [nan, 2048, 2048]\n" + PAN_10,
        2,
        r"\[bus\] zeros: expected an integer in 0..4095, got nan",
        "ok",
    ),
    (
        "[bus] baud 1e300",
        ["plan", "{file}"],
        "[bus]\nbaud = 1e300\n" + PAN_10,
        2,
        r"\[bus\] baud: expected an integer, got 1e\+300",
        "ok",
    ),
    (
        "[spline] k nan",
        ["plan", "{file}"],
        "[spline]\nk = nan\n" + PAN_10,
        2,
        r"\[spline\] k: expected an integer in 1..6, got nan",
        "ok",
    ),
    (
        "quat of 1e300 is the direction it names (a zero norm before)",
        ["plan", "{file}"],
        "[[keyframes]]\nt = 0\nquat = [1e300, 1e300, 0, 0]\n[[keyframes]]\nt = 1\npan = 10\n",
        0,
        r"planned keys.toml: 201 samples",
        "wrong",
    ),
    # very long lines
    (
        "a keyframe field with a name of a million letters",
        ["plan", "{file}"],
        "[[keyframes]]\nt = 0\npan = 0\n"
        + "x" * 1_000_000
        + " = 1\n[[keyframes]]\nt = 1\npan = 10\n",
        2,
        r"keyframe 1: unknown field 'x{20,}\.\.\.' \(known: t, pan, tilt, roll, quat\)$",
        "unclear",
    ),
]


def _write(path, content) -> None:
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content, encoding="utf-8")


def run_case(argv, file, tmp_path, capsys) -> tuple[int, str, str]:
    """Run one row through ``trajgen.cli.main``; returns (status, stdout, stderr).

    Besides ``{file}`` and ``{tmp}``, ``argv`` may name ``{link}`` (a symbolic link
    to the keyframe file), ``{hardlink}`` (a hard link to it), ``{empty}`` (an
    empty file) and ``{loop}`` (a symbolic link to itself).
    """
    folder = tmp_path / "empty"
    folder.mkdir()
    path = tmp_path / "keys.toml"
    if file is not None:
        _write(path, file)
    link, hardlink, empty = tmp_path / "link.csv", tmp_path / "hard.csv", tmp_path / "empty.csv"
    empty.touch()
    loop = tmp_path / "loop.toml"
    loop.symlink_to(loop)
    if file is not None:
        link.symlink_to(path)
        os.link(path, hardlink)
    argv = [
        a.format(file=path, tmp=folder, link=link, hardlink=hardlink, empty=empty, loop=loop)
        for a in argv
    ]
    try:
        status = main(argv)
    except SystemExit as e:  # argparse
        status = e.code
    out = capsys.readouterr()
    return status, out.out, out.err


@pytest.mark.parametrize(
    ("argv", "file", "status", "message"),
    [pytest.param(*row[1:5], id=row[0]) for row in CASES],
)
def test_bad_input_is_refused_clearly(argv, file, status, message, tmp_path, capsys):
    got, out, err = run_case(argv, file, tmp_path, capsys)
    assert "Traceback" not in err
    assert got == status, err
    if status == 2:
        line = err.strip()
        command = argv[0] if argv and argv[0] in COMMANDS else None
        assert line.startswith(f"trajgen {command}:" if command else "trajgen:"), err
        assert "\n" not in line, err
        assert re.search(message, line), line
    else:
        assert re.search(message, out + err), out + err


def test_the_table_is_what_the_report_counts():
    names = [row[0] for row in CASES]
    assert len(names) == len(set(names))
    assert all(
        row[5] in ("ok", "crash", "hang", "silent", "wrong", "unclear", "new") for row in CASES
    )


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_an_unwritable_folder_is_refused(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    status, _, err = run_case(["plan", "--out", f"{locked}/p.csv"], None, tmp_path, capsys)
    assert status == 2 and "is not writable" in err


def test_a_closed_pipe_ends_quietly():
    import subprocess
    import sys

    code = "import sys; from trajgen.cli import main; sys.exit(main(['plan']))"
    plan = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert plan.stdout.readline().startswith(b"t_s,")
    plan.stdout.close()  # as `trajgen plan | head -1` does
    assert plan.wait(timeout=60) == 0
    err = plan.stderr.read()
    assert b"Traceback" not in err and b"BrokenPipe" not in err


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    from trajgen.cli.common import output_file

    out = tmp_path / "plan.csv"
    out.write_text("old")
    with pytest.raises(RuntimeError, match="half way"):
        with output_file("--out", str(out)) as f:
            f.write("new, but only half")
            raise RuntimeError("half way")
    assert out.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.csv"]


def test_an_output_through_a_symbolic_link_replaces_what_it_names(tmp_path):
    from trajgen.cli.common import output_file

    target, link = tmp_path / "target.csv", tmp_path / "link.csv"
    target.write_text("old")
    target.chmod(0o640)
    link.symlink_to(target)
    with output_file("--out", str(link)) as f:
        f.write("new")
    assert link.is_symlink() and target.read_text() == "new"
    assert target.stat().st_mode & 0o777 == 0o640  # the permissions of the file replaced


def test_ctrl_c_while_plan_writes_leaves_no_half_csv(tmp_path, monkeypatch, capsys):
    from trajgen.cli import plan

    written = []

    def interrupted(out, *args):
        out.write("t_s,qw\n")  # a first block, then Ctrl-C
        written.append(out.name)
        raise KeyboardInterrupt

    monkeypatch.setattr(plan, "write_plan_csv", interrupted)
    out = tmp_path / "p.csv"
    assert main(["plan", "--out", str(out)]) == 130
    assert "trajgen plan: interrupted" in capsys.readouterr().err
    assert written and not out.exists() and not list(tmp_path.iterdir())


def test_ctrl_c_while_the_command_line_loads_is_one_line(monkeypatch, capsys):
    import builtins

    import trajgen_launch

    real_import = builtins.__import__

    def interrupted(name, *args, **kwargs):
        if name == "trajgen.cli":
            raise KeyboardInterrupt  # Ctrl-C in the middle of loading numpy and the commands
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", interrupted)
    assert trajgen_launch.main() == 130
    assert capsys.readouterr().err.strip() == "trajgen: interrupted while starting"


def test_ctrl_c_in_a_commands_lazy_import_is_one_line(monkeypatch, capsys):
    from trajgen.cli import sim

    def interrupted_import(args):
        try:
            raise KeyboardInterrupt  # Ctrl-C while MuJoCo loads ...
        except KeyboardInterrupt as e:  # ... which a module turned into an ImportError
            raise ImportError("cannot import name 'mjModel' (most likely a circular import)") from e

    monkeypatch.setattr(sim, "run_sim", interrupted_import)
    monkeypatch.setattr(sim, "register", _registering(sim.register, interrupted_import))
    assert main(["sim"]) == 130
    assert capsys.readouterr().err.strip() == "trajgen sim: interrupted"


def test_ctrl_c_inside_ctypes_while_mujoco_loads_is_one_line_and_the_report(
    monkeypatch, capsys, tmp_path
):
    # Ctrl-C while ctypes converts an argument (MuJoCo's EGL set-up on import) reaches us
    # as ctypes.ArgumentError naming only "KeyboardInterrupt": seen once in CI as a
    # traceback and exit 1. `sim` says "interrupted" and writes its interrupted report.
    import ctypes

    from trajgen.cli import sim

    def interrupted(args, progress, done):
        raise ctypes.ArgumentError("argument 1: KeyboardInterrupt: ")

    monkeypatch.setattr(sim, "_run", interrupted)
    out = tmp_path / "r.json"
    assert main(["sim", "--json", str(out)]) == 130
    assert capsys.readouterr().err.strip() == "trajgen sim: interrupted"
    report = json.loads(out.read_text())
    assert report["interrupted"] is True and report["ok"] is None


def test_a_ctypes_error_that_is_no_interrupt_still_shows(monkeypatch):
    import ctypes

    from trajgen.cli import sim

    def wrong(args, progress, done):
        raise ctypes.ArgumentError("argument 1: TypeError: wrong type")

    monkeypatch.setattr(sim, "_run", wrong)
    with pytest.raises(ctypes.ArgumentError, match="wrong type"):
        main(["sim"])


def _registering(register, func):
    """``register`` with ``func`` as the subcommand's function."""

    def wrapped(subparsers):
        register(subparsers)
        subparsers.choices["sim"].set_defaults(func=func)

    return wrapped


def test_an_import_error_that_is_no_interrupt_still_shows(monkeypatch):
    from trajgen.cli import sim

    def missing(args):
        raise ImportError("No module named 'mujoco'")

    monkeypatch.setattr(sim, "register", _registering(sim.register, missing))
    with pytest.raises(ImportError, match="mujoco"):
        main(["sim"])
