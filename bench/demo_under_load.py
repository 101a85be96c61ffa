"""The demo's stream command, run N times with CPU-bound processes beside it.

The command is the one ``make demo`` runs, read from the Makefile (its output
files go to a temporary directory). Beside each run, ``--hogs`` processes spin
a core each. A run passes when it exits 0 and its JSON says the stream ran to
its end. The peer, in the same run: the same command with no hog beside it
(``--peer`` runs of it). Prints passes, wall time per run and the machine load
(``os.getloadavg()``) around each.

    .venv/bin/python bench/demo_under_load.py            # 20 runs, 2 hogs, 2 peer runs
    .venv/bin/python bench/demo_under_load.py --runs 6 --peer 1
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HOG = "while True: pass"


def demo_command(out_dir: Path) -> list[str]:
    """``make demo``'s trajgen command, its ``out/`` files moved to ``out_dir``."""
    text = (ROOT / "Makefile").read_text()
    recipe = text[text.index("\ndemo:") :]
    line = next(line for line in recipe.splitlines() if "trajgen stream" in line)
    line = line.strip().replace("$(BIN)", str(ROOT / ".venv" / "bin"))
    line = re.sub(r"\bout/", f"{out_dir}/", line)
    return shlex.split(line)


def run_once(out_dir: Path) -> tuple[bool, float, str]:
    """(passed, wall seconds, why it failed or "")."""
    command = demo_command(out_dir)
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    start = time.monotonic()
    proc = subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT)
    wall_s = time.monotonic() - start
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        return False, wall_s, f"exit {proc.returncode}: {last}"
    outcome = json.loads((out_dir / "demo.json").read_text())
    stream = outcome["stream"] or {}
    if outcome["stopped_by"] or stream.get("frames_sent") != stream.get("frames_planned"):
        return False, wall_s, outcome["stopped_by"] or "not every frame sent"
    return True, wall_s, ""


def series(runs: int, hogs: int, label: str) -> tuple[int, list[str]]:
    passes, failures = 0, []
    procs = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(hogs)]
    try:
        for k in range(runs):
            load = os.getloadavg()[0]
            with tempfile.TemporaryDirectory() as tmp:
                ok, wall_s, why = run_once(Path(tmp))
            passes += ok
            status = "pass" if ok else f"FAIL ({why})"
            print(
                f"{label} run {k + 1:2d}/{runs}: {status}, {wall_s:.1f} s, load {load:.2f}",
                flush=True,
            )
            if not ok:
                failures.append(why)
    finally:
        for p in procs:
            p.kill()
            p.wait()
    return passes, failures


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="runs with the hogs (default 20)")
    parser.add_argument("--hogs", type=int, default=2, help="CPU-bound processes (default 2)")
    parser.add_argument("--peer", type=int, default=2, help="runs without hogs (default 2)")
    args = parser.parse_args(argv)
    print(f"command: {shlex.join(demo_command(Path('OUT')))}")
    print(f"cores: {os.cpu_count()}, load at start {os.getloadavg()}")
    peer_passes, _ = series(args.peer, 0, "peer (no hog)")
    passes, failures = series(args.runs, args.hogs, f"{args.hogs} hogs")
    print(
        f"\nwith {args.hogs} CPU-bound processes: {passes}/{args.runs} pass; "
        f"peer without them: {peer_passes}/{args.peer}; load at end {os.getloadavg()}"
    )
    for why in sorted(set(failures)):
        print(f"  failure: {why}")
    return 0 if passes == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
