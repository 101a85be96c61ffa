"""How long Ctrl-C at start-up can still give Python's own traceback, before our code runs.

``trajgen_launch`` (the ``trajgen`` script's entry point) makes SIGINT, SIGTERM
and SIGHUP end the start-up with one line as its first statements. Before
those, the interpreter itself runs: from ``exec`` until Python installs its
SIGINT handler a Ctrl-C kills the process silently (the shell shows 130, no
output); from then until our first statement it raises KeyboardInterrupt inside
``site`` (the environment's ``.pth`` files) and prints a traceback. This is that
window, measured on the real script by watching ``/proc/<pid>/status`` (SigCgt,
polled every 0.2 ms: SIGINT caught = Python's handler; SIGTERM caught = ours;
SIGTERM no longer caught = handed over to ``trajgen.cli``). A traceback "in
our code" is one with a frame in trajgen's own files.

The peer, in the same run, is the same interpreter and ``site`` running a
two-line script that installs a SIGTERM handler first: the window every Python
program has. Then ``--probe`` sends SIGINT at random times in the first 300 ms
and counts the outcomes (seeded).

    python bench/startup_window.py [--runs 20] [--probe 40]
"""

import argparse
import collections
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

TRAJGEN = Path(sys.executable).with_name("trajgen")
PEER = "import signal; signal.signal(signal.SIGTERM, lambda *a: None)\nimport time; time.sleep(0.3)"
INT, TERM = 1 << (signal.SIGINT - 1), 1 << (signal.SIGTERM - 1)


def caught(pid: int) -> int | None:
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    return int(re.search(r"^SigCgt:\s*([0-9a-f]+)", text, re.M).group(1), 16)


def times(argv) -> tuple[float, float, float]:
    """Seconds from Popen to Python's SIGINT handler, to our SIGTERM handler, to the
    hand-over (SIGTERM no longer caught; nan for the peer)."""
    start = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen = {}
    while proc.poll() is None:
        mask = caught(proc.pid)
        if mask is None:
            break
        now = time.perf_counter() - start
        if mask & INT:
            seen.setdefault("python", now)
        if mask & TERM:
            seen.setdefault("ours", now)
        elif "ours" in seen:
            seen.setdefault("handed", now)
            break
        time.sleep(0.0002)  # leave the (shared) cores to the process measured
    proc.kill()
    proc.wait()
    return seen.get("python", np.nan), seen.get("ours", np.nan), seen.get("handed", np.nan)


def probe(n: int, seed: int) -> collections.Counter:
    """Outcomes of SIGINT at random times in the first 300 ms of ``trajgen plan``."""
    rng = np.random.default_rng(seed)
    counts = collections.Counter()
    for delay in rng.uniform(0.0, 0.3, n):
        argv = [str(TRAJGEN), "plan", "--out", os.devnull, "--rate", "5000"]
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        err = proc.communicate()[1].decode()
        if "Traceback" in err:
            ours = re.search(r'File "[^"]*(trajgen_launch\.py|/trajgen/|/drivers/|/sim/)', err)
            where = "in our code" if ours else "before our first statement (site, the script)"
            counts[f"traceback {where}"] += 1
        elif proc.returncode == -signal.SIGINT and not err:
            counts["killed before Python's handler (no output)"] += 1
        elif proc.returncode == 130 and len(err.strip().splitlines()) == 1:
            counts["exit 130, one line"] += 1
        else:
            counts[f"exit {proc.returncode}, {len(err.strip().splitlines())} lines"] += 1
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--probe", type=int, default=40)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    print(f"load before: {os.getloadavg()}")
    ours = np.array([times([str(TRAJGEN), "plan", "--out", os.devnull]) for _ in range(args.runs)])
    peer = np.array([times([sys.executable, "-c", PEER]) for _ in range(args.runs)])
    window, peer_window = ours[:, 1] - ours[:, 0], peer[:, 1] - peer[:, 0]
    for name, values in [
        ("exec -> Python's SIGINT handler (silent kill)", ours[:, 0]),
        ("Python's handler -> our first statement (traceback window)", window),
        ("  peer: the same for a two-line script", peer_window),
        ("our first statement -> hand-over to trajgen.cli (one line)", ours[:, 2] - ours[:, 1]),
    ]:
        ms = 1000 * values[np.isfinite(values)]
        print(f"{name}: median {np.median(ms):.1f} ms, p90 {np.percentile(ms, 90):.1f} ms")
    ratio = np.nanmedian(window) / np.nanmedian(peer_window)
    print(f"traceback window, ours / peer (medians): {ratio:.2f}")
    if args.probe:
        print(f"SIGINT at uniform random times in 0-300 ms, {args.probe} runs (seed {args.seed}):")
        for outcome, count in probe(args.probe, args.seed).most_common():
            print(f"  {count:3d}  {outcome}")
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
