"""Every numbered example runs, on the public API only, with small arguments."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).parents[1] / "examples"

SHORT = """\
[stream]
rate_hz = 100

[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 1.0
pan = 10.0
tilt = 5.0
"""


def _arguments(name: str, tmp_path: Path) -> list[str]:
    short = tmp_path / "short.toml"
    short.write_text(SHORT)
    return {
        "01_plan_offline.py": ["--rate", "20"],
        "02_joint_stream.py": ["--file", str(short)],
        "03_simulate_torque.py": ["--file", str(EXAMPLES / "sim_too_fast.toml"), "--expect-fail"],
        "04_stream_virtual.py": ["--file", str(short)],
        "05_follow_target.py": ["--seconds", "1", "--no-plot"],
        "06_stream_file.py": ["--file", str(short), "--json", str(tmp_path / "out.json")],
    }[name]


NUMBERED = sorted(p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py"))


def test_the_examples_are_numbered_from_01():
    assert NUMBERED[:6] == [
        "01_plan_offline.py",
        "02_joint_stream.py",
        "03_simulate_torque.py",
        "04_stream_virtual.py",
        "05_follow_target.py",
        "06_stream_file.py",
    ]


@pytest.mark.parametrize("name", NUMBERED)
def test_an_example_uses_the_public_api_only(name):
    tree = ast.parse((EXAMPLES / name).read_text())
    modules = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    modules |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert not {m for m in modules if m.startswith("trajgen.cli")}
    assert ast.get_docstring(tree).splitlines()[0]  # says what it shows


@pytest.mark.parametrize("name", NUMBERED)
def test_an_example_runs(name, tmp_path):
    proc = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *_arguments(name, tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip() and "Traceback" not in proc.stderr
