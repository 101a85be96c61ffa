"""Ctrl-C while `trajgen` starts: exit status 130 and one line, never a traceback.

The signal is sent at several delays after the entry point's first statements
(``trajgen_launch``: seen as SIGTERM caught in ``/proc/<pid>/status``) to the
real console script, while numpy, the command modules and (for ``sim``) MuJoCo
load, or once the command runs. The interpreter's own start-up before that
(``site``, ``.pth`` files) is outside our code: ``bench/startup_window.py``
measures it (docs/cli.md).
"""

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

TRAJGEN = Path(sys.executable).with_name("trajgen")

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/status").exists() or not TRAJGEN.exists(),
    reason="needs /proc and the installed trajgen script",
)


def caught_signals(pid: int) -> int:
    """The bit mask of signals process ``pid`` has handlers for (SigCgt), 0 once gone."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0
    return int(re.search(r"^SigCgt:\s*([0-9a-f]+)", text, re.M).group(1), 16)


def wait_for_the_entry_point(proc: subprocess.Popen, timeout_s: float = 120.0) -> None:
    """Return once ``trajgen_launch`` has installed its handlers (SIGTERM caught)."""
    bit = 1 << (signal.SIGTERM - 1)
    deadline = time.monotonic() + timeout_s
    while not caught_signals(proc.pid) & bit:
        assert proc.poll() is None, "trajgen ended before its entry point was seen"
        assert time.monotonic() < deadline, "trajgen's entry point was never seen"
        time.sleep(0.0002)


@pytest.mark.parametrize("command", ["plan", "sim"])
@pytest.mark.parametrize("delay_ms", [0, 20, 50, 100, 200])
def test_ctrl_c_at_start_up_is_exit_130_and_one_line(command, delay_ms, tmp_path):
    rng = np.random.default_rng(delay_ms)
    out = tmp_path / ("p.csv" if command == "plan" else "s.json")
    flag = "--out" if command == "plan" else "--json"
    argv = [str(TRAJGEN), command, flag, str(out)]
    if command == "plan":
        argv += ["--rate", "5000"]  # seconds of work: the signal finds it running
    proc = subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path, text=True
    )
    try:
        wait_for_the_entry_point(proc)
        time.sleep((delay_ms + rng.uniform(0.0, 5.0)) / 1000)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "Error" not in stderr, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    # before the command line is parsed the command is not known yet: "trajgen: interrupted"
    assert re.fullmatch(
        rf"trajgen(: interrupted while starting|( {command})?: interrupted)", lines[0]
    )
    # Nothing half written: no file, or (once `sim` runs: its --json is "the report, on
    # Ctrl-C what was done so far") the whole interrupted report, said on stdout.
    if command == "sim" and out.exists():
        report = json.loads(out.read_text())
        assert report["interrupted"] is True and report["ok"] is None
        assert f"json: {out}" in stdout
        assert list(tmp_path.iterdir()) == [out]
    else:
        assert not out.exists() and list(tmp_path.iterdir()) == []


def test_the_entry_point_gives_the_handlers_back_when_it_returns(monkeypatch):
    import builtins

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    import trajgen_launch  # installs its own on first import

    real_import = builtins.__import__

    def interrupted(name, *args, **kwargs):
        if name == "trajgen.cli":
            raise KeyboardInterrupt
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", interrupted)
    assert trajgen_launch.main() == 130
    assert {s: signal.getsignal(s) for s in before} == before


def test_the_entry_point_imports_nothing_before_its_handlers():
    # Its first statement needs no module beyond the interpreter's built-in `_signal`:
    # loading `signal` (and `enum`) before the handlers would lengthen Python's window.
    code = (
        "import sys; before = set(sys.modules); import trajgen_launch; "
        "print(' '.join(sorted(set(sys.modules) - before)))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["trajgen_launch"]
