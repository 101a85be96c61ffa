"""Keyframe files: parsing, the built-in example, one-line errors naming file, keyframe, field."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from trajgen import keyframes
from trajgen import quat as Q
from trajgen.keyframes import BUILTIN_EXAMPLE, KeyframeFileError, load_keyframe_file

GOOD = """
[spline]
k = 3
boundary = "natural"

[stream]
rate_hz = 250

[gimbal]
servo = "XL430-W250"

[[keyframes]]
t = 0.0
pan = 90.0

[[keyframes]]
t = 1.5
quat = [2.0, 0.0, 0.0, 0.0]

[[keyframes]]
t = 2.0
tilt = 30.0
"""


def write(tmp_path, text, name="keys.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_good_file(tmp_path):
    kf = load_keyframe_file(write(tmp_path, GOOD))
    np.testing.assert_array_equal(kf.times, [0.0, 1.5, 2.0])
    np.testing.assert_allclose(kf.quats[0], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    np.testing.assert_allclose(kf.quats[1], [1, 0, 0, 0])  # normalised
    np.testing.assert_allclose(kf.quats[2], Q.from_axis_angle([0, 1, 0], np.pi / 6))
    assert kf.spline_options == {"k": 3, "boundary": "natural"}
    assert kf.rate_hz == 250.0
    assert kf.tables == {"gimbal": {"servo": "XL430-W250"}}
    s = kf.spline()
    assert s.k == 3 and s.boundary == "natural"
    assert Q.distance(s(kf.times), kf.quats).max() < 1e-12


def test_builtin_and_shipped_examples_load():
    from pathlib import Path

    files = [BUILTIN_EXAMPLE, *sorted(Path(__file__).parents[1].glob("examples/*.toml"))]
    assert len(files) >= 4
    for f in files:
        kf = load_keyframe_file(f)
        assert len(kf.times) >= 2
        kf.spline()


KEYS = """
[[keyframes]]
t = 0.0
pan = 0.0
"""


@pytest.mark.parametrize(
    "text,match",
    [
        (
            "[[keyframes]]\nt = 0.0\npan = 'abc'\n" + KEYS.replace("0.0", "1.0", 1),
            r"keyframe 1: field 'pan': expected a finite number, got 'abc'",
        ),
        (
            KEYS + "\n[[keyframes]]\nt = 1.0\ntlt = 3.0\n",
            r"keyframe 2: unknown field 'tlt' \(known: t, pan, tilt, roll, quat\)",
        ),
        (KEYS + "\n[[keyframes]]\npan = 3.0\n", r"keyframe 2: field 't' is missing"),
        (
            KEYS + "\n[[keyframes]]\nt = 0.0\npan = 3.0\n",
            r"keyframe 2: field 't': 0 s is not after keyframe 1's 0 s",
        ),
        (
            KEYS + "\n[[keyframes]]\nt = 1.0\nquat = [1, 0, 0]\n",
            r"keyframe 2: field 'quat': expected \[w, x, y, z\], got \[1, 0, 0\]",
        ),
        (
            KEYS + "\n[[keyframes]]\nt = 1.0\nquat = [0, 0, 0, 0]\n",
            r"keyframe 2: field 'quat': zero quaternion",
        ),
        (
            KEYS + "\n[[keyframes]]\nt = 1.0\nquat = [1, 0, 0, 0]\npan = 2\n",
            r"keyframe 2: give either 'quat' or pan/tilt/roll, not both",
        ),
        (KEYS + "\n[[keyframes]]\nt = 1.0\n", r"keyframe 2: no orientation"),
        (
            KEYS + "\n[[keyframes]]\nt = true\npan = 1\n",
            r"keyframe 2: field 't': expected a finite number, got True",
        ),
        (KEYS, r"\[\[keyframes\]\]: at least 2 are needed, got 1"),
        ("[spline]\nk = 2\n", r"no \[\[keyframes\]\]"),
        ("[spline]\nk = 0\n" + KEYS * 2, r"\[spline\] k: expected an integer in 1\.\.6, got 0"),
        (
            "[spline]\nboundary = 'free'\n" + KEYS,
            r"\[spline\] boundary: expected one of rest, natural, closed, got 'free'",
        ),
        ("[spline]\nkk = 2\n" + KEYS, r"\[spline\]: unknown key 'kk'"),
        (
            "[stream]\nrate_hz = -5\n" + KEYS,
            r"\[stream\] rate_hz: expected a finite number > 0, got -5",
        ),
        ("[keyframe]\nt = 1\n", r"unknown table 'keyframe' \(known: spline, keyframes"),
        ("[[keyframes]\nt = 1\n", r"invalid TOML"),
        (
            "[spline]\nboundary = 'closed'\n" + KEYS + "\n[[keyframes]]\nt = 1.0\npan = 5.0\n"
            "\n[[keyframes]]\nt = 2.0\npan = 9.0\n",
            r"last keyframe to repeat the first; they are 9 deg apart",
        ),
    ],
)
def test_malformed_files_raise_one_line_errors(tmp_path, text, match):
    path = write(tmp_path, text)
    with pytest.raises(KeyframeFileError, match=match) as info:
        load_keyframe_file(path).spline()  # what the spline refuses, it refuses when built
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message


def test_missing_file(tmp_path):
    with pytest.raises(KeyframeFileError, match="nope.toml: no such file"):
        load_keyframe_file(tmp_path / "nope.toml")


def test_plan_command_writes_csv(tmp_path):
    from trajgen.cli import main

    out = tmp_path / "plan.csv"
    assert main(["plan", str(write(tmp_path, GOOD)), "--rate", "10", "--out", str(out)]) == 0
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert rows.shape == (21, 11)
    np.testing.assert_allclose(rows[[0, -1], 0], [0.0, 2.0])
    np.testing.assert_allclose(np.linalg.norm(rows[:, 1:5], axis=1), 1.0, atol=1e-9)


def test_plan_command_bad_file_exits_2_with_one_line(tmp_path):
    path = write(tmp_path, KEYS + "\n[[keyframes]]\nt = 1.0\ntlt = 3.0\n")
    proc = subprocess.run(
        [sys.executable, "-m", "trajgen", "plan", str(path)], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"trajgen plan: error: {path}: keyframe 2: unknown field 'tlt' "
        "(known: t, pan, tilt, roll, quat)"
    ]
    assert "Traceback" not in proc.stderr


def test_import_trajgen_needs_numpy_only():
    code = (
        "import sys, trajgen, trajgen.cli\n"
        "heavy = {'scipy', 'mujoco', 'dynamixel_sdk', 'serial', 'matplotlib', 'numba'}\n"
        "ours = ('trajgen.sim', 'trajgen.drivers')\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in heavy or m.startswith(ours)))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_the_fast_reader_agrees_with_tomllib(tmp_path):
    # The same keyframes read by the regular-expression reader and, with one
    # line it does not handle (a quoted key), by tomllib.
    rng = np.random.default_rng(7)
    lines = ["[spline]\nk = 2\n"]
    for i, (pan, tilt, roll) in enumerate(rng.uniform(-60, 60, (50, 3))):
        lines.append(f"[[keyframes]]  # no. {i + 1}\nt = {0.5 * i:.3f}\npan = {pan:.4f}\n")
        lines.append(f"tilt = {tilt / 2:.4e}\nroll = {roll / 6:+.2f}\n\n")
    lines.append("[gimbal]\npayload_kg = 0.1\n")
    fast = load_keyframe_file(write(tmp_path, "".join(lines), "fast.toml"))
    slow_text = "".join(lines).replace("\nroll = ", '\n"roll" = ', 1)
    slow = load_keyframe_file(write(tmp_path, slow_text, "slow.toml"))
    assert keyframes._read_keyframe_run(slow_text) is None
    assert keyframes._read_keyframe_run("".join(lines)) is not None
    np.testing.assert_array_equal(fast.times, slow.times)
    np.testing.assert_allclose(fast.quats, slow.quats, rtol=0, atol=1e-15)
    assert fast.tables == slow.tables == {"gimbal": {"payload_kg": 0.1}}


@pytest.mark.parametrize(
    "text, match",
    [
        ("[[keyframes]]\nt = 0\npan = 1\npan = 2\n[[keyframes]]\nt = 1\n", "Cannot overwrite"),
        ("[[keyframes]]\nt = 01\npan = 1\n[[keyframes]]\nt = 2\npan = 0\n", "invalid TOML"),
        ("[[keyframes]]\nt = 0\npan = 1\n[spline]\nk = 2\n[[keyframes]]\nt = 1\npan = 0\n", None),
    ],
)
def test_the_fast_reader_leaves_what_it_does_not_handle_to_tomllib(tmp_path, text, match):
    path = write(tmp_path, text)
    if match is None:  # keyframes on both sides of another table: still valid TOML
        assert len(load_keyframe_file(path).times) == 2
    else:
        with pytest.raises(KeyframeFileError, match=match):
            load_keyframe_file(path)


def test_the_spline_is_built_once_on_first_use():
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    assert kf.spline() is kf.spline()
    assert kf.stream_rate() == 200.0 and kf.stream_rate(50.0) == 50.0


def test_a_byte_order_mark_is_read_and_a_huge_file_is_refused_unread(tmp_path, monkeypatch):
    import trajgen.keyframes as keyframes_module

    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + GOOD.encode())
    assert len(load_keyframe_file(path).times) == len(
        load_keyframe_file(write(tmp_path, GOOD)).times
    )
    monkeypatch.setattr(keyframes_module, "MAX_FILE_BYTES", 64)
    with pytest.raises(KeyframeFileError, match=r"bom.toml: more than 0 MiB, the most a keyframe"):
        load_keyframe_file(path)


@pytest.mark.parametrize(
    ("rows", "match"),
    [
        # Two turns of pan are no motion as orientations: refused, not followed as nothing.
        (
            ["t = 0.0\npan = 0", "t = 1.0\npan = 720"],
            r"keyframe 2: field 'pan': 720 deg is outside",
        ),
        (
            ["t = 0.0\npan = 0", "t = 1.0\npan = 360"],
            r"keyframe 2: field 'pan': 360 deg: 360 deg from",
        ),
        (
            ["t = 0.0\nroll = 100", "t = 1.0\nroll = -90"],
            r"keyframe 2: field 'roll': -90 deg: 190 deg",
        ),
        (
            ["t = 0.0\npan = 190", "t = 1.0\npan = 180"],
            r"keyframe 1: field 'pan': 190 deg: the path "
            r"reaches this orientation with pan at -170 deg",
        ),
        (
            ["t = 0.0\ntilt = -81", "t = 1.0\npan = 3"],
            r"keyframe 1: field 'tilt': -81 deg is within "
            r"10.0 deg of gimbal lock",
        ),
    ],
)
def test_angles_the_path_would_not_follow_as_written_are_refused(tmp_path, rows, match):
    text = "".join(f"[[keyframes]]\n{row}\n\n" for row in rows)
    with pytest.raises(KeyframeFileError, match=match):
        load_keyframe_file(write(tmp_path, text))


def test_angles_the_path_follows_are_kept_as_written(tmp_path):
    from trajgen.stream import plan_joint_trajectory

    rows = [(0.0, 0, 0, 0), (1.0, 150, 20, 0), (2.0, 300, -30, 0), (3.0, 300, 0, -150)]
    text = "".join(
        f"[[keyframes]]\nt = {t}\npan = {p}\ntilt = {ti}\nroll = {r}\n\n" for t, p, ti, r in rows
    )
    kf = load_keyframe_file(write(tmp_path, text))
    assert len(kf.times) == 4
    # The joint stream passes every keyframe at the angles written (pan unwrapped to 300).
    stream = plan_joint_trajectory(kf.spline(), 100.0)
    at = np.searchsorted(stream.t, kf.times)
    np.testing.assert_allclose(np.degrees(stream.q[at]), [r[1:] for r in rows], atol=1e-6)
